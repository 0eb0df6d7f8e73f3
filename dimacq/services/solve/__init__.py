"""Solving: the analysis that composes estimation, modal correction, cross-checks and the verdict; planning studies."""
