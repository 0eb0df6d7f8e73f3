"""Scripted exchanges for driver tests on the three wires (pymeasure's ``expected_protocol``).

A test lists the pairs (what the driver sends, what the device answers) and runs the driver on
a scripted transport; every send must equal the next pair's, whose answer then becomes readable.
Leaving the block with pairs not yet sent or answers not yet read fails the test, as does a send
that is not the one expected::

    with expected_exchange("can", [(Can(CMD, b"\\x01"), Can(RSP, bytes.fromhex("810c..."))], connect=amp) as a:
        a.identify()

The wires and what a pair holds:

- ``"serial"``: ``(bytes written, bytes answered or None)``; ``vanish_after=k`` makes the port
  raise like an unplugged adapter after the k-th write;
- ``"can"``: ``(Can sent or None, Can answered, a list of them, or None)``; a pair whose sent
  frame is None is the device speaking unprompted (data frames, heartbeats): it is released as
  soon as the pairs before it are done;
- ``"usb"``: ``(Ctrl(...) or BulkIn(...), answer)``; the answer is the bytes of an IN transfer,
  the length returned by an OUT transfer, or an exception to raise (a stall, a timeout).

The answers are literal bytes where the test pins the wire format; a test may build them with the
protocol's message table where it exercises the driver's logic.
"""

from __future__ import annotations

import contextlib
import threading
import time
from collections import deque
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from typing import Any, Literal

import can
import serial
import usb.core

__all__ = [
    "BulkIn",
    "Can",
    "Ctrl",
    "ScriptedBus",
    "ScriptedSerial",
    "ScriptedUsb",
    "expected_exchange",
]


# ---------------------------------------------------------------------------- serial


class ScriptedSerial:
    """A fake pyserial port (the part :class:`~dimacq.drivers.digitizer.SerialLike` names)."""

    def __init__(
        self, pairs: Sequence[tuple[bytes, bytes | None]], vanish_after: int | None = None
    ) -> None:
        self.pairs = list(pairs)
        self.rx = bytearray()
        self.timeout: float | None = 0.0
        self.closed = False
        self.vanish_after = vanish_after
        self.writes = 0

    def _maybe_vanish(self) -> None:
        if self.vanish_after is not None and self.writes > self.vanish_after:
            raise serial.SerialException("device reports readiness to read but returned no data")

    def write(self, data: bytes) -> int:
        self.writes += 1
        self._maybe_vanish()
        assert self.pairs, f"unexpected write {data!r}: script exhausted"
        sent, answered = self.pairs.pop(0)
        assert data == sent, f"sent {data!r}, script expected {sent!r}"
        if answered:
            self.rx += answered
        return len(data)

    def read(self, size: int = 1) -> bytes:
        self._maybe_vanish()
        out = bytes(self.rx[:size])
        del self.rx[:size]
        return out

    @property
    def in_waiting(self) -> int:
        return len(self.rx)

    def reset_input_buffer(self) -> None:
        self.rx.clear()

    def close(self) -> None:
        self.closed = True

    def assert_done(self) -> None:
        assert not self.pairs, f"script not consumed: {self.pairs!r}"
        assert not self.rx, f"answers left unread: {bytes(self.rx)!r}"


# ---------------------------------------------------------------------------- CAN


@dataclass(frozen=True)
class Can:
    """One CAN frame: 11-bit identifier, data, CAN FD or classic."""

    id: int
    data: bytes
    fd: bool = False

    def __repr__(self) -> str:
        return f"Can({self.id:#05x}, {self.data.hex()}{', fd' if self.fd else ''})"


CanAnswer = Can | Sequence[Can] | None


