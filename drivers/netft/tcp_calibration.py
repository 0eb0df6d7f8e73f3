"""The Net F/T's calibration read from the device: Read Calibration Info over its TCP
command interface (the request and response of :class:`~dimacq.drivers.netft.protocol.
CalibrationInfo`, network byte order; port :data:`~dimacq.drivers.netft.protocol.TCP_PORT`,
49151 — the port is not in the manual pages read for this module).

The socket is injected (connected, blocking with a timeout); this module moves the bytes only.
"""

from __future__ import annotations

from typing import Any

from dimacq.drivers.netft import protocol as p
from dimacq.errors import DeviceError, DeviceTimeoutError

__all__ = ["read_calibration_info"]


def read_calibration_info(sock: Any, *, where: str = "Net F/T") -> p.CalibrationInfo:
    """Send READCALINFO and read the 24-byte answer.

    Raises
    ------
    DeviceTimeoutError
        No (whole) answer within the socket's timeout.
    DeviceError
        The connection failed.
    ProtocolError
        A wrong header or unit code.
    """
    try:
        sock.sendall(p.CalibrationInfo.command())
        buf = b""
        while len(buf) < p.CalibrationInfo.SIZE:
            chunk = sock.recv(p.CalibrationInfo.SIZE - len(buf))
            if not chunk:
                raise DeviceError(f"{where}: the connection closed during Read Calibration Info")
            buf += chunk
    except TimeoutError as err:
        raise DeviceTimeoutError(
            f"{where}: no Read Calibration Info answer ({err}); check its IP address and TCP "
            f"port {p.TCP_PORT}"
        ) from err
    except OSError as err:
        raise DeviceError(f"{where}: Read Calibration Info failed: {err}") from err
    return p.CalibrationInfo.decode(buf)
