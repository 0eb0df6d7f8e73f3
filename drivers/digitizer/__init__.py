"""Sonic digitizer (SD-3) wire-level driver; protocol documented in :mod:`.protocol`."""

from dimacq.drivers.digitizer.driver import (
    DigitizerDriver,
    DriverStats,
    SerialDigitizer,
    SerialLike,
)

__all__ = ["DigitizerDriver", "DriverStats", "SerialDigitizer", "SerialLike"]
