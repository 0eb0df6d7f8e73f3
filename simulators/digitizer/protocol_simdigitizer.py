"""pyserial URL handler for ``simdigitizer://<name>``: a serial port wired to a simulated device.

pyserial imports ``<package>.protocol_<scheme>`` for every package in
``serial.protocol_handler_packages`` and instantiates its ``Serial`` class; importing
:mod:`dimacq.simulators.digitizer` adds that package to the list.
"""

from __future__ import annotations

import time
from typing import Any

from serial.serialutil import PortNotOpenError, SerialBase, SerialException, to_bytes

from dimacq.errors import SetupError

__all__ = ["Serial"]


class Serial(SerialBase):
    """A serial port whose far end is a :class:`SimulatedDigitizer` (settings are accepted, unused)."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        self._device: Any = None
        self._generation = 0
        self._buffer = bytearray()
        super().__init__(*args, **kwargs)

    def open(self) -> None:
        from dimacq.simulators.digitizer import get_device

        if getattr(self, "is_open", False):
            raise SerialException("Port is already open.")
        if self._port is None:
            raise SerialException("Port must be configured before it can be used.")
        try:
            device = get_device(self.portstr)
        except SetupError as err:
            raise SerialException(str(err)) from err
        if not device.plugged:
            raise SerialException(f"could not open port {self.portstr}: device not connected")
        self._device = device
        self._generation = device.port_generation
        self._buffer.clear()
        self.is_open = True

    def close(self) -> None:
        self.is_open = False
        self._device = None
        self._buffer.clear()

    def _reconfigure_port(self) -> None:
        pass

    def _check(self) -> Any:
        if not self.is_open or self._device is None:
            raise PortNotOpenError()
        if not self._device.plugged or self._device.port_generation != self._generation:
            raise SerialException(f"{self.portstr}: device disconnected")
        return self._device

    def _pull(self) -> None:
        self._buffer += self._check().poll()

    @property
    def in_waiting(self) -> int:
        self._pull()
        return len(self._buffer)

    def read(self, size: int = 1) -> bytes:
        self._pull()
        deadline = None if self._timeout is None else time.monotonic() + self._timeout
        while len(self._buffer) < size:
            if deadline is not None and time.monotonic() >= deadline:
                break
            time.sleep(0.0005)
            self._pull()
        data = bytes(self._buffer[:size])
        del self._buffer[:size]
        return data

    def write(self, data: Any) -> int:
        raw = to_bytes(data)
        self._check().receive(raw)
        return len(raw)

    def reset_input_buffer(self) -> None:
        self._pull()
        self._buffer.clear()

    def reset_output_buffer(self) -> None:
        self._check()

    @property
    def out_waiting(self) -> int:
        return 0

    def _update_break_state(self) -> None:
        pass

    def _update_rts_state(self) -> None:
        pass

    def _update_dtr_state(self) -> None:
        pass

    @property
    def cts(self) -> bool:
        return True

    @property
    def dsr(self) -> bool:
        return True

    @property
    def ri(self) -> bool:
        return False

    @property
    def cd(self) -> bool:
        return True
