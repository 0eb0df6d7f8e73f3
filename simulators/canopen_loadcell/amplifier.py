"""The CANopen load cell amplifier simulator: a ``canopen.LocalNode`` on python-can's ``virtual``
bus, from the same EDS file the driver reads (``config/canopen/loadcell.eds``).

The node's own SDO server (``canopen``) answers every SDO request from the object dictionary;
this module adds what the firmware does behind it: the gauge inputs read 12 channels of the
virtual lab's :class:`~dimacq.simulators.lab.source.SampleSource` (the strain-gauge bridges of
:mod:`dimacq.simulators.lab.bridge` on the dead-weight bench, or the lab's load cells), the
sample counter counts the pulses of the DAQ simulator's :class:`~dimacq.simulators.daq.clock.
SampleClock` (the SYNC cable, as for the CAN FD amplifier), NMT OPERATIONAL starts the stream
and PRE-OPERATIONAL stops it, every sample goes out as the TPDOs its mapping parameters say
(:class:`~dimacq.drivers.canopen_loadcell.protocol.PdoLayout` read from its own dictionary),
the heartbeat is the node's NMT heartbeat (``0x1017``), and EMCY frames carry the sample counter.

The TPDOs of a burst go out in order as one :meth:`SimVirtualBus.send_frames
<dimacq.simulators.virtual_can.SimVirtualBus.send_frames>` (about 1 µs a frame, not the 15 µs or
more of ``Network.send_message``): at PRE-OPERATIONAL the node sends the frames of every pulse
it counted before it answers the SDO read of the counter (``0x2102``) that follows, as a real
node's frames are on the bus before that answer, so the stop costs the backlog's bursts, not
a send per frame on the thread that answers SDO. On an adaptive DAQ clock it holds the clock
:data:`_MAX_BACKLOG` pulses ahead of what it sent (:meth:`SyncPulses._hold_clock`), so that
backlog stays bounded when the host is busy.

Faults (:class:`CanopenFaults`): TPDO frames not sent (bus overload), a bus-off period (nothing
sent, then the EMCY "recovered from bus-off"), the heartbeat stopped, EMCY at given samples,
and SDO writes of the calibration matrix refused while streaming (as the firmware does; a real
abort, not a fault switch).
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import canopen
import numpy as np
from canopen.sdo import SdoAbortedError

from dimacq.drivers.canopen_loadcell import protocol as p
from dimacq.simulators.daq.clock import SampleClock
from dimacq.simulators.lab.source import SampleSource
from dimacq.simulators.loadcell.pulses import BURST_S, SyncPulses
from dimacq.simulators.virtual_can import SimVirtualBus

__all__ = ["CanopenAmplifierSim", "CanopenFaults"]

log = logging.getLogger(__name__)

_CHUNK = 128
#: SYNC pulses an adaptive DAQ clock may run ahead of the frames sent (it waits there)
_MAX_BACKLOG = 16 * _CHUNK
_ABORT_STATE = 0x08000022  # data cannot be transferred because of the present device state
_ABORT_LENGTH = 0x06070010  # data type and length do not match


@dataclass
class CanopenFaults:
    """``dropped_frames``: sample counters whose second TPDO is not sent; ``bus_off``: (first
    sample, samples) during which the node is bus-off (nothing sent; then EMCY 0x8140);
    ``emcy_at``: sample counter → EMCY code sent with that sample; ``heartbeat_lost``: the
    heartbeat stops (set at any time, see :meth:`CanopenAmplifierSim.lose_heartbeat`);
    ``silent``: the node is not on the bus at all."""

    dropped_frames: set[int] = field(default_factory=set)
    bus_off: tuple[int, int] | None = None
    emcy_at: dict[int, int] = field(default_factory=dict)
    heartbeat_lost: bool = False
    silent: bool = False


class CanopenAmplifierSim(SyncPulses):
    """Simulated CANopen amplifier; a context manager (node, thread and bus closed on exit).

    Parameters
    ----------
    channel : str
        python-can ``virtual`` channel shared with the driver's bus.
    eds : path
        The amplifier's EDS file.
    source : SampleSource
    gauge_channels : sequence of 12 int
    clock : SampleClock, optional
        The DAQ's SYNC output (sample clock source 1).
    node_id, serial_number : int
    calibration_matrix : array_like (6, 12), optional
        In the amplifier's memory at power-on (default zeros).
    time_scale : float
        Simulation only: the internal clock runs this many times faster than the wall clock.
    faults : CanopenFaults, optional
    """

    def __init__(
        self,
        channel: str,
        eds: str | Path,
        source: SampleSource,
        gauge_channels: Sequence[int],
        *,
        clock: SampleClock | None = None,
        node_id: int = 1,
        serial_number: int = 501,
        calibration_matrix: Any = None,
        time_scale: float = 1.0,
        faults: CanopenFaults | None = None,
    ) -> None:
        if len(gauge_channels) != p.N_GAUGES:
            raise ValueError(f"give {p.N_GAUGES} gauge channels, got {len(gauge_channels)}")
        if time_scale <= 0:
            raise ValueError(f"time_scale {time_scale}: give a positive factor")
        self.source = source
        self.gauges = np.asarray(gauge_channels, dtype=np.intp)
        self.clock = clock
        self.time_scale = float(time_scale)
        self.faults = faults if faults is not None else CanopenFaults()
        self.matrix = (
            np.zeros((6, p.N_GAUGES))
            if calibration_matrix is None
            else np.array(calibration_matrix)
        )
        self.offsets = np.zeros(p.N_GAUGES)
        self.last_volts = np.zeros(p.N_GAUGES)
        self.streaming = False
        self._counter = 0  # samples labelled since NMT start
        self._world_internal = 0
        self._init_pulses(_CHUNK)
        self._bus_off_reported = False
        self._hb_stopped = False
        self._lock = threading.RLock()
        self._count_lock = threading.Lock()  # samples read ↔ counter, held briefly
        self._stop_evt = threading.Event()
        # the node's controller accepts NMT and its SDO requests: not the other amplifiers'
        # TPDOs on a shared channel, which its receive thread would take and drop one by one
        self._bus = SimVirtualBus(channel=channel, accept_ids=frozenset({0x000, 0x600 + node_id}))
        self.network = canopen.Network(self._bus)
        self.network.NOTIFIER_CYCLE = 0.1  # how long closing waits for the receive thread
        self.node = canopen.LocalNode(node_id, canopen.import_od(str(eds), node_id))
        self.node_id = node_id
        if not self.faults.silent:  # a silent node is not on the bus: nothing answers
            self.network.add_node(self.node)
        self.node.add_read_callback(self._on_read)
        self.node.add_write_callback(self._on_write)
        self._obj(p.IDENTITY)[4].raw = int(serial_number)
        self.layout = self._layout()
        self.rate_hz = float(self._obj(p.SAMPLE_RATE).raw)
        self.network.subscribe(0, self._on_nmt)
        self.network.connect()
        if not self.faults.silent:
            self.node.nmt.send_command(0x80)  # boot-up → PRE-OPERATIONAL, heartbeat starts
        self._thread = threading.Thread(target=self._run, name=f"canopen-sim-{channel}")
        self._thread.start()

    max_backlog = _MAX_BACKLOG

    def _obj(self, index: int) -> Any:
        """Object ``index`` of the node's own dictionary (read and written locally)."""
        return self.node.sdo[index]

    def _layout(self) -> p.PdoLayout:
        """The TPDO layout from the node's own mapping parameters (as the driver reads it)."""
        maps = []
        for k in range(6):
            com, mapping = self._obj(0x1800 + k), self._obj(0x1A00 + k)
            cob = int(com[1].raw)
            entries, offset = [], 0
            for sub in range(1, int(mapping[0].raw) + 1):
                v = int(mapping[sub].raw)
                e = p.MappedEntry(v >> 16, (v >> 8) & 0xFF, v & 0xFF, offset)
                entries.append(e)
                offset += e.bits
            maps.append((cob & 0x7FF, not cob & (1 << 31), entries))
        fs = float(self._obj(p.FULL_SCALE).raw)
        return p.PdoLayout.from_mappings(maps, full_scale_v=fs, where="simulator")

    # -- lifetime ----------------------------------------------------------------------------
    def close(self) -> None:
        self._stop_evt.set()
        if self.clock is not None:
            self.clock.notify()
        self._thread.join(timeout=5.0)
        self.node.nmt.stop_heartbeat()
        self.network.disconnect()

    def __enter__(self) -> CanopenAmplifierSim:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def lose_heartbeat(self) -> None:
        """The heartbeat stops from now on (the stream goes on)."""
        self.faults.heartbeat_lost = True
        self.node.nmt.stop_heartbeat()
        self._hb_stopped = True

    # -- object dictionary behaviour ------------------------------------------------------------
    def _on_read(self, index: int, subindex: int, od: Any) -> Any:
        if index == p.COUNTER:
            with self._count_lock:  # the count of the samples read from the bridges so far
                return self._counter & 0xFFFFFFFF
        if index == p.STATUS:
            missing = self._external and (self.clock is None or not self.clock.state().running)
            return p.STATUS_SYNC_MISSING if missing else 0
        if index == p.GAUGES and subindex >= 1:
            return int(np.rint(self.last_volts[subindex - 1] / self.layout.full_scale_v * 2**23))
        if index == p.LOADS and subindex >= 1:
            return float((self.matrix @ self.last_volts)[subindex - 1])
        if index == p.CALIBRATION_MATRIX:
            return p.matrix_to_blob(self.matrix)
        return None

    def _on_write(self, index: int, subindex: int, od: Any, data: bytes) -> None:
        if index in (p.CALIBRATION_MATRIX, p.CLOCK_SOURCE, p.SAMPLE_RATE, p.TARE) and (
            self.streaming
        ):
            raise SdoAbortedError(_ABORT_STATE)
        if index == p.CALIBRATION_MATRIX:
            if len(data) != 6 * p.N_GAUGES * 4:
                raise SdoAbortedError(_ABORT_LENGTH)
            self.matrix = p.matrix_from_blob(bytes(data))
        elif index == p.SAMPLE_RATE:
            rate = int.from_bytes(data, "little")
            if rate <= 0:
                raise SdoAbortedError(0x06090032)
            self.rate_hz = float(rate)
        elif index == p.TARE:
            n = max(1, int.from_bytes(data, "little"))
            pos = self._world_now()
            with self._source_lock():
                g = self.source.read(self.gauges, pos, n)
            self.offsets = g.mean(axis=1)
            if self.clock is None or not self._external:
                self._world_internal = pos + n

    def _on_nmt(self, can_id: int, data: bytearray, timestamp: float) -> None:
        state = self.node.nmt.state
        if state == "OPERATIONAL" and not self.streaming:
            self._arm()
        elif state != "OPERATIONAL" and self.streaming:
            with self._lock:
                self._send_pulses(final=True)
                self.streaming = False

    # -- clock ---------------------------------------------------------------------------------
    def _source_lock(self) -> Any:
        return self.clock.source_lock if self.clock is not None else self._lock

    def _world_now(self) -> int:
        if self.clock is not None and self._external:
            st = self.clock.state()
            return st.epoch + st.count
        return self._world_internal

    def _arm(self) -> None:
        with self._lock:
            external = int(self._obj(p.CLOCK_SOURCE).raw) == 1
            if external and self.clock is None:
                log.warning("node %d: SYNC clock source without a SYNC input", self.node_id)
            self._counter = 0
            self._bus_off_reported = False
            self._arm_pulses(external)
            self.streaming = True

    def _run(self) -> None:
        try:
            while not self._stop_evt.is_set():
                sent = 0
                with self._lock:
                    if self.streaming:
                        sent = self._send_pulses()
                if self.held_back:
                    self._stop_evt.wait(BURST_S)
                elif not sent:
                    if self.streaming and self.clock is not None and self._external:
                        self.clock.wait_change(self.clock.state(), 0.005)
                    else:
                        time.sleep(0.002)
                elif sent < _CHUNK:  # caught up: the next burst in BURST_S
                    self._stop_evt.wait(BURST_S)
        except Exception:  # pragma: no cover - surfaced through the driver's timeouts
            log.exception("CANopen load cell simulator thread failed")

    def _receivers_behind(self) -> bool:
        return self._bus.receivers_behind(self.layout.tpdos[0].cob_id)

    def _emit(self, pulse0: int, n: int) -> None:
        """Samples at pulses ``pulse0 .. pulse0 + n − 1`` as TPDOs (counter = pulse)."""
        world0 = self._world0()
        with self._count_lock:  # the counter says what was read (a load placed now is later)
            with self._source_lock():
                g = self.source.read(self.gauges, world0 + pulse0, n)
            self._counter = pulse0 + n
        if not self._external:
            self._world_internal = world0 + pulse0 + n
        volts = (g - self.offsets[:, None]).T
        self.last_volts = volts[-1].copy()
        counters = pulse0 + np.arange(n, dtype=np.int64)
        counts, _over = self.layout.counts_of(volts)
        frames = self.layout.encode(counters, counts)
        f = self.faults
        off_a, off_n = f.bus_off if f.bus_off is not None else (-1, 0)
        if f.silent:
            return
        tpdos = [(t.cob_id, k) for k, t in enumerate(self.layout.tpdos)]
        burst: list[tuple[int, bytes | bytearray, bool]] = []
        for i, c in enumerate(counters.tolist()):
            if off_a <= c < off_a + off_n:
                if not self._hb_stopped:
                    self._flush(burst)
                    self.node.nmt.stop_heartbeat()
                    self._hb_stopped = True
                continue
            if off_n and c >= off_a + off_n and not self._bus_off_reported:
                self._flush(burst)  # the frames before it first, in order
                self._bus_off_reported = True
                if not f.heartbeat_lost:
                    self.node.nmt.start_heartbeat(int(self._obj(p.HEARTBEAT_TIME).raw))
                    self._hb_stopped = False
                self.node.emcy.send(p.EMCY_BUS_OFF_RECOVERED, 0x11, p.emcy_data(c))
            if c in f.emcy_at:
                self._flush(burst)
                self.node.emcy.send(f.emcy_at[c], 0x01, p.emcy_data(c))
            dropped = c in f.dropped_frames
            burst.extend((cob, frames[k][i], False) for cob, k in tpdos if not (k == 1 and dropped))
        self._flush(burst)

    def _flush(self, burst: list[tuple[int, bytes | bytearray, bool]]) -> None:
        """Send the TPDO frames of ``burst`` in order as one burst, and empty it."""
        if burst:
            self._bus.send_frames(burst)
            burst.clear()
