"""Driver of the SD-3 sonic digitizer over any pyserial-like port.

Template method (:class:`~dimacq.drivers.base.WireDriver`): :class:`DigitizerDriver` owns the
public methods (validation, timeouts, logging, reply matching, error mapping); a transport
subclass implements only the wire step
(:meth:`DigitizerDriver._send`, :meth:`DigitizerDriver._receive_line`,
:meth:`DigitizerDriver._reopen`). :class:`SerialDigitizer` is that subclass for pyserial ports,
opened from a URL (``serial_for_url``) so that a real port, ``rfc2217://``, ``socket://`` and the
simulator (``simdigitizer://``) are one configuration value apart.

Robustness (see :mod:`dimacq.drivers.digitizer.protocol` for the byte format):

* timeouts: no complete reply line within ``timeout_s`` → :class:`DeviceTimeoutError`;
* garbage bytes: everything before the next ``$`` is discarded (counted in :attr:`stats`);
* truncated line (a second ``$`` before the end of line): the fragment is dropped and reading goes
  on from the new ``$``; a record with too few fields → :class:`ProtocolError` naming the field;
* checksum mismatch → :class:`ProtocolError` naming the ``checksum`` field; the stream stays in
  step (the bad line was consumed);
* the port vanishes (``OSError``/``SerialException``) → :class:`DeviceNotFoundError`;
  :meth:`DigitizerDriver.reconnect` reopens the same URL. The driver keeps no acquired data, so
  nothing is lost: records already returned belong to the caller.
"""

from __future__ import annotations

import abc
import logging
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any, Protocol

from dimacq.devices.digitizer import DeviceIdentity, DigitizerSettings, ShotRecord
from dimacq.drivers.base import Deadline, WireDriver
from dimacq.drivers.digitizer import protocol as wire
from dimacq.errors import (
    DeviceError,
    DeviceNotFoundError,
    DeviceStateError,
    DeviceTimeoutError,
    ProtocolError,
    SetupError,
)

__all__ = ["DigitizerDriver", "DriverStats", "SerialDigitizer", "SerialLike"]

log = logging.getLogger(__name__)


class _DamagedLine(ProtocolError):
    """A reply line damaged on the link (checksum, too few fields): the command may be resent."""


class SerialLike(Protocol):
    """The part of :class:`serial.Serial` the driver uses."""

    timeout: float | None

    def read(self, size: int = 1) -> bytes: ...

    def write(self, data: bytes) -> int | None: ...

    @property
    def in_waiting(self) -> int: ...

    def reset_input_buffer(self) -> None: ...

    def close(self) -> None: ...


@dataclass
class DriverStats:
    """Link health counters."""

    garbage_bytes: int = 0
    truncated_lines: int = 0
    bad_lines: int = 0
    stale_records: int = 0
    seq_gaps: int = 0
    reconnects: int = 0


