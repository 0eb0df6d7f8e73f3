"""Driver of a CANopen 6-DOF load cell amplifier through ``canopen`` (python-can bus injected).

The amplifier is a CiA 301 node described by its EDS file (``config/canopen/loadcell.eds``,
objects in :mod:`dimacq.drivers.canopen_loadcell.protocol`); the driver is the
:class:`~dimacq.devices.loadcell.LoadCell` of :mod:`dimacq.devices` over it::

    bus = can.Bus(interface="pcan", channel="PCAN_USBBUS1", bitrate=1_000_000)  # or "virtual"
    cell = CanopenLoadCell(bus, node_id=5, eds="config/canopen/loadcell.eds")

- **PDO mapping read from the node** (:meth:`read_mapping`, at open): the TPDO communication and
  mapping parameters through SDO (``canopen``'s ``PdoMap.read``); the decoder is built from what
  the node says (which TPDO carries which gauge at which offset), never assumed.
- **NMT**: :meth:`start` writes the clock source and puts the node OPERATIONAL (the stream
  starts); :meth:`stop` puts it PRE-OPERATIONAL and reads the pulses it counted.
- **Aligned on SYNC as the CAN FD driver**: the amplifier counts the DAQ's SYNC pulses (its
  sample clock) and labels every TPDO with the count's low word; frames are filed by that label,
  unwrapped per TPDO, in the shared :class:`~dimacq.drivers.stream.CounterStream`. A sample
  with a frame missing is NaN and not valid (``gap`` event), and :meth:`verify_count` compares
  the pulses counted with the DAQ's samples after both stopped (``drift`` event).
- **EMCY and heartbeat loss** are ``device_error`` events naming the node: an EMCY invalidates
  the sample it names (so the average containing it is rejected, not silently kept); a node
  whose heartbeat is older than ``heartbeat_factor`` periods is reported lost (once per loss)
  and back when it returns.
- **SDO aborts** become one-line :class:`~dimacq.errors.DeviceError`\\ s naming the object
  (``calibration matrix (0x2200:00)``), its abort code and text.
- **Calibration**: :meth:`download_calibration` writes the 6×12 matrix (REAL32, one segmented
  SDO transfer) and :meth:`upload_calibration` reads it back.

Public methods own timeouts and logging (:class:`~dimacq.drivers.base.WireDriver`); the wire
steps are ``canopen``'s SDO client and NMT master, and the frame callback of the network.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar

import can
import canopen
import numpy as np
from canopen.sdo import SdoAbortedError, SdoCommunicationError
from numpy.typing import NDArray

from dimacq.devices.loadcell import LoadCellBlock, LoadCellEvent, LoadCellIdentity
from dimacq.drivers.base import Deadline, WireDriver
from dimacq.drivers.canopen_loadcell import protocol as p
from dimacq.drivers.loadcell.counting import SyncCounting, unwrap_u32
from dimacq.drivers.stream import CounterStream, false_runs
from dimacq.errors import (
    DeviceError,
    DeviceStateError,
    DeviceTimeoutError,
    ProtocolError,
    SetupError,
)

__all__ = ["CanopenLoadCell"]

log = logging.getLogger(__name__)

T = TypeVar("T")

#: abort codes that mean "not now" (the device's state) rather than "not ever"
_STATE_ABORTS = {0x08000021, 0x08000022}


def _new_samples() -> CounterStream[LoadCellEvent]:
    return CounterStream(p.N_GAUGES, flag_shape=(), flag_dtype=np.uint8)


class _Assembly:
    """Gauges of samples not yet complete, by counter: frames of one sample arrive as several
    TPDOs; a sample is taken when all 12 gauges are in (else it reads lost)."""

    def __init__(self) -> None:
        self.base = 0
        self.data = np.full((0, p.N_GAUGES), np.nan)
        self.have = np.zeros((0, p.N_GAUGES), dtype=bool)

    def put(self, counters: NDArray[np.int64], gauges: list[int], volts: NDArray[np.float64]):
        keep = counters >= self.base
        counters, volts = counters[keep], volts[keep]
        if counters.size == 0:
            return
        need = int(counters.max()) - self.base + 1
        if need > self.data.shape[0]:
            grow = max(need, 2 * self.data.shape[0], 1024) - self.data.shape[0]
            self.data = np.concatenate([self.data, np.full((grow, p.N_GAUGES), np.nan)])
            self.have = np.concatenate([self.have, np.zeros((grow, p.N_GAUGES), dtype=bool)])
        rows = counters - self.base
        cols = np.asarray(gauges, dtype=np.intp)
        self.data[rows[:, None], cols[None, :]] = volts
        self.have[rows[:, None], cols[None, :]] = True

    def take(self, end: int) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
        """Complete samples below ``end`` (counters, volts (n, 12)); drops everything below."""
        m = max(0, min(end - self.base, self.data.shape[0]))
        idx = np.flatnonzero(self.have[:m].all(axis=1))
        out = (self.base + idx.astype(np.int64), self.data[idx].copy())
        self.data, self.have = self.data[m:], self.have[m:]
        self.base = max(self.base, end)
        return out


class CanopenLoadCell(SyncCounting, WireDriver):
    """One CANopen load cell amplifier.

    Parameters
    ----------
    bus : can.BusABC
        Injected (classic CAN); the driver does not shut it down.
    node_id : int
    eds : path
        The amplifier's EDS file.
    timeout_s : float
        SDO response timeout and default wait of a read.
    calibration_matrix : array_like (6, 12), optional
        Applied to the gauges (``F = C g``).
    heartbeat_ms : int
        Producer heartbeat time written to the node (``0x1017``).
    heartbeat_factor : float
        Periods without a heartbeat after which the node is reported lost.
    bitrate : int
        The bus's bit rate (bit/s): what the stream's bus load is computed against.
    label : str
        How messages name the cell besides its node id (e.g. "load cell 501").
    """

    reopen_hint = "open the load cell again (its backend)"

    def __init__(
        self,
        bus: can.BusABC,
        *,
        node_id: int,
        eds: str | Path,
        timeout_s: float = 1.0,
        calibration_matrix: Any = None,
        heartbeat_ms: int = 100,
        heartbeat_factor: float = 3.0,
        bitrate: int = 1_000_000,
        label: str = "",
    ) -> None:
        if not 1 <= node_id <= 127:
            raise SetupError(f"CANopen node id {node_id}: give 1..127 as set on the amplifier")
        what = f"CANopen load cell amplifier node {node_id}" + (f" ({label})" if label else "")
        super().__init__(what, timeout_s=timeout_s, log=log)
        self.node_id = node_id
        self.bitrate = int(bitrate)
        self.heartbeat_ms = int(heartbeat_ms)
        self.heartbeat_factor = float(heartbeat_factor)
        self.sample_rate_hz: float | None = None
        self.calibration_matrix: NDArray[np.float64] | None = None
        self.events: list[LoadCellEvent] = []
        self.streaming = False
        self.layout: p.PdoLayout | None = None
        self._final_pulses: int | None = None
        self._samples = _new_samples()
        self._assembly = _Assembly()
        self._last_low: list[int] = []
        self._last_abs: list[int] = []
        self._cond = threading.Condition()
        self._frames: dict[int, list[bytes]] = {}
        self._emcys: list[Any] = []
        self._bad: set[int] = set()
        self._last_heartbeat: float | None = None
        self._hb_lost_reported = False
        self._nmt_state: int | None = None
        try:
            od = canopen.import_od(str(eds), node_id)
        except Exception as err:
            raise SetupError(
                f"{what}: cannot read the EDS file {eds} ({type(err).__name__}: {err}); give the "
                "amplifier's EDS (loadcell_canopen_eds)"
            ) from err
        self.network = canopen.Network(bus)
        self.network.NOTIFIER_CYCLE = 0.1  # how long closing waits for the receive thread
        self.node = canopen.RemoteNode(node_id, od)
        self.node.sdo.RESPONSE_TIMEOUT = self.timeout_s
        self.network.add_node(self.node)
        self.node.nmt.add_heartbeat_callback(self._on_heartbeat)
        self.node.emcy.add_callback(self._on_emcy)
        if calibration_matrix is not None:  # refused before a receive thread is started
            self.set_calibration_matrix(calibration_matrix)
        self.network.connect()

    # -- wire steps ---------------------------------------------------------------------------
    def _close_transport(self) -> None:
        if self.network.notifier is not None:
            self.network.notifier.stop(self.network.NOTIFIER_SHUTDOWN_TIMEOUT)
            self.network.notifier = None
        for cob in list(self._frames):
            self.network.unsubscribe(cob, self._on_tpdo)
        del self.network[self.node_id]

    def _sdo(
        self, what: str, index: int, subindex: int, fn: Callable[[], T], idempotent: bool
    ) -> T:
        name = p.object_name(index, subindex)

        def attempt(deadline: Deadline) -> T:
            try:
                return fn()
            except SdoAbortedError as err:
                code = int(err.code)
                text = SdoAbortedError.CODES.get(code, "abort")
                exc = DeviceStateError if code in _STATE_ABORTS else ProtocolError
                hint = (
                    "stop the stream first (NMT pre-operational)"
                    if code in _STATE_ABORTS
                    else "check the value and the EDS against the amplifier's"
                )
                raise exc(
                    f"{self.name}: SDO {what} of {name} aborted with 0x{code:08X} ({text}); {hint}"
                ) from err
            except SdoCommunicationError as err:
                raise DeviceTimeoutError(
                    f"{self.name}: SDO {what} of {name} got no answer ({err}); check the node's "
                    "power, the bit rate (loadcell_canopen_bitrate) and its node id in the rig file"
                ) from err
            except can.CanError as err:
                raise DeviceError(
                    f"{self.name}: cannot send the SDO {what} of {name}: {err}"
                ) from err

        return self._exchange(f"SDO {what} {name}", attempt, idempotent=idempotent)

    def _read(self, index: int, subindex: int = 0) -> bytes:
        return self._sdo(
            "upload", index, subindex, lambda: self.node.sdo.upload(index, subindex), True
        )

    def _read_int(self, index: int, subindex: int = 0) -> int:
        raw = self._read(index, subindex)
        return int.from_bytes(raw, "little")

    def _write(self, index: int, subindex: int, data: bytes) -> None:
        self._sdo(
            "download",
            index,
            subindex,
            lambda: self.node.sdo.download(index, subindex, data, force_segment=len(data) > 4),
            False,
        )

    # -- notifier-thread callbacks -------------------------------------------------------------
    def _on_tpdo(self, can_id: int, data: bytearray, timestamp: float) -> None:
        # no wake-up per frame: the reader decodes what came in every few ms, in bulk
        with self._cond:
            self._frames[can_id].append(bytes(data))

    def _on_emcy(self, emcy: Any) -> None:
        with self._cond:
            self._emcys.append(emcy)
            self._cond.notify_all()

    def _on_heartbeat(self, state: int) -> None:
        self._last_heartbeat = time.monotonic()
        self._nmt_state = state

    # -- setup ----------------------------------------------------------------------------------
    def read_mapping(self) -> p.PdoLayout:
        """Read the TPDO mapping from the node (SDO) and build the frame decoder from it.

        Raises
        ------
        SetupError
            The mapping does not carry the 12 gauges with the sample counter.
        DeviceError
            An SDO abort (naming the object) or no answer.
        """
        tpdo_maps: Any = self.node.tpdo.map

        def read_all(deadline: Deadline) -> list[tuple[int, bool, list[p.MappedEntry]]]:
            out = []
            try:
                for k in sorted(tpdo_maps):
                    m = tpdo_maps[k]
                    m.read()
                    if m.enabled and m.cob_id is not None:
                        self.network.unsubscribe(m.cob_id, m.on_message)  # ours decode in bulk
                    entries = [
                        p.MappedEntry(v.index, v.subindex, int(v.length), int(v.offset or 0))
                        for v in m.map
                    ]
                    out.append((int(m.cob_id or 0), bool(m.enabled), entries))
            except SdoAbortedError as err:
                raise ProtocolError(
                    f"{self.name}: reading the TPDO mapping: SDO aborted with 0x{err.code:08X} "
                    f"({SdoAbortedError.CODES.get(int(err.code), 'abort')}); check the EDS"
                ) from err
            except SdoCommunicationError as err:
                raise DeviceTimeoutError(
                    f"{self.name}: reading the TPDO mapping got no answer ({err}); check the "
                    "node's power, bit rate and node id"
                ) from err
            return out

        maps = self._exchange("read TPDO mapping", read_all, idempotent=True)
        full_scale = float(np.frombuffer(self._read(p.FULL_SCALE), "<f4")[0])
        layout = p.PdoLayout.from_mappings(maps, full_scale_v=full_scale, where=self.name)
        for cob in list(self._frames):
            self.network.unsubscribe(cob, self._on_tpdo)
        self._frames = {cob: [] for cob in layout.cob_ids}
        for cob in layout.cob_ids:
            self.network.subscribe(cob, self._on_tpdo)
        self.layout = layout
        return layout

    def _require_layout(self) -> p.PdoLayout:
        if self.layout is None:
            return self.read_mapping()
        return self.layout

    def identify(self) -> LoadCellIdentity:
        """Serial number (``0x1018:04``), software version (``0x100A``), gauges (``0x6100:00``);
        the node's producer heartbeat is set to ``heartbeat_ms`` and the mapping read. First the
        node must be the device its EDS describes (device type ``0x1000``, vendor and product
        ``0x1018:01/02``): else a one-line SetupError naming both."""
        od: Any = self.node.object_dictionary
        got = (self._read_int(0x1000), self._read_int(p.IDENTITY, 1), self._read_int(p.IDENTITY, 2))
        want = (
            int(od[0x1000].default or 0),
            int(od[p.IDENTITY][1].default or 0),
            int(od[p.IDENTITY][2].default or 0),
        )
        if got != want:
            raise SetupError(
                f"{self.name} answers device type 0x{got[0]:08X}, vendor 0x{got[1]:08X}, product "
                f"0x{got[2]:08X} but its EDS describes 0x{want[0]:08X}, 0x{want[1]:08X}, "
                f"0x{want[2]:08X}: another device is at this node id; give its own EDS "
                "(loadcell_canopen_eds, or loadcell = 'cia404' for a generic CiA 404 amplifier) "
                "or correct node_id in the rig file"
            )
        serial = self._read_int(p.IDENTITY, 4)
        firmware = self._read(0x100A).decode("ascii", "replace").strip("\0 ")
        n_gauges = self._read_int(p.GAUGES, 0)
        self._write(p.HEARTBEAT_TIME, 0, self.heartbeat_ms.to_bytes(2, "little"))
        self._require_layout()
        return LoadCellIdentity(n_gauges, firmware, serial)

    def set_rate(self, rate_hz: int) -> float:
        """Nominal sample rate (the DAQ's when counting SYNC); warns when the stream would take
        more than the bus (:func:`~dimacq.drivers.canopen_loadcell.protocol.bus_load`)."""
        self._write(p.SAMPLE_RATE, 0, int(rate_hz).to_bytes(4, "little"))
        self.sample_rate_hz = float(self._read_int(p.SAMPLE_RATE))
        layout = self._require_layout()
        load = p.bus_load(layout, self.sample_rate_hz, self.bitrate)
        if load > 0.8:
            log.warning(
                "%s: %d TPDOs per sample at %g S/s take %.0f %% of a %d bit/s bus; frames will "
                "be lost on a real bus: lower the rate or raise loadcell_canopen_bitrate",
                self.name,
                len(layout.tpdos),
                self.sample_rate_hz,
                100 * load,
                self.bitrate,
            )
        return self.sample_rate_hz

    def tare(self, n_samples: int = 256) -> None:
        if self.streaming:
            raise DeviceStateError(f"{self.name}: tare() while streaming; stop() first")
        self._write(p.TARE, 0, int(n_samples).to_bytes(2, "little"))

    # -- NMT -------------------------------------------------------------------------------------
    def start(self, *, external_clock: bool = True) -> None:
        """Clock source, then NMT OPERATIONAL: the counter restarts at 0 and counts the DAQ's
        SYNC pulses (``external_clock``) or the amplifier's own clock. Start before the DAQ."""
        if self.sample_rate_hz is None:
            raise SetupError("call set_rate() with the DAQ's sample rate before start()")
        layout = self._require_layout()
        self._write(p.CLOCK_SOURCE, 0, bytes([1 if external_clock else 0]))
        with self._cond:
            self._samples = _new_samples()
            self._assembly = _Assembly()
            self._last_low = [-1] * len(layout.tpdos)
            self._last_abs = [-1] * len(layout.tpdos)
            for cob in self._frames:
                self._frames[cob] = []
            self._emcys = []
            self._bad = set()
        self._final_pulses = None
        self._hb_lost_reported = False
        self._last_heartbeat = time.monotonic()
        self._exchange("NMT start", lambda d: self.node.nmt.send_command(0x01))
        # NMT is unconfirmed: an SDO answer comes after the node handled the command (one queue),
        # so the counter is armed before this returns and the DAQ may start
        self._read_int(p.STATUS)
        self.streaming = True

    def stop(self) -> int:
        """NMT PRE-OPERATIONAL, then the pulses counted (``0x2102``); frames in flight are kept."""
        self._exchange("NMT stop", lambda d: self.node.nmt.send_command(0x80))
        self.streaming = False
        pulses = self._read_int(p.COUNTER)
        self._final_pulses = pulses
        return pulses

    @property
    def _who(self) -> str:
        return self.name

    def _device_counter(self) -> int:
        return unwrap_u32(self._read_int(p.COUNTER), self._have() - 1)

    def get_status(self) -> tuple[int, int, int]:
        """(0 idle / 2 streaming, status flags ``0x2103``, sample counter ``0x2102``)."""
        flags = self._read_int(p.STATUS)
        counter = self._read_int(p.COUNTER)
        return (2 if self.streaming else 0), flags, counter

    # -- calibration ----------------------------------------------------------------------------
    def set_calibration_matrix(self, matrix: Any) -> None:
        m = np.asarray(matrix, dtype=float)
        if m.shape != (6, p.N_GAUGES) or not np.all(np.isfinite(m)):
            raise SetupError(
                f"calibration matrix has shape {m.shape}; give a finite 6x12 matrix "
                "(N and N·m per gauge volt)"
            )
        self.calibration_matrix = m

    def download_calibration(
        self, matrix: Any, *, serial: str | None = None, date: str | None = None
    ) -> None:
        """Store a 6×12 matrix in the amplifier (``0x2200``, REAL32 row-major; one segmented SDO
        transfer), with its serial number and date when given."""
        blob = p.matrix_to_blob(np.asarray(matrix, dtype=float))
        self._write(p.CALIBRATION_MATRIX, 0, blob)
        if serial is not None:
            self._write(p.CALIBRATION_SERIAL, 0, serial.encode("ascii"))
        if date is not None:
            self._write(p.CALIBRATION_DATE, 0, date.encode("ascii"))

    def upload_calibration(self) -> NDArray[np.float64]:
        """The matrix stored in the amplifier (``0x2200``)."""
        blob = self._read(p.CALIBRATION_MATRIX)
        if len(blob) != 6 * p.N_GAUGES * 4:
            raise ProtocolError(
                f"{self.name}: {p.object_name(p.CALIBRATION_MATRIX)} holds {len(blob)} bytes, "
                "expected 288 (6x12 REAL32); download the calibration again"
            )
        return p.matrix_from_blob(blob)

    # -- stream ----------------------------------------------------------------------------------
    def _record(self, ev: LoadCellEvent) -> None:
        self._samples.record(ev)
        self.events.append(ev)
        log.warning("%s", ev.message)

    def _check_heartbeat(self) -> None:
        last = self._last_heartbeat
        if last is None:
            return
        age = time.monotonic() - last
        limit = self.heartbeat_factor * self.heartbeat_ms / 1000
        if age > limit and not self._hb_lost_reported:
            self._hb_lost_reported = True
            at = self._samples.next_sample
            self._record(
                LoadCellEvent(
                    "device_error",
                    at,
                    0,
                    f"{self.name}: no heartbeat for {age:.2f} s (producer time "
                    f"{self.heartbeat_ms} ms, lost after {self.heartbeat_factor:g} periods); the "
                    "node may be lost: check its power and the CAN bus",
                )
            )
        elif age <= limit and self._hb_lost_reported:
            self._hb_lost_reported = False
            log.warning("%s: heartbeat back", self.name)

    def _decode_pending(self) -> None:
        layout = self.layout
        assert layout is not None
        with self._cond:
            batches = {cob: frames for cob, frames in self._frames.items() if frames}
            for cob in batches:
                self._frames[cob] = []
            emcys, self._emcys = self._emcys, []
        for k, t in enumerate(layout.tpdos):
            frames = batches.get(t.cob_id)
            if not frames:
                continue
            low, gauges, volts = layout.decode(k, frames)
            # unwrap the 16-bit labels along this TPDO's stream
            ref_low = self._last_low[k] if self._last_low[k] >= 0 else int(low[0])
            diffs = np.diff(np.concatenate([[ref_low], low])) & 0xFFFF
            diffs = np.where(diffs >= 2**15, diffs - 2**16, diffs)
            start = self._last_abs[k] if self._last_abs[k] >= 0 else int(low[0]) - int(diffs[0])
            counters = start + np.cumsum(diffs)
            self._last_low[k] = int(low[-1])
            self._last_abs[k] = int(counters[-1])
            self._assembly.put(counters, gauges, volts)
        for e in emcys:
            self._emcy_event(e)

    def _emcy_event(self, e: Any) -> None:
        code = int(e.code)
        if code & 0xFF00 == 0:
            log.info("%s: EMCY error reset", self.name)
            return
        try:
            at = p.emcy_counter(bytes(e.data))
        except ProtocolError:
            at = self._samples.next_sample
        desc = e.get_desc() if hasattr(e, "get_desc") else ""
        if code == p.EMCY_BUS_OFF_RECOVERED:
            why = "the node was bus-off and rejoined; the samples it could not send are lost"
        else:
            why = "the sample it names is rejected (with the average that contains it)"
            self._bad.add(at)
        self._record(
            LoadCellEvent(
                "device_error",
                at,
                1,
                f"{self.name}: EMCY 0x{code:04X} ({desc}), error register 0x{int(e.register):02X}, "
                f"at sample {at}: {why}",
            )
        )

    def _have(self) -> int:
        """One past the highest sample every TPDO has reached."""
        if not self._last_abs or min(self._last_abs) < 0:
            return 0
        return min(self._last_abs) + 1

    def read_until(self, end_sample: int, timeout_s: float | None = None) -> LoadCellBlock:
        """Samples ``next .. end_sample − 1`` (blocking until every TPDO's counter passed it).

        Raises
        ------
        DeviceTimeoutError
            The counter did not get there in time (received samples are kept); names the node
            and its heartbeat.
        """
        self._require_open()
        self._require_layout()
        if end_sample <= self._samples.next_sample:
            raise SetupError(
                f"end_sample {end_sample} is not after the next unread sample "
                f"{self._samples.next_sample}"
            )
        deadline = self._deadline(timeout_s)

        def have() -> int:
            self._decode_pending()
            self._check_heartbeat()
            return self._have()

        def pump(left: float) -> None:
            with self._cond:
                self._cond.wait(min(left, 0.004))

        def timed_out(got: int) -> DeviceTimeoutError:
            hb = self._last_heartbeat
            seen = "never" if hb is None else f"{time.monotonic() - hb:.2f} s ago"
            return DeviceTimeoutError(
                f"{self.name}: counter reached {got}, not {end_sample}, within "
                f"{deadline.timeout_s} s (last heartbeat {seen}); is the DAQ clock running, "
                "the node operational and on the bus?"
            )

        self._await_counter(end_sample, deadline, have, pump, timed_out)
        return self._take(end_sample)

    def _take(self, end: int) -> LoadCellBlock:
        layout = self.layout
        assert layout is not None
        samples = self._samples
        counters, volts = self._assembly.take(end)
        keep = counters >= samples.next_sample
        counters, volts = counters[keep], volts[keep]
        flags = np.where(layout.overload(volts), p.STATUS_OVERLOAD, 0).astype(np.uint8)
        samples.put_counters(counters, volts, flags)
        got = samples.take(end)
        first = got.first
        valid = got.valid.copy()
        data = got.data
        bad = [c for c in self._bad if first <= c < end]
        if bad:
            valid[np.asarray(bad) - first] = False
            data = data.copy()
            data[np.asarray(bad) - first] = np.nan
            self._bad.difference_update(bad)
        status = got.flags.astype(np.uint8, copy=False)
        if not got.valid.all():
            for a, b in false_runs(got.valid):
                self._record(
                    LoadCellEvent(
                        "gap",
                        first + int(a),
                        int(b - a + 1),
                        f"{self.name}: samples {first + a}..{first + b} incomplete (TPDO frames "
                        "lost on the CAN bus); the average that contains them must be repeated",
                    )
                )
        over = (status & p.STATUS_OVERLOAD) > 0
        if over.any():
            k = np.flatnonzero(over)
            self._record(
                LoadCellEvent(
                    "overload",
                    first + int(k[0]),
                    int(k[-1] - k[0] + 1),
                    f"{self.name}: gauge overload in samples {first + k[0]}..{first + k[-1]}",
                )
            )
        events = samples.pop_events(first, end)
        g = data.T
        forces = None if self.calibration_matrix is None else self.calibration_matrix @ g
        return LoadCellBlock(first, g, forces, valid, over, events)
