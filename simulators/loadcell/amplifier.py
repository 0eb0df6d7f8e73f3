"""The load cell amplifier simulator on python-can's ``virtual`` interface.

A thread owns its own bus end (``can.Bus(interface="virtual", channel=...)``, sent through
:class:`~dimacq.simulators.virtual_can.SimVirtualBus`), answers the
control frames of :mod:`dimacq.drivers.loadcell.protocol` (the codec is all it shares with the
driver) and, once started, streams one CAN FD data frame per sample and a heartbeat every 256
samples (a burst of them at once, :meth:`SimVirtualBus.send_frames
<dimacq.simulators.virtual_can.SimVirtualBus.send_frames>`). Its 12 gauges read 12 channels of the virtual lab's
:class:`~dimacq.simulators.lab.source.SampleSource` (volts at the bridge outputs).

Clock: with SYNC (external clock, the normal case) it counts the pulses of the DAQ simulator's
:class:`~dimacq.simulators.daq.clock.SampleClock`: armed before the DAQ starts, its counter ``k``
is DAQ sample ``k`` and world sample ``clock.epoch + k``; it streams as the DAQ clocks samples.
Its heartbeat time comes from its own oscillator (the true time of the pulse, plus a configurable
ppm error). With the internal clock it paces itself on the wall clock.

Faults for tests (:class:`LoadCellFaults`): data frames not sent (bus overload: a counter gap),
SYNC pulses missed at given pulses (the counter falls behind the DAQ: drift), and a silent node.
At random (seeded; each one logged on :data:`~dimacq.simulators.imperfections.fault_log`): CAN
frames lost (``frame_loss_rate`` per data frame), and **bus-off** (``bus_off_rate`` per second of
streamed pulses, at pulses drawn from the seed whatever the thread's timing): the node's transmit error counter passes 255, it leaves the bus for
``bus_off_s`` wall seconds (sends nothing, hears no command) and then recovers by itself
(ISO 11898-1 auto-recovery) and goes on; it kept counting SYNC pulses meanwhile, so the host sees
a counter gap, not a shift.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import can
import numpy as np

from dimacq.drivers.loadcell import protocol as p
from dimacq.errors import ProtocolError
from dimacq.simulators.daq.clock import SampleClock
from dimacq.simulators.imperfections import fault_log
from dimacq.simulators.lab.source import SampleSource
from dimacq.simulators.loadcell.pulses import BURST_S, SyncPulses
from dimacq.simulators.virtual_can import SimVirtualBus

__all__ = ["LoadCellAmplifierSim", "LoadCellFaults"]

log = logging.getLogger(__name__)

_CHUNK = 256
#: SYNC pulses the simulator may fall behind the DAQ clock before their frames are dropped
_MAX_BACKLOG = 128 * _CHUNK


@dataclass
class LoadCellFaults:
    """``dropped_samples``: counters whose data frame is not sent; ``missed_pulses``: pulse
    index → number of SYNC pulses the counter misses there; ``silent``: answer nothing."""

    dropped_samples: set[int] = field(default_factory=set)
    missed_pulses: dict[int, int] = field(default_factory=dict)
    silent: bool = False
    #: per data frame: probability it is lost on the bus
    frame_loss_rate: float = 0.0
    #: per second of streamed pulses: probability the node goes bus-off
    bus_off_rate: float = 0.0
    #: wall seconds until it has recovered
    bus_off_s: float = 0.1
    #: seed of the random faults
    seed: int = 0


class LoadCellAmplifierSim(SyncPulses):
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
    time_scale : float
        Simulation only: the internal clock runs this many times faster than the host's wall
        clock (a dead-weight calibration's minutes of settling in seconds). SYNC is unaffected.
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
        time_scale: float = 1.0,
        faults: LoadCellFaults | None = None,
    ) -> None:
        if time_scale <= 0:
            raise ValueError(f"time_scale {time_scale}: give a positive factor")
        self.time_scale = float(time_scale)
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
        self.rng = np.random.default_rng([self.faults.seed, node_id])
        self._bus_off_until = 0.0
        # bus-offs at pulses streamed drawn from their own stream of the seed (exponential
        # spacing, mean rate_hz / bus_off_rate pulses), not a draw per burst: where they fall
        # does not depend on how the thread happened to split the stream
        self._bus_rng = np.random.default_rng([self.faults.seed, node_id, 1])
        self._streamed = 0  # pulses streamed since creation, every run
        self._next_bus_off: float | None = None
        #: faults injected so far, by kind
        self.injected: dict[str, int] = {}
        self.rate_hz = float(source.sample_rate_hz)
        self.offsets = np.zeros(p.N_GAUGES)
        self.state = 0
        self._init_pulses(_CHUNK)
        self._counter = 0  # next counter value to send
        self._world_internal = 0  # next world sample on the internal clock
        self._download: dict[int, bytes] = {}
        self._download_len = 0
        self._stop_evt = threading.Event()
        self._lock = threading.Lock()
        # its CAN controller accepts its command frames only (hardware acceptance filter)
        self.bus = SimVirtualBus(channel=channel, fd=True, accept_ids=[p.command_id(node_id)])
        self._thread = threading.Thread(target=self._run, name=f"loadcell-sim-{channel}")
        self._thread.start()

    # -- lifetime ----------------------------------------------------------------------------
    def close(self) -> None:
        self._stop_evt.set()
        if self.clock is not None:
            self.clock.hold_at(f"amplifier-{id(self)}", None)
            self.clock.notify()
        self._thread.join(timeout=5.0)
        self.bus.shutdown()

    def __enter__(self) -> LoadCellAmplifierSim:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- thread ------------------------------------------------------------------------------
    def _run(self) -> None:
        next_burst = 0.0
        try:
            while not self._stop_evt.is_set():
                wait = max(0.0, next_burst - time.monotonic()) if self.state == 2 else 0.005
                msg = self.bus.recv(wait)
                if msg is not None and msg.arbitration_id == p.command_id(self.node):
                    if not self.faults.silent and not self._bus_off():
                        self._handle(bytes(msg.data))
                    continue
                if self.state == 2 and time.monotonic() >= next_burst:
                    sent = self._send_pulses()
                    if self.held_back:
                        next_burst = time.monotonic() + BURST_S
                    elif not sent:
                        self._wait_for_clock(0.005)
                    elif sent < _CHUNK:  # caught up: the next burst in BURST_S or more
                        next_burst = time.monotonic() + self._burst_s()
        except Exception:  # pragma: no cover - surfaced through the test's timeouts
            log.exception("load cell simulator thread failed")

    def _wait_for_clock(self, timeout_s: float) -> None:
        if self.clock is not None and self._external:
            self.clock.wait_change(self.clock.state(), timeout_s)
        else:
            time.sleep(timeout_s / 5)

    def _bus_off(self) -> bool:
        return time.monotonic() < self._bus_off_until

    def _inject(self, kind: str, message: str, *args: Any) -> None:
        self.injected[kind] = self.injected.get(kind, 0) + 1
        fault_log.warning("simulated fault %s: node %d " + message, kind, self.node, *args)

    def _send(self, aid: int, data: bytes, fd: bool = False) -> None:
        if self._bus_off():
            return
        self.bus.send(can.Message(arbitration_id=aid, data=data, is_extended_id=False, is_fd=fd))

    def _reply(self, msg: p.Reply) -> None:
        self._send(p.response_id(self.node), msg.encode())

    def _error(self, op: int, code: p.ErrorCode) -> None:
        self._reply(p.ErrorReply(op, int(code)))

    #: commands answered in any state; the others are refused (busy) while armed or streaming
    _ANY_STATE = (p.Identify, p.GetStatus, p.Stop)

    def _handle(self, d: bytes) -> None:
        op = d[0]
        kind = p.REQUESTS.get(op)
        if self.state != 0 and kind not in self._ANY_STATE:
            self._error(op, p.ErrorCode.BUSY)
            return
        try:
            req = p.decode_request(d)
        except p.BadMessage as err:
            self._error(op, err.code)
            return
        match req:
            case p.Identify():
                self._reply(p.IdentifyReply(p.N_GAUGES, 1, 0, self.serial_number))
            case p.GetStatus():
                flags = 0
                if self._external and (self.clock is None or not self.clock.state().running):
                    flags |= p.STATUS_SYNC_MISSING
                self._reply(p.StatusReply(self.state, flags, self._counter & 0xFFFFFFFF))
            case p.Stop():
                self._send_pulses(final=True)
                self.state = 0
                if self.clock is not None:
                    self.clock.hold_at(f"amplifier-{id(self)}", None)
                self._reply(p.StopReply(self._counter & 0xFFFFFFFF))
            case p.Start(clock=clock):
                self._arm(external=clock == 1)
                self._reply(p.StartReply())
            case p.SetRate(rate_hz=rate):
                self.rate_hz = float(rate)
                self._reply(p.SetRateReply(rate))
            case p.Tare(n_samples=n):
                pos = self._world_now()
                with self._source_lock():
                    g = self.source.read(self.gauges, pos, max(1, n))
                self.offsets = g.mean(axis=1)
                if self.clock is None or not self._external:
                    self._world_internal = pos + max(1, n)
                self._reply(p.TareReply())
            case p.CalDownloadBegin(n_bytes=n_bytes):
                self._download_len = n_bytes
                self._download = {}
                self._reply(p.CalDownloadBeginReply())
            case p.CalSegment(index=i, data=seg):
                self._download[i] = seg
            case p.CalDownloadEnd(crc32=crc):
                try:
                    blob = p.join_segments(self._download, self._download_len)
                except p.BadMessage as err:
                    self._error(op, err.code)
                    return
                if p.blob_crc(blob) != crc:
                    self._error(op, p.ErrorCode.CRC_MISMATCH)
                    return
                try:
                    self.matrix = p.matrix_from_blob(blob)
                except ProtocolError:
                    self._error(op, p.ErrorCode.BAD_ARGUMENT)
                    return
                self._reply(p.CalDownloadEndReply())
            case p.CalUpload():
                blob = p.matrix_to_blob(self.matrix)
                self._reply(p.CalUploadReply(len(blob), p.blob_crc(blob)))
                for i, seg in enumerate(p.segments(blob)):
                    self._reply(p.CalUploadSegment(i, seg))
            case _:  # pragma: no cover - every request of the table has its case
                self._error(op, p.ErrorCode.UNKNOWN_COMMAND)

    def _source_lock(self) -> Any:
        return self.clock.source_lock if self.clock is not None else self._lock

    def _world_now(self) -> int:
        if self.clock is not None and self._external:
            st = self.clock.state()
            return st.epoch + st.count
        return self._world_internal  # on its own clock the world goes on from its last read

    def _arm(self, external: bool) -> None:
        if external and self.clock is None:
            raise RuntimeError("external clock requested but no SampleClock wired")
        self._counter = 0
        self._arm_pulses(external)
        self.state = 2

    max_backlog = _MAX_BACKLOG

    def _receivers_behind(self) -> bool:
        return self.bus.receivers_behind(p.data_id(self.node))

    def _drop_backlog(self, avail: int) -> None:
        if self._external and avail - self._pulses > _MAX_BACKLOG:
            # A real amplifier cannot queue seconds of frames: the bus is saturated and they are
            # dropped (a counter gap). Here the simulator thread got too little CPU to keep up.
            skip = avail - self._pulses - _MAX_BACKLOG
            self._inject("can_overload", "fell %d pulses behind SYNC; their frames dropped", skip)
            self._pulses += skip

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
        world0 = self._world0()
        with self._source_lock():
            g = self.source.read(self.gauges, world0 + pulse0, n)
        if not self._external:
            self._world_internal = world0 + pulse0 + n
        g = (g - self.offsets[:, None]).T
        keep = ~is_missed
        frames, _ = p.encode_data_frames(counters[keep], g[keep])
        aid = p.data_id(self.node)
        hb = p.heartbeat_id(self.node)
        flt = self.faults
        if flt.bus_off_rate:
            mean = self.rate_hz / flt.bus_off_rate
            if self._next_bus_off is None:
                self._next_bus_off = float(self._bus_rng.exponential(mean))
            if self._next_bus_off < self._streamed + n:  # one bus-off per burst at most
                self._bus_off_until = time.monotonic() + flt.bus_off_s
                self._inject(
                    "can_bus_off", "goes bus-off for %g s at pulse %d", flt.bus_off_s, pulse0
                )
                self._next_bus_off = max(
                    self._next_bus_off + float(self._bus_rng.exponential(mean)),
                    float(self._streamed + n),
                )
        self._streamed += n
        lost = np.zeros(n, dtype=bool)
        if flt.frame_loss_rate:
            lost = self.rng.random(n) < flt.frame_loss_rate
        if self._bus_off():  # off the bus: the burst is not sent (the counter goes on)
            self._counter = int(counters[keep][-1]) + 1 if keep.any() else self._counter
            return
        kc, kq, kl = counters[keep], pulses[keep], lost[keep]
        for c in kc[kl].tolist():
            self._inject("can_frame_loss", "data frame of counter %d lost on the bus", c)
        send = ~kl
        if self.faults.dropped_samples:
            send &= ~np.isin(kc, np.fromiter(self.faults.dropped_samples, np.int64))
        # heartbeats after the frames of counters c with (c + 1) % HEARTBEAT_EVERY == 0: the
        # counter reached, and the true time of that pulse on the amplifier's oscillator
        beat = (kc + 1) % p.HEARTBEAT_EVERY == 0
        scale_us = 1e6 / self.rate_hz * (1 + self.oscillator_ppm * 1e-6)
        beats = {
            int(c): p.Heartbeat(int(c) + 1, round((int(q) + 1) * scale_us)).encode()
            for c, q in zip(kc[beat], kq[beat], strict=True)
        }
        out: list[tuple[int, bytes | bytearray, bool]] = []
        for c, f, s in zip(kc.tolist(), frames, send.tolist(), strict=True):
            if s:
                out.append((aid, f, True))
            if c in beats:
                out.append((hb, beats[c], False))
        self.bus.send_frames(out)
        if keep.any():
            self._counter = int(counters[keep][-1]) + 1
