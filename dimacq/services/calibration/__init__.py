"""Calibration: load-cell bench calibration, the inertial calibration mass and the circular check."""
