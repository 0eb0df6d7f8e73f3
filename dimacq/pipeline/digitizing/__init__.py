"""Sonic digitizer pipeline: triangulation, registration, orientation jig, lines of action."""
