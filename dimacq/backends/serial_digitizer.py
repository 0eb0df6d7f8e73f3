"""Backend ``digitizer = "serial"``: the sonic digitizer on the pyserial URL ``digitizer_url``
(a port such as ``/dev/ttyUSB0``, ``rfc2217://host:port``, ``socket://host:port``), at
``digitizer_baudrate`` with ``digitizer_timeout_s`` per reply line and ``digitizer_poll_s`` reads."""

from __future__ import annotations

from dimacq.backends.base import DeviceContext
from dimacq.drivers.digitizer import SerialDigitizer

__all__ = ["open_digitizer"]


def open_digitizer(ctx: DeviceContext) -> SerialDigitizer:
    """The table entry ``"serial"``; the port's closer goes to ``ctx``."""
    st = ctx.settings
    driver = SerialDigitizer.from_url(
        st.digitizer_url,
        timeout_s=st.digitizer_timeout_s,
        poll_s=st.digitizer_poll_s,
        baudrate=st.digitizer_baudrate,
    )
    ctx.on_close(driver.close)
    return driver
