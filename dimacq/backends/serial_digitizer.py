"""Backend ``digitizer = "serial"``: the sonic digitizer on the pyserial URL ``digitizer_url``
(a port such as ``/dev/ttyUSB0``, ``rfc2217://host:port``, ``socket://host:port``)."""

from __future__ import annotations

from dimacq.backends.base import DeviceContext
from dimacq.drivers.digitizer import SerialDigitizer

__all__ = ["open_digitizer"]


def open_digitizer(ctx: DeviceContext) -> SerialDigitizer:
    """The table entry ``"serial"``; the port's closer goes to ``ctx``."""
    driver = SerialDigitizer.from_url(ctx.settings.digitizer_url, timeout_s=2.0)
    ctx.on_close(driver.close)
    return driver
