"""The load cell amplifier simulator on python-can's ``virtual`` interface.

A thread owns its own bus end (``can.Bus(interface="virtual", channel=...)``), answers the
control frames of :mod:`dimacq.drivers.loadcell.protocol` (the codec is all it shares with the
driver) and, once started, streams one CAN FD data frame per sample and a heartbeat every 256
samples. Its 12 gauges read 12 channels of the virtual lab's
:class:`~dimacq.simulators.lab.source.SampleSource` (volts at the bridge outputs).

Clock: with SYNC (external clock, the normal case) it counts the pulses of the DAQ simulator's
:class:`~dimacq.simulators.daq.clock.SampleClock`: armed before the DAQ starts, its counter ``k``
is DAQ sample ``k`` and world sample ``clock.epoch + k``; it streams as the DAQ clocks samples.
Its heartbeat time comes from its own oscillator (the true time of the pulse, plus a configurable
ppm error). With the internal clock it paces itself on the wall clock.

Faults for tests (:class:`LoadCellFaults`): data frames not sent (bus overload: a counter gap),
SYNC pulses missed at given pulses (the counter falls behind the DAQ: drift), and a silent node.
"""

from __future__ import annotations

import logging
import threading
import time
import zlib
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import can
import numpy as np

from dimacq.drivers.loadcell import protocol as p
from dimacq.simulators.daq.clock import SampleClock
from dimacq.simulators.lab.source import SampleSource

__all__ = ["LoadCellAmplifierSim", "LoadCellFaults"]

log = logging.getLogger(__name__)

_CHUNK = 256


@dataclass
class LoadCellFaults:
    """``dropped_samples``: counters whose data frame is not sent; ``missed_pulses``: pulse
    index → number of SYNC pulses the counter misses there; ``silent``: answer nothing."""

    dropped_samples: set[int] = field(default_factory=set)
    missed_pulses: dict[int, int] = field(default_factory=dict)
    silent: bool = False


