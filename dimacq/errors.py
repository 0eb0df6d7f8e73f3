"""The one exception tree of dimacq.

Every error dimacq raises on purpose derives from :class:`DimacqError`, so a caller (the CLI,
the REST API) can catch one type and show the message, which always names the item that was
wrong and says how to fix it::

    DimacqError
     ├── SetupError             a test setup, scenario, jig or config file is wrong
     │    └── DataError         measured data are unusable (NaNs, mismatched axes, bad UFF)
     ├── SolverError            a numerical solve cannot give a trustworthy answer (rank < 6, ...)
     └── DeviceError            anything about an instrument
          ├── DeviceNotFoundError   no device at that port / bus / USB id
          │    └── DeviceLostError  it was there and dropped off (port lost, USB re-enumeration)
          ├── DeviceTimeoutError    the device did not answer in time (also a TimeoutError)
          ├── ProtocolError         bytes on the wire do not follow the documented protocol
          ├── DeviceStateError      the request does not fit the device's state (e.g. not started)
          └── DatabaseUnavailableError  the database server cannot be reached (the service retries)

Chain with ``raise ... from err`` so the original cause stays visible.
"""

from __future__ import annotations

__all__ = [
    "DataError",
    "DatabaseUnavailableError",
    "DeviceError",
    "DeviceLostError",
    "DeviceNotFoundError",
    "DeviceStateError",
    "DeviceTimeoutError",
    "DimacqError",
    "ProtocolError",
    "SetupError",
    "SolverError",
]


class DimacqError(Exception):
    """Base of every error raised by dimacq on purpose."""


class SetupError(DimacqError, ValueError):
    """A setup, scenario, jig or configuration item is wrong; the message names it and the fix."""


class DataError(SetupError):
    """Measured or imported data are unusable (NaNs, mismatched frequency axes, bad records)."""


class SolverError(DimacqError):
    """A numerical solution cannot be trusted (rank deficiency, no data in band, ...)."""


class DeviceError(DimacqError):
    """Base of instrument errors."""


class DeviceNotFoundError(DeviceError):
    """No device answers at the configured port, bus or USB id."""


class DeviceLostError(DeviceNotFoundError):
    """The device answered, then dropped off (port lost, USB re-enumeration): reconnect."""


class DeviceTimeoutError(DeviceError, TimeoutError):
    """The device did not answer within the timeout."""


class ProtocolError(DeviceError):
    """Bytes on the wire do not follow the documented protocol (bad checksum, truncated record)."""


class DeviceStateError(DeviceError):
    """The request does not fit the device's present state (not connected, already streaming)."""


class DatabaseUnavailableError(DeviceError):
    """The database server cannot be reached now (restart, network); the service retries with
    backoff and keeps acquired data on its own disk until the database is back."""