class DigitizerDriver(WireDriver, abc.ABC):
    """Public behaviour of an SD-3 digitizer driver; subclasses move the bytes.

    Parameters
    ----------
    timeout_s : float
        Longest wait for one reply line.
    """

    reopen_hint = "create a new one or call reconnect()"

    def __init__(self, timeout_s: float = 1.0) -> None:
        super().__init__("digitizer", timeout_s=timeout_s, log=log)
        self.stats = DriverStats()
        self._last_seq: int | None = None
        self._in_reconnect = False

    # ------------------------------------------------------------------ wire step (subclass)
    @abc.abstractmethod
    def _send(self, raw: bytes) -> None:
        """Write ``raw``; raise :class:`DeviceNotFoundError` if the port has gone."""

    @abc.abstractmethod
    def _receive_line(self, deadline: float) -> bytes:
        """Next line starting with ``$`` and ending with LF, before ``deadline`` (monotonic)."""

    @abc.abstractmethod
    def _reopen(self) -> None:
        """Reopen the transport (raise :class:`DeviceNotFoundError` when it cannot)."""

    @abc.abstractmethod
    def _close_transport(self) -> None:
        """Close the transport."""

    # ------------------------------------------------------------------ helpers
    def _read_fields(self, deadline: float, what: str) -> list[str]:
        try:
            line = self._receive_line(deadline)
        except DeviceTimeoutError as err:
            raise DeviceTimeoutError(
                f"digitizer: no reply to {what} within {self.timeout_s:g} s ({err})"
            ) from err
        try:
            return wire.unframe(line)
        except ProtocolError as err:
            self.stats.bad_lines += 1
            raise _DamagedLine(str(err)) from err

    #: further attempts of a command whose reply line was damaged on the link, or whose port
    #: dropped off (reopened first); SHOT is not repeated here (the caller fires again)
    link_retries = 2

    def _transact(self, command: bytes, expect: str, *, repeatable: bool = True) -> list[str]:
        """Send ``command`` and return the fields of the reply tagged ``expect``.

        A repeatable command (every one but SHOT and STRM) whose reply line arrives damaged
        (checksum, truncated) is sent again, and one whose port dropped off is sent again on the
        reopened port, up to :attr:`link_retries` times; the device's own ERR replies are not
        retried.
        """
        tries = 1 + (self.link_retries if repeatable and not self._in_reconnect else 0)
        for k in range(tries):
            try:
                return self._transact_once(command, expect)
            except _DamagedLine as err:
                if k + 1 == tries:
                    raise ProtocolError(str(err)) from err
                log.warning("digitizer: %s; sending the command again", err)
            except DeviceNotFoundError as err:
                if k + 1 == tries:
                    raise
                log.warning("digitizer: port lost (%s); reopening it", err)
                self.reconnect()
        raise AssertionError("unreachable")  # pragma: no cover

    def _transact_once(self, command: bytes, expect: str) -> list[str]:
        what = command.strip().decode("ascii", "replace")

        def attempt(deadline: Deadline) -> list[str]:
            self._send(command)
            while True:
                fields = self._read_fields(deadline.at, what)
                log.debug("digitizer < %s", ",".join(fields)[:120])
                tag = fields[0]
                if tag == expect:
                    return fields
                if tag == "ERR":
                    self._raise_device_error(fields, what)
                if tag == "SHT":
                    self.stats.stale_records += 1
                    log.warning("digitizer: stale shot record ignored while waiting for %s", expect)
                    continue
                raise ProtocolError(
                    f"digitizer: reply to {what!r} has tag {tag!r}; expected {expect!r}"
                )

        return self._exchange(what, attempt)

    @staticmethod
    def _raise_device_error(fields: list[str], what: str) -> None:
        code = fields[1] if len(fields) > 1 else "?"
        text = ",".join(fields[2:])
        if code == str(int(wire.ErrorCode.BUSY)):
            raise DeviceStateError(
                f"digitizer refused {what!r}: busy ({text}); send STOP or wait for the stream end"
            )
        if code == str(int(wire.ErrorCode.HARDWARE)):
            raise DeviceError(
                f"digitizer hardware fault on {what!r}: {text}; check emitters and cables"
            )
        raise ProtocolError(f"digitizer refused {what!r}: error {code} ({text})")

    def _check_seq(self, record: ShotRecord) -> None:
        if self._last_seq is not None and record.seq != (self._last_seq + 1) % 65536:
            self.stats.seq_gaps += 1
            log.warning(
                "digitizer: shot sequence jumped from %d to %d (records lost)",
                self._last_seq,
                record.seq,
            )
        self._last_seq = record.seq

    # ------------------------------------------------------------------ public API
    def identify(self) -> DeviceIdentity:
        """``*IDN?``."""
        return wire.decode_identity(self._transact(wire.encode_command("*IDN?"), "IDN"))

    def reset(self) -> None:
        """``RST``: defaults, sequence 0, stream stopped."""
        fields = self._transact(wire.encode_command("RST"), "OK")
        if fields[1:2] != ["RST"]:
            raise ProtocolError(f"digitizer: reply to RST is {fields!r}")
        self._last_seq = None

    def settings(self) -> DigitizerSettings:
        """``CFG?``."""
        return wire.decode_settings(self._transact(wire.encode_command("CFG?"), "CFG"))

    def configure(
        self,
        *,
        emitters: int | None = None,
        microphones: int | None = None,
        averaging: int | None = None,
        bar_repeats: int | None = None,
    ) -> DigitizerSettings:
        """``CFG E=..,M=..,A=..,B=..``: change settings, return what the device reports."""
        limits = {
            "emitters": (emitters, 1, 2, "E"),
            "microphones": (microphones, 3, 64, "M"),
            "averaging": (averaging, 1, 16, "A"),
            "bar_repeats": (bar_repeats, 1, 8, "B"),
        }
        args = []
        for name, (value, lo, hi, key) in limits.items():
            if value is None:
                continue
            if not isinstance(value, int) or not lo <= value <= hi:
                raise SetupError(
                    f"digitizer configure: {name} = {value!r}; give an integer {lo}..{hi}"
                )
            args.append(f"{key}={value}")
        if not args:
            return self.settings()
        got = wire.decode_settings(
            self._transact(wire.encode_command("CFG", ",".join(args)), "CFG")
        )
        for name, (value, *_rest) in limits.items():
            if value is not None and getattr(got, name) != value:
                raise ProtocolError(
                    f"digitizer configure: asked {name} = {value}, device reports {getattr(got, name)}"
                )
        return got

    def command(self, text: str, expect: str = "OK") -> list[str]:
        """Send a raw command line (e.g. a simulator-only ``SIM:`` command) and return the fields
        of the reply tagged ``expect``."""
        name, _, args = text.strip().partition(" ")
        return self._transact(wire.encode_command(name, args.strip()), expect)

    def fire(self) -> ShotRecord:
        """``SHOT``: fire once, return the record."""
        record = wire.decode_shot(
            self._transact(wire.encode_command("SHOT"), "SHT", repeatable=False)
        )
        self._check_seq(record)
        return record

    def stream(self, n_shots: int) -> Iterator[ShotRecord]:
        """``STRM n``: yield ``n_shots`` records as they arrive.

        A corrupted record (checksum) is logged, counted in :attr:`stats` and skipped; the
        sequence numbers show the gap. Stopping the iteration early sends ``STOP``.
        """
        if not isinstance(n_shots, int) or not 1 <= n_shots <= 100000:
            raise SetupError(f"digitizer stream: n_shots = {n_shots!r}; give an integer 1..100000")
        self._require_open()
        self._send(wire.encode_command("STRM", str(n_shots)))
        done = False
        try:
            while True:
                deadline = time.monotonic() + self.timeout_s
                try:
                    fields = self._read_fields(deadline, f"STRM {n_shots}")
                except ProtocolError as err:
                    log.warning("digitizer: bad line in stream skipped: %s", err)
                    continue
                if fields[0] == "SHT":
                    record = wire.decode_shot(fields)
                    self._check_seq(record)
                    yield record
                elif fields[0] == "OK" and fields[1:2] == ["STRM"]:
                    done = True
                    return
                elif fields[0] == "ERR":
                    done = True
                    self._raise_device_error(fields, f"STRM {n_shots}")
                else:
                    raise ProtocolError(f"digitizer: unexpected {fields[0]!r} line in a stream")
        finally:
            if not done and not self._closed:
                try:
                    self._transact(wire.encode_command("STOP"), "OK")
                except DeviceError as err:
                    log.warning("digitizer: STOP after an interrupted stream failed: %s", err)

    def reconnect(self, attempts: int = 5, delay_s: float = 0.2) -> DeviceIdentity:
        """Reopen the port (``attempts`` tries, ``delay_s`` apart) and identify the device."""
        last: Exception | None = None
        for i in range(attempts):
            try:
                self._reopen()
                self._closed = False
                self._in_reconnect = True
                try:
                    identity = self.identify()
                finally:
                    self._in_reconnect = False
                self.stats.reconnects += 1
                self._last_seq = None
                log.info("digitizer reconnected (%s) after %d attempt(s)", identity.serial, i + 1)
                return identity
            except DeviceError as err:
                # each failed attempt is reported (a reply damaged on the link while reopening
                # is a fault of its own, not only a cause of the retry)
                log.warning(
                    "digitizer: reconnect attempt %d of %d failed: %s", i + 1, attempts, err
                )
                last = err
                time.sleep(delay_s)
        raise DeviceNotFoundError(
            f"digitizer: reconnect failed after {attempts} attempts ({last}); check the cable/port"
        ) from last


