"""Simulated ATI Net F/T sensors speaking the manual's frames (:mod:`.can_sensor`)."""
