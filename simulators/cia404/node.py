"""A generic CiA 404 amplifier node and the rig's SYNC producer, on python-can's ``virtual`` bus.

:class:`Cia404NodeSim` is a ``canopen.LocalNode`` built from the amplifier's EDS (the generic
``config/canopen/cia404-generic.eds``): ``canopen``'s SDO server answers every SDO request from
that dictionary (so the master's mapping writes land in the node's own 0x1800/0x1A00 objects),
its NMT slave follows the master's NMT commands and sends the heartbeat (0x1017). What the
firmware adds: on each SYNC, when OPERATIONAL, the node samples its inputs (channels of the
virtual lab's :class:`~dimacq.simulators.lab.source.SampleSource`, in the lab's own units) and
answers with every valid synchronous TPDO, packed as **its own** mapping parameters say
(0x6130 REAL32, 0x7130 INTEGER16 × 10^digits of 0x6132). It knows nothing of the DAQ, the host
or the calibration: only its dictionary and the SYNCs it hears.

**Its own sampling.** Its ADC runs free on its own clock at the rate its dictionary holds
(0x6114, in Hz as the generic EDS declares it; its phase at power-on drawn from its node id),
each input through its filter (0x61A0 = 1: the mean of its last 0x61A1 samples; 0: none) and its
scaling (0x6126 × value + 0x6127); a SYNC sends the last filtered value, not a sample taken at
the SYNC (:mod:`~dimacq.simulators.lab.held`). Without 0x6114 in its EDS it samples at the SYNC. Faults: EMCY codes at given SYNCs
(sent with that sample, CiA 301 layout: code, error register, 5 bytes), and an NMT state it falls
into by itself at a given SYNC (e.g. PRE-OPERATIONAL after an internal error).

:class:`SyncProducerSim` is the rig's SYNC producer wired to the DAQ's sample clock (the
simulated DAQ's :class:`~dimacq.simulators.daq.clock.SampleClock`): on pulse ``k`` of a DAQ run it
puts a SYNC on the bus, then the synchronous TPDOs the nodes send for it, in identifier order
(bus arbitration), before the next SYNC — the window CiA 301 gives synchronous PDOs. The SYNC's
time on the wire (world sample ``epoch + k``) is when each node samples; the nodes learn it from
the SYNC, nothing else. While a receiver on the bus is too far behind
(:meth:`~dimacq.simulators.virtual_can.SimVirtualBus.receivers_behind`) it sends nothing, and an
adaptive DAQ clock is held at the last SYNC sent (at most :data:`_MAX_BACKLOG` past it
otherwise): a simulated test on a host that cannot carry the time-lapse slows down instead of
falling ever further behind the DAQ.
"""

from __future__ import annotations

import logging
import struct
import threading
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import can
import canopen
import numpy as np
from numpy.typing import NDArray

from dimacq.drivers.cia404 import protocol as p
from dimacq.simulators.daq.clock import SampleClock
from dimacq.simulators.lab.held import held_sample, read_between
from dimacq.simulators.lab.source import SampleSource
from dimacq.simulators.loadcell.pulses import BURST_S
from dimacq.simulators.virtual_can import SimVirtualBus

__all__ = ["Cia404Faults", "Cia404NodeSim", "SyncProducerSim"]

log = logging.getLogger(__name__)

_CHUNK = 128
#: SYNCs an adaptive DAQ clock may count past those the producer has sent: past it the DAQ
#: waits for the bus (:meth:`SampleClock.hold_at`), as it waits for the amplifiers
_MAX_BACKLOG = 16 * _CHUNK
_OPERATIONAL = "OPERATIONAL"


@dataclass
class Cia404Faults:
    """``emcy_at``: SYNC number of a run (0-based, counted from OPERATIONAL) → EMCY code sent
    with that sample; ``nmt_at``: SYNC number → NMT command the node applies to itself then
    (0x80: falls back to PRE-OPERATIONAL); ``silent``: not on the bus."""

    emcy_at: dict[int, int] = field(default_factory=dict)
    nmt_at: dict[int, int] = field(default_factory=dict)
    silent: bool = False