class ScriptedBus(can.BusABC):
    """A python-can bus whose far end plays the script."""

    def __init__(self, pairs: Sequence[tuple[Can | None, CanAnswer]]) -> None:
        super().__init__(channel="scripted")
        self.channel_info = "scripted exchange"
        self.pairs = list(pairs)
        self.rx: deque[can.Message] = deque()
        self._release()

    def _queue(self, answered: CanAnswer) -> None:
        frames = [] if answered is None else [answered] if isinstance(answered, Can) else answered
        for f in frames:
            self.rx.append(
                can.Message(
                    arbitration_id=f.id,
                    data=f.data,
                    is_extended_id=False,
                    is_fd=f.fd,
                    timestamp=time.time(),
                )
            )

    def _release(self) -> None:
        while self.pairs and self.pairs[0][0] is None:
            self._queue(self.pairs.pop(0)[1])

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        got = Can(msg.arbitration_id, bytes(msg.data), bool(msg.is_fd))
        assert self.pairs, f"unexpected frame {got!r}: script exhausted"
        sent, answered = self.pairs.pop(0)
        assert got == sent, f"sent {got!r}, script expected {sent!r}"
        self._queue(answered)
        self._release()

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        if self.rx:
            return self.rx.popleft(), False
        time.sleep(0.1 if timeout is None else timeout)
        return None, False

    def assert_done(self) -> None:
        assert not self.pairs, f"script not consumed: {self.pairs!r}"
        left = [Can(m.arbitration_id, bytes(m.data), bool(m.is_fd)) for m in self.rx]
        assert not left, f"answers left unread: {left!r}"


# ---------------------------------------------------------------------------- USB


@dataclass(frozen=True)
class Ctrl:
    """A control transfer: ``data`` is the bytes of an OUT transfer or the length of an IN one."""

    bm_request_type: int
    request: int
    value: int = 0
    index: int = 0
    data: bytes | int = b""


@dataclass(frozen=True)
class BulkIn:
    """A bulk IN transfer of at most ``size`` bytes on ``endpoint``."""

    endpoint: int
    size: int


class _Ctx:
    def dispose(self, device: object) -> None:
        return None


class ScriptedUsb:
    """A stand-in for ``usb.core.Device`` whose far end plays the script.

    ``reader_thread=True`` (a driver reading the bulk endpoint in its own thread): a bulk read
    whose pair is not next waits, as a device with no data, for the control transfers scripted
    before it (at most 5 s or its own timeout, whichever is longer), then times out without
    taking a pair; with the script done it times out at once.
    """

    def __init__(
        self, pairs: Sequence[tuple[Ctrl | BulkIn, Any]], *, reader_thread: bool = False
    ) -> None:
        self.pairs = list(pairs)
        self._ctx = _Ctx()
        self._threaded = reader_thread
        self._cond = threading.Condition()

    def set_configuration(self) -> None:
        return None

    def _next(self, got: Ctrl | BulkIn) -> Any:
        with self._cond:
            assert self.pairs, f"unexpected {got!r}: script exhausted"
            sent, answer = self.pairs.pop(0)
            self._cond.notify_all()
        assert got == sent, f"sent {got!r}, script expected {sent!r}"
        if isinstance(answer, BaseException):
            raise answer
        return answer

    def _await_bulk(self, timeout_ms: int) -> bool:
        """Reader-thread mode: wait until a bulk read is next (False: it is not)."""
        with self._cond:
            self._cond.wait_for(
                lambda: not self.pairs or isinstance(self.pairs[0][0], BulkIn),
                max(5.0, timeout_ms / 1000),
            )
            return bool(self.pairs) and isinstance(self.pairs[0][0], BulkIn)

    def ctrl_transfer(
        self, bm: int, req: int, value: int, index: int, data: Any, timeout: int
    ) -> Any:
        payload = data if isinstance(data, int) else bytes(data)
        return self._next(Ctrl(bm, int(req), value, index, payload))

    def read(self, endpoint: int, size: int, timeout: int) -> Any:
        if self._threaded and not self._await_bulk(timeout):
            raise usb.core.USBTimeoutError("Operation timed out", error_code=-7, errno=110)
        return self._next(BulkIn(endpoint, size))

    def assert_done(self) -> None:
        assert not self.pairs, f"script not consumed: {self.pairs!r}"


# ---------------------------------------------------------------------------- the helper

_WIRES: dict[str, Callable[..., Any]] = {
    "serial": ScriptedSerial,
    "can": ScriptedBus,
    "usb": ScriptedUsb,
}


@contextlib.contextmanager
def expected_exchange(
    wire: Literal["serial", "can", "usb"],
    pairs: Sequence[tuple[Any, Any]],
    connect: Callable[[Any], Any] | None = None,
    **transport_kw: Any,
) -> Iterator[Any]:
    """Yield ``connect(transport)`` (or the scripted transport itself); on leaving the block,
    every pair must have been exchanged and every answer read."""
    transport = _WIRES[wire](pairs, **transport_kw)
    try:
        yield transport if connect is None else connect(transport)
        transport.assert_done()
    finally:
        if isinstance(transport, can.BusABC):
            transport.shutdown()
