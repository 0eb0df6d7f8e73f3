"""Acquisition: impact sessions, strike detection, stream alignment, rigs and FRFs from time data."""
