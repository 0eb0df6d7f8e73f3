"""Numerical pipeline: pure functions over numpy arrays (no I/O, no threads, no HTTP)."""
