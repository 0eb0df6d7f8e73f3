"""Geometry: digitizing sessions, the digitizer's configuration and self-test, and the trust in a registration."""