class LoadCellAmplifierSim:
    """Simulated amplifier; use as a context manager (the thread and bus are closed on exit).

    Parameters
    ----------
    channel : str
        python-can virtual channel name shared with the driver's bus.
    source : SampleSource
    gauge_channels : sequence of 12 int
        Source channels of gauges 1..12.
    clock : SampleClock, optional
        The DAQ's SYNC output. Without it only the internal clock works.
    node_id, serial_number : int
    calibration_matrix : array_like (6, 12), optional
        What the amplifier holds in its memory at power-on (default zeros).
    oscillator_ppm : float
        Error of the amplifier's own oscillator (heartbeat time base).
    faults : LoadCellFaults, optional
    """

    def __init__(
        self,
        channel: str,
        source: SampleSource,
        gauge_channels: Sequence[int],
        *,
        clock: SampleClock | None = None,
        node_id: int = 1,
        serial_number: int = 501,
        calibration_matrix: Any = None,
        oscillator_ppm: float = 0.0,
        faults: LoadCellFaults | None = None,
    ) -> None:
        if len(gauge_channels) != p.N_GAUGES:
            raise ValueError(f"give {p.N_GAUGES} gauge channels, got {len(gauge_channels)}")
        self.source = source
        self.gauges = np.asarray(gauge_channels, dtype=np.intp)
        self.clock = clock
        self.node = node_id
        self.serial_number = serial_number
        self.matrix = (
            np.zeros((6, p.N_GAUGES))
            if calibration_matrix is None
            else np.array(calibration_matrix)
        )
        self.oscillator_ppm = oscillator_ppm
        self.faults = faults if faults is not None else LoadCellFaults()
        self.rate_hz = float(source.sample_rate_hz)
        self.offsets = np.zeros(p.N_GAUGES)
        self.state = 0
        self._external = True
        self._counter = 0  # next counter value to send
        self._pulses = 0  # SYNC pulses seen since START
        self._base_run = 0
        self._base_count = 0
        self._epoch = 0
        self._t0 = 0.0
        self._download: dict[int, bytes] = {}
        self._download_len = 0
        self._stop_evt = threading.Event()
        self._lock = threading.Lock()
        self.bus = can.Bus(interface="virtual", channel=channel, fd=True)
        self._thread = threading.Thread(target=self._run, name=f"loadcell-sim-{channel}")
        self._thread.start()

    # -- lifetime ----------------------------------------------------------------------------
    def close(self) -> None:
        self._stop_evt.set()
        if self.clock is not None:
            self.clock.notify()
        self._thread.join(timeout=5.0)
        self.bus.shutdown()

    def __enter__(self) -> LoadCellAmplifierSim:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- thread ------------------------------------------------------------------------------
    def _run(self) -> None:
        try:
            while not self._stop_evt.is_set():
                msg = self.bus.recv(0.0 if self.state == 2 else 0.005)
                if msg is not None and msg.arbitration_id == p.command_id(self.node):
                    if not self.faults.silent:
                        self._handle(bytes(msg.data))
                    continue
                if self.state == 2:
                    if not self._stream_some():
                        self._wait_for_clock(0.005)
        except Exception:  # pragma: no cover - surfaced through the test's timeouts
            log.exception("load cell simulator thread failed")

    def _wait_for_clock(self, timeout_s: float) -> None:
        if self.clock is not None and self._external:
            self.clock.wait_change(self.clock.state(), timeout_s)
        else:
            time.sleep(timeout_s / 5)

    def _send(self, aid: int, data: bytes, fd: bool = False) -> None:
        self.bus.send(can.Message(arbitration_id=aid, data=data, is_extended_id=False, is_fd=fd))

    def _reply(self, data: bytes) -> None:
        self._send(p.response_id(self.node), data)

    def _error(self, op: int, code: p.ErrorCode) -> None:
        self._reply(bytes([p.ERROR, op, int(code)]))

    def _handle(self, d: bytes) -> None:
        op = d[0]
        C = p.Command
        if op == C.IDENTIFY:
            self._reply(bytes([0x81, p.N_GAUGES, 1, 0]) + self.serial_number.to_bytes(4, "little"))
        elif op == C.GET_STATUS:
            flags = 0
            if self._external and (self.clock is None or not self.clock.state().running):
                flags |= p.STATUS_SYNC_MISSING
            self._reply(
                bytes([0x8B, self.state, flags, 0])
                + (self._counter & 0xFFFFFFFF).to_bytes(4, "little")
            )
        elif op == C.STOP:
            self._stream_some(final=True)
            self.state = 0
            self._reply(bytes([0x83]) + (self._counter & 0xFFFFFFFF).to_bytes(4, "little"))
        elif self.state != 0:
            self._error(op, p.ErrorCode.BUSY)
        elif op == C.START:
            if len(d) < 2 or d[1] not in (0, 1):
                self._error(op, p.ErrorCode.BAD_ARGUMENT)
                return
            self._arm(external=d[1] == 1)
            self._reply(bytes([0x82]))
        elif op == C.SET_RATE:
            rate = int.from_bytes(d[1:5], "little") if len(d) >= 5 else 0
            if rate <= 0:
                self._error(op, p.ErrorCode.BAD_ARGUMENT)
                return
            self.rate_hz = float(rate)
            self._reply(bytes([0x84]) + rate.to_bytes(4, "little"))
        elif op == C.TARE:
            n = max(1, int.from_bytes(d[1:3], "little"))
            pos = self._world_now()
            with self._source_lock():
                g = self.source.read(self.gauges, pos, n)
            self.offsets = g.mean(axis=1)
            self._reply(bytes([0x85]))
        elif op == C.CAL_DOWNLOAD_BEGIN:
            self._download_len = int.from_bytes(d[1:3], "little")
            self._download = {}
            self._reply(bytes([0x86]))
        elif op == C.CAL_SEGMENT:
            self._download[d[1]] = d[2:8]
        elif op == C.CAL_DOWNLOAD_END:
            n_seg = (self._download_len + 5) // 6
            if any(i not in self._download for i in range(n_seg)):
                self._error(op, p.ErrorCode.MISSING_SEGMENT)
                return
            blob = b"".join(self._download[i] for i in range(n_seg))[: self._download_len]
            if zlib.crc32(blob) != int.from_bytes(d[1:5], "little"):
                self._error(op, p.ErrorCode.CRC_MISMATCH)
                return
            try:
                self.matrix = p.matrix_from_blob(blob)
            except Exception:
                self._error(op, p.ErrorCode.BAD_ARGUMENT)
                return
            self._reply(bytes([0x88]))
        elif op == C.CAL_UPLOAD:
            blob = p.matrix_to_blob(self.matrix)
            self._reply(
                bytes([0x89])
                + len(blob).to_bytes(2, "little")
                + zlib.crc32(blob).to_bytes(4, "little")
            )
            for i, seg in enumerate(p.segments(blob)):
                self._reply(bytes([p.UPLOAD_SEGMENT, i]) + seg)
        else:
            self._error(op, p.ErrorCode.UNKNOWN_COMMAND)

    def _source_lock(self) -> Any:
        return self.clock.source_lock if self.clock is not None else self._lock

    def _world_now(self) -> int:
        if self.clock is not None:
            st = self.clock.state()
            return st.epoch + st.count
        return 0

    def _arm(self, external: bool) -> None:
        self._external = external
        self._counter = 0
        self._pulses = 0
        self._t0 = time.monotonic()
        if external:
            if self.clock is None:
                raise RuntimeError("external clock requested but no SampleClock wired")
            st = self.clock.state()
            if st.running:
                self._base_run, self._base_count = st.run, st.count
            else:
                self._base_run, self._base_count = st.run + 1, 0
        self.state = 2

    def _available_pulses(self) -> int:
        """SYNC pulses seen since START (or internal clock ticks)."""
        if not self._external:
            return int((time.monotonic() - self._t0) * self.rate_hz)
        assert self.clock is not None
        st = self.clock.state()
        if st.run != self._base_run:
            return self._pulses  # the DAQ has not started this run yet, or has moved on
        self._epoch = st.epoch
        return st.count - self._base_count

    def _stream_some(self, final: bool = False) -> bool:
        """Send frames for pulses seen; returns False when there was nothing to send."""
        avail = self._available_pulses()
        sent = False
        while self._pulses < avail:
            n = min(_CHUNK, avail - self._pulses)
            self._emit(self._pulses, n)
            self._pulses += n
            sent = True
            if not final:
                break
        return sent

    def _emit(self, pulse0: int, n: int) -> None:
        """Samples at pulses ``pulse0 .. pulse0 + n − 1``, labelled with the amplifier's counter.

        A missed SYNC pulse produces no sample and is not counted, so every later sample is
        labelled with a counter smaller than its true pulse: the stream is misaligned.
        """
        pulses = pulse0 + np.arange(n, dtype=np.int64)
        missed_upto = np.zeros(n, dtype=np.int64)
        is_missed = np.zeros(n, dtype=bool)
        for at, m in self.faults.missed_pulses.items():
            is_missed |= (pulses >= at) & (pulses < at + m)
            missed_upto += np.clip(pulses - at + 1, 0, m)
        counters = pulses - missed_upto
        world0 = self._epoch + self._base_count if self._external else 0
        with self._source_lock():
            g = self.source.read(self.gauges, world0 + pulse0, n)
        g = (g - self.offsets[:, None]).T
        keep = ~is_missed
        frames, _ = p.encode_data_frames(0, g[keep])
        aid = p.data_id(self.node)
        hb = p.heartbeat_id(self.node)
        scale_us = 1e6 / self.rate_hz * (1 + self.oscillator_ppm * 1e-6)
        for c, q, f in zip(counters[keep].tolist(), pulses[keep].tolist(), frames, strict=True):
            if c not in self.faults.dropped_samples:
                self._send(aid, (c & 0xFFFFFFFF).to_bytes(4, "little") + f[4:], fd=True)
            if (c + 1) % p.HEARTBEAT_EVERY == 0:
                # counter reached, and the true time of that pulse on the amplifier's oscillator
                t_us = round((q + 1) * scale_us)
                self._send(hb, p.HEARTBEAT.pack((c + 1) & 0xFFFFFFFF, t_us & 0xFFFFFFFF))
        if keep.any():
            self._counter = int(counters[keep][-1]) + 1