class SerialDigitizer(DigitizerDriver):
    """SD-3 driver over an injected pyserial-like port.

    Parameters
    ----------
    port : SerialLike
        An open port (``serial.serial_for_url(url, baudrate=115200, timeout=0.02)``).
    reopen : callable, optional
        Returns a fresh open port; used by :meth:`reconnect`.
    timeout_s : float
        Longest wait for one reply line.
    name : str
        For messages (the URL).
    """

    def __init__(
        self,
        port: SerialLike,
        *,
        reopen: Callable[[], SerialLike] | None = None,
        timeout_s: float = 1.0,
        name: str = "digitizer port",
    ) -> None:
        super().__init__(timeout_s=timeout_s)
        self._port: SerialLike | None = port
        self._reopen_factory = reopen
        self.name = name
        self._buf = bytearray()

    @classmethod
    def from_url(
        cls,
        url: str,
        *,
        timeout_s: float = 1.0,
        poll_s: float = 0.02,
        baudrate: int = wire.BAUDRATE,
        **serial_kwargs: Any,
    ) -> SerialDigitizer:
        """Open ``url`` with :func:`serial.serial_for_url`, 8N1 at ``baudrate`` (the SD-3's
        115200 unless the settings say otherwise)."""
        import serial

        def opener() -> SerialLike:
            try:
                port: SerialLike = serial.serial_for_url(
                    url, baudrate=baudrate, timeout=poll_s, **serial_kwargs
                )
            except (serial.SerialException, OSError, ValueError) as err:
                raise DeviceNotFoundError(
                    f"digitizer: cannot open {url!r} ({err}); check the port name"
                ) from err
            return port

        return cls(opener(), reopen=opener, timeout_s=timeout_s, name=url)

    def _port_or_raise(self) -> SerialLike:
        if self._port is None:
            raise DeviceNotFoundError(f"{self.name}: port is gone; call reconnect()")
        return self._port

    def _vanished(self, err: Exception) -> DeviceNotFoundError:
        log.warning("%s vanished: %s", self.name, err)
        port, self._port = self._port, None
        if port is not None:
            try:
                port.close()
            except Exception:
                pass
        return DeviceNotFoundError(f"{self.name}: port vanished ({err}); call reconnect()")

    def _send(self, raw: bytes) -> None:
        port = self._port_or_raise()
        try:
            port.write(raw)
        except OSError as err:  # serial.SerialException is an OSError
            raise self._vanished(err) from err

    def _receive_line(self, deadline: float) -> bytes:
        buf = self._buf
        while True:
            start = buf.find(wire.START)
            if start < 0 and buf:
                self.stats.garbage_bytes += len(buf)
                log.warning("%s: line noise, %d garbage bytes dropped", self.name, len(buf))
                buf.clear()
            elif start > 0:
                self.stats.garbage_bytes += start
                log.warning("%s: line noise, %d garbage bytes dropped", self.name, start)
                del buf[:start]
            if buf:
                eol = buf.find(b"\n")
                nxt = buf.find(wire.START, 1)
                if nxt > 0 and (eol < 0 or nxt < eol):
                    self.stats.truncated_lines += 1
                    log.warning("%s: truncated line dropped: %r", self.name, bytes(buf[:nxt])[:60])
                    del buf[:nxt]
                    continue
                if eol >= 0:
                    line = bytes(buf[: eol + 1])
                    del buf[: eol + 1]
                    return line
                if len(buf) > wire.MAX_LINE:
                    self.stats.garbage_bytes += len(buf)
                    buf.clear()
            if time.monotonic() >= deadline:
                raise DeviceTimeoutError(f"{self.name}: no complete reply line")
            port = self._port_or_raise()
            try:
                chunk = port.read(max(1, port.in_waiting))
            except OSError as err:
                raise self._vanished(err) from err
            buf += chunk

    def _reopen(self) -> None:
        if self._reopen_factory is None:
            raise DeviceNotFoundError(
                f"{self.name}: no way to reopen the port (created without reopen=)"
            )
        if self._port is not None:
            try:
                self._port.close()
            except OSError:
                pass
            self._port = None
        self._port = self._reopen_factory()
        self._buf.clear()
        try:
            self._port.reset_input_buffer()
        except OSError as err:
            raise self._vanished(err) from err

    def _close_transport(self) -> None:
        if self._port is not None:
            try:
                self._port.close()
            finally:
                self._port = None