class Cia404NodeSim:
    """A simulated generic CiA 404 amplifier node (see the module docstring).

    Parameters
    ----------
    channel : str
        python-can virtual channel.
    eds : path
    source : SampleSource
    inputs : sequence of int
        Source channels wired to inputs 1..n.
    node_id, serial_number : int
    identity : dict, optional
        Values written over the EDS's defaults (``{0x1000: ..., (0x1018, 2): ...}``): a node of
        another kind than the EDS the host reads.
    """

    def __init__(
        self,
        channel: str,
        eds: str | Path,
        source: SampleSource,
        inputs: Sequence[int],
        *,
        node_id: int = 1,
        serial_number: int = 0,
        identity: dict[Any, int] | None = None,
        faults: Cia404Faults | None = None,
        hear_sync: bool = False,
    ) -> None:
        self.source = source
        self.inputs = np.asarray(inputs, dtype=np.intp)
        self.node_id = node_id
        self.faults = faults if faults is not None else Cia404Faults()
        # the node's controller accepts NMT and its SDO requests; SYNC comes through on_sync
        # from the producer on the DAQ's clock, or (hear_sync) from the bus: a host's SYNC,
        # sampled on the node's own clock (one sample per SYNC from world sample 0)
        accept = {0x000, 0x600 + node_id} | ({p.SYNC_COB_ID} if hear_sync else set())
        self.network = canopen.Network(SimVirtualBus(channel=channel, accept_ids=frozenset(accept)))
        self._own_world = 0
        self.network.NOTIFIER_CYCLE = 0.1
        self.node = canopen.LocalNode(node_id, canopen.import_od(str(eds), node_id))
        if not self.faults.silent:
            self.network.add_node(self.node)
        self._od: Any = self.node.sdo  # the node's own dictionary, read and written locally
        od: Any = self.node.sdo
        od[p.IDENTITY][4].raw = int(serial_number) & 0xFFFFFFFF
        for key, value in (identity or {}).items():
            obj = od[key] if isinstance(key, int) else od[key[0]][key[1]]
            obj.raw = value
        n_in = int(od[0x6130][0].raw) if 0x6130 in self.node.object_dictionary else 0
        if len(self.inputs) > max(n_in, 1):
            raise ValueError(f"{len(self.inputs)} inputs wired, the EDS has {n_in}")
        self._phase = float(np.random.default_rng([0x404, node_id]).random())
        self._lock = threading.Lock()
        self._deferred_nmt: int | None = None
        self._syncs = 0  # SYNCs heard while OPERATIONAL (this run)
        self._was_operational = False
        self._layout: list[tuple[int, list[tuple[int, int, int]]]] = []
        self.last_values = np.zeros(len(self.inputs))
        self.network.connect()
        if hear_sync:
            self.network.subscribe(p.SYNC_COB_ID, self._on_bus_sync)
        self.node.add_read_callback(self._on_read)
        if not self.faults.silent:
            self.node.nmt.send_command(0x80)  # boot-up → PRE-OPERATIONAL, heartbeat per 0x1017

    # -- lifetime ----------------------------------------------------------------------------
    def close(self) -> None:
        self.node.nmt.stop_heartbeat()
        self.network.disconnect()

    def __enter__(self) -> Cia404NodeSim:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    @property
    def state(self) -> str:
        return str(self.node.nmt.state)

    # -- dictionary ------------------------------------------------------------------------------
    def _on_read(self, index: int, subindex: int, od: Any) -> Any:
        """Process values read by SDO: the last sample taken."""
        if index in (p.REAL32_PV.index, p.INT16_PV.index) and 1 <= subindex <= len(self.inputs):
            v = float(self.last_values[subindex - 1])
            if index == p.INT16_PV.index:
                digits = int(self._od[p.AI_DECIMAL_DIGITS][subindex].raw)
                return int(np.clip(np.rint(v * 10**digits), -32768, 32767))
            return v
        return None

    def _own(self, index: int, default: float) -> float:
        if index not in self.node.object_dictionary:
            return default
        return float(self._od[index][1].raw)

    def _sampled(self, world0: int, n: int) -> NDArray[np.float64]:
        """What it sends at SYNCs at world samples ``world0 ..``: its last filtered, scaled
        values, shape (n, inputs)."""
        if n == 0:
            return np.zeros((0, len(self.inputs)))
        x = world0 + np.arange(n, dtype=float)
        if p.AI_ADC_SAMPLE_RATE not in self.node.object_dictionary:
            raw = self.source.read(self.inputs, world0, n).T
        else:
            per_world = self._own(p.AI_ADC_SAMPLE_RATE, 1.0) / self.source.sample_rate_hz
            kind = int(self._own(p.AI_FILTER_TYPE, 0))
            taps = int(self._own(p.AI_FILTER_CONSTANT, 1)) if kind == p.FILTER_MOVING_AVERAGE else 1
            taps = max(taps, 1)
            _, m = held_sample(x, per_world, self._phase)
            own = (m[:, None] - np.arange(taps)[None, :] + self._phase) / per_world  # (n, taps)
            g = read_between(self.source, self.inputs, np.asarray(own.ravel(), float), self._lock)
            raw = g.reshape(len(self.inputs), n, taps).mean(axis=2).T
        return raw * self._own(p.AI_SCALING_FACTOR, 1.0) + self._own(p.AI_SCALING_OFFSET, 0.0)

    def _read_layout(self) -> list[tuple[int, list[tuple[int, int, int]]]]:
        """Valid synchronous TPDOs from the node's own 0x1800/0x1A00: (COB-ID, entries)."""
        od: Any = self.node.sdo
        out = []
        k = 0
        while p.TPDO_COMM + k in self.node.object_dictionary:
            cob = int(od[p.TPDO_COMM + k][1].raw)
            ttype = int(od[p.TPDO_COMM + k][2].raw)
            mapping = od[p.TPDO_MAP + k]
            n = int(mapping[0].raw)
            k += 1
            if cob & p.COB_ID_INVALID or not 0 <= ttype <= 240 or n == 0:
                continue  # not valid, or event-driven: nothing on SYNC
            entries = []
            for s in range(1, n + 1):
                v = int(mapping[s].raw)
                entries.append((v >> 16, (v >> 8) & 0xFF, v & 0xFF))
            out.append((cob & 0x7FF, entries))
        return sorted(out)  # sent in identifier order (arbitration)

    def _pack(
        self, entries: list[tuple[int, int, int]], values: NDArray[np.float64]
    ) -> list[bytes]:
        """Payloads of one TPDO for ``values`` (n, inputs), as its mapping entries say."""
        n = values.shape[0]
        cols = []
        for index, sub, bits in entries:
            v = values[:, sub - 1] if 1 <= sub <= values.shape[1] else np.zeros(n)
            if index == p.REAL32_PV.index and bits == 32:
                cols.append(np.ascontiguousarray(v, dtype="<f4").view(np.uint8).reshape(n, 4))
            elif index == p.INT16_PV.index and bits == 16:
                digits = int(self._od[p.AI_DECIMAL_DIGITS][sub].raw)
                iv = np.clip(np.rint(v * 10**digits), -32768, 32767).astype("<i2")
                cols.append(iv.view(np.uint8).reshape(n, 2))
            else:  # an object this firmware does not sample: zeros of its length
                cols.append(np.zeros((n, bits // 8), dtype=np.uint8))
        raw = np.concatenate(cols, axis=1)
        return [bytes(r) for r in raw]

    # -- SYNC --------------------------------------------------------------------------------------
    def _on_bus_sync(self, can_id: int, data: bytearray, timestamp: float) -> None:
        """A SYNC heard on the bus: this sample's frames sent at once (its own clock)."""
        (frames,) = self.on_sync(self._own_world, 1)
        self._own_world += 1
        for cob, payload in frames:
            self.network.send_message(cob, payload)
        self.settle()

    def on_sync(self, world0: int, n: int) -> list[list[tuple[int, bytes]]]:
        """``n`` SYNCs at world samples ``world0 ..``: per SYNC, the frames the node sends."""
        empty: list[list[tuple[int, bytes]]] = [[] for _ in range(n)]
        if self.faults.silent:
            return empty
        operational = self.state == _OPERATIONAL
        if operational and not self._was_operational:
            self._syncs = 0
            self._layout = self._read_layout()  # PDO parameters latched on entering OPERATIONAL
        self._was_operational = operational
        if not operational:
            return empty
        # a fault that takes the node out of OPERATIONAL within these SYNCs cuts them short
        first = self._syncs
        cut = n
        for s in self.faults.nmt_at:
            if first <= s < first + n:
                cut = min(cut, s - first)
        values = self._sampled(world0, n)
        if n:
            self.last_values = values[max(cut - 1, 0)].copy()
        out = empty
        for cob, entries in self._layout:
            payloads = self._pack(entries, values[:cut])
            for j, d in enumerate(payloads):
                out[j].append((cob, d))
        for s, code in self.faults.emcy_at.items():
            if first <= s < first + cut:
                data = struct.pack("<HB5s", code, 0x01, b"\0" * 5)
                out[s - first].append((p.emcy_cob_id(self.node_id), data))
        self._syncs = first + n
        if cut < n:
            # taken once the frames before it are on the bus (:meth:`settle`)
            self._deferred_nmt = next(c for s, c in self.faults.nmt_at.items() if s == first + cut)
            self._was_operational = False
        return out

    def settle(self) -> None:
        """After the frames of :meth:`on_sync` are sent: the NMT state a fault left it in."""
        cmd, self._deferred_nmt = self._deferred_nmt, None
        if cmd is not None:
            self.node.nmt.send_command(cmd)


class SyncProducerSim:
    """The rig's SYNC producer on the DAQ's sample clock, with the nodes that answer it.

    Parameters
    ----------
    channel : str
    clock : SampleClock
    nodes : sequence of Cia404NodeSim
    """

    def __init__(self, channel: str, clock: SampleClock, nodes: Sequence[Cia404NodeSim]) -> None:
        self.clock = clock
        self.nodes = list(nodes)
        self.sent = 0  # SYNCs of this run
        self._run = -1
        self._stop_evt = threading.Event()
        self.bus = SimVirtualBus(channel=channel, accept_ids=frozenset())  # it only sends
        self._thread = threading.Thread(target=self._loop, name=f"cia404-sync-{channel}")
        self._thread.start()

    def close(self) -> None:
        self._stop_evt.set()
        self.clock.notify()
        self._thread.join(timeout=5.0)
        self.bus.shutdown()

    def __enter__(self) -> SyncProducerSim:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _pulses(self) -> int:
        """SYNCs for the DAQ's pulses not yet sent, and the nodes' answers (one chunk)."""
        st = self.clock.state()
        if st.run != self._run:
            if not st.running and st.count == 0:
                return 0
            self._run, self.sent = st.run, 0
        n = min(st.count - self.sent, _CHUNK)
        if n <= 0:
            return 0
        world0 = st.epoch + self.sent
        with self.clock.source_lock:
            answers = [node.on_sync(world0, n) for node in self.nodes]
        send, Msg = self.bus.send, can.Message
        sync = Msg(arbitration_id=p.SYNC_COB_ID, data=b"", is_extended_id=False)
        one = len(answers) == 1  # one node: its TPDOs are already in identifier order
        for j in range(n):
            send(sync)
            # arbitration: the lowest identifier first
            frames = answers[0][j] if one else sorted(f for a in answers for f in a[j])
            for cob, data in frames:
                send(Msg(arbitration_id=cob, data=data, is_extended_id=False))
        for node in self.nodes:
            node.settle()
        self.sent += n
        return n

    def _hold_clock(self, ahead: int) -> None:
        """Tell an adaptive DAQ clock it may count at most ``ahead`` pulses past the SYNCs sent
        in this run: a simulated bus slower than the clock (a busy host, a high time-lapse)
        slows the clock down instead of falling ever further behind it. A fixed clock, as a
        real DAQ's, ignores the limit."""
        st = self.clock.state()
        if st.run == self._run and st.running:
            self.clock.hold_at(self._hold_key, self.sent + ahead)

    @property
    def _hold_key(self) -> str:
        return f"cia404-sync-{id(self)}"

    def _loop(self) -> None:
        try:
            while not self._stop_evt.is_set():
                if self.bus.receivers_behind():
                    # the pulses wait while a receiver holds too many frames, so the answer
                    # to the host's next SDO request is not queued behind seconds of them;
                    # an adaptive DAQ clock waits with them at the last SYNC sent
                    self._hold_clock(ahead=0)
                    self._stop_evt.wait(BURST_S)
                    continue
                sent = self._pulses()
                self._hold_clock(ahead=_MAX_BACKLOG)
                if sent == 0:
                    self.clock.wait_change(self.clock.state(), BURST_S)
                elif sent < _CHUNK:
                    self._stop_evt.wait(BURST_S)
        except Exception:  # pragma: no cover - surfaced through the driver's timeouts
            log.exception("CiA 404 SYNC producer simulator failed")
