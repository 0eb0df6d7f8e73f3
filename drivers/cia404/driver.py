"""A generic CiA 404 measuring amplifier (CANopen) as a load cell on the DAQ's sample clock.

The node is described by its own EDS (CiA 306); nothing project-specific is asked of it. At
:meth:`Cia404Amplifier.identify` the driver checks it is the device the EDS describes (device
type ``0x1000``, vendor and product ``0x1018:01/02``), then **maps** the CiA 404 process values
(``0x6130`` REAL32, or ``0x7130`` INTEGER16 scaled by ``0x6132``, whichever the EDS offers) into
its TPDOs by SDO, in the CiA 301 order (disable, clear, entries, count, transmission type 1 =
synchronous, enable): :func:`~dimacq.drivers.cia404.protocol.mapping_writes`.

**SYNC and the DAQ's clock.** A synchronous TPDO carries what the node sampled at the last SYNC,
and is sent before the next one (CiA 301's synchronous window). So the ``k``-th SYNC the driver
sees after :meth:`start` *is* the node's sample ``k``, and the frames between SYNC ``k`` and
``k + 1`` are that sample. Whether it is also DAQ sample ``k`` depends on who sends the SYNC:

- ``sync = "daq"`` (the rig's choice for an acquisition): the SYNC is produced on each pulse of
  the DAQ's sample clock — the DAQ's clock output wired to a CAN interface's trigger input (a
  hardware-triggered transmit, as the Net F/T's requests) or a SYNC producer node clocked by it.
  SYNC ``k`` is DAQ sample ``k`` to the transmit latency (µs, constant), the counts are checked
  after the run (:meth:`verify_count`: SYNCs counted against samples the DAQ clocked; unequal is
  ``drift``); a lost SYNC shifts the count and shows there.
- ``sync = "host"``: the driver's own periodic SYNC (``canopen``'s ``SyncProducer``, a
  ``bus.send_periodic`` at ``1 / rate``). It runs on the PC's timer, not on the DAQ's crystal: its
  first SYNC is some ms after the DAQ's first sample (unknown) and its period jitters by the OS's
  timer (0.1–1 ms) and differs from the DAQ's by the two clocks' tolerance. At 100 Hz a 1 ms
  offset is 36° of FRF phase, so :meth:`start` refuses it for an acquisition on the DAQ's clock
  (``external_clock=True``); it serves readings on the node's own time (``external_clock=False``:
  bench, devices check). A node does not hear its host's own SYNC, so in that mode a sample starts
  with the lowest TPDO (sent first: lowest identifier wins arbitration).

**Its own sampling.** A CiA 404 amplifier samples its inputs on its own clock (0x6114) and a
synchronous TPDO carries the last value its filter produced, not a sample taken at the SYNC.
At :meth:`Cia404Amplifier.set_rate` the driver sets the fastest ADC rate the EDS allows and a
moving average over about one DAQ period (0x61A0/0x61A1) where the EDS has them writable (else
it reads what the node has); the node's timing
(:class:`~dimacq.drivers.held_timing.HeldSampleTiming`) gives the FRF factor that is divided out
(:meth:`Cia404Amplifier.known_response`) and the phase the held value's random age costs at the
band's top, refused above ``max_phase_deg``. An EDS without 0x6114 is refused for a run on the
DAQ's clock: the node's timing could not be bounded.

**Units and scaling.** :meth:`Cia404Amplifier.identify` reads each input's physical unit
(0x6131), sensor type (0x6110) and scaling (0x6126/0x6127): the unit must be the calibration
file's ``gauge_unit`` (:data:`~dimacq.drivers.cia404.protocol.UNIT_CODES`), the sensor type and
scaling what the EDS declares (the calibration was made through them), else it refuses.

**Faults.** A lost TPDO leaves its sample incomplete (NaN, ``gap``). Any EMCY (except an error
reset) and any NMT state other than OPERATIONAL while streaming (heartbeat ``0x700 + n``; a
boot-up means the node reset and lost its mapping) are ``device_error`` events naming the node;
their samples are marked invalid, so the running average is rejected with that reason. A
heartbeat older than ``heartbeat_factor`` periods is reported as a lost node.

The bus and its ``canopen.Network`` are one per CAN channel (:class:`CanChannel`, injected): all
nodes of that channel share them (PCAN allows one client per channel), and the channel refuses
a summed load above its limit (:meth:`CanChannel.check_load`).
"""

from __future__ import annotations

import logging
import struct
import time
from collections import deque
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
from dimacq.drivers.cia404 import protocol as p
from dimacq.drivers.held_timing import HeldSampleTiming
from dimacq.drivers.stream import CounterStream, false_runs
from dimacq.errors import DeviceError, DeviceTimeoutError, ProtocolError, SetupError

__all__ = ["CanChannel", "Cia404Amplifier"]

log = logging.getLogger(__name__)

T = TypeVar("T")

#: seconds without a frame after which a stopped run is taken as fully received
_QUIET_S = 0.1
#: how long a read waits before looking at the received frames again, s
_POLL_S = 0.004
#: markers among the received frames: an EMCY, an NMT state change
_EMCY, _NMT = -1, -2


class CanChannel:
    """One CAN channel: its bus and ``canopen.Network``, shared by every node on it.

    Parameters
    ----------
    bus : can.BusABC
        Opened by the caller; shut down by :meth:`close`.
    bitrate : int
        The bus's bit rate, bit/s.
    max_load : float
        Largest fraction of the bus the nodes' streams (and the SYNC) may take.
    where : str
        How errors name the channel and its settings.
    enforce : bool
        False (a simulated bus, which has no bit rate): a load above ``max_load`` is logged as
        a warning saying a real bus would refuse it, not refused.
    """

    def __init__(
        self,
        bus: can.BusABC,
        *,
        bitrate: int,
        max_load: float,
        where: str,
        enforce: bool = True,
    ) -> None:
        self.bus = bus
        self.bitrate = int(bitrate)
        self.max_load = float(max_load)
        self.enforce = enforce
        self.where = where
        self.network = canopen.Network(bus)
        self.network.NOTIFIER_CYCLE = 0.1  # how long closing waits for the receive thread
        self.network.connect()
        self.nodes: dict[int, tuple[int, ...]] = {}  # node id → TPDO data bytes per sample
        self._host_sync_users = 0

    def register(self, node_id: int, frame_bytes: tuple[int, ...]) -> None:
        if node_id in self.nodes:
            raise SetupError(
                f"{self.where}: two load cells on CANopen node {node_id}; give each cell its own "
                "node_id in the rig file"
            )
        self.nodes[node_id] = frame_bytes

    def check_load(self, rate_hz: float) -> float:
        """The summed load of every node's TPDOs and the SYNC at ``rate_hz``.

        Raises
        ------
        SetupError
            Above ``max_load``: names the numbers, the highest rate that fits and the fixes.
        """
        frames = [n for fb in self.nodes.values() for n in fb]
        load = p.bus_load(frames, rate_hz, self.bitrate)
        if load > self.max_load:
            bits = p.frame_bits(0) + sum(p.frame_bits(n) for n in frames)
            fits = self.max_load * self.bitrate / bits
            msg = (
                f"{self.where}: {len(self.nodes)} node(s), {len(frames)} TPDO frames + SYNC = "
                f"{bits} bits per sample (worst-case stuffing) at {rate_hz:g} S/s is "
                f"{100 * load:.0f} % of {self.bitrate} bit/s, above {100 * self.max_load:.0f} % "
                f"(loadcell_cia404_max_bus_load); lower the DAQ's sample_rate_hz to <= "
                f"{int(fits)} S/s, map 0x7130 (INTEGER16) or fewer channels, or give cells "
                "another CAN channel (rig file channel)"
            )
            if self.enforce:
                raise SetupError(msg)
            log.warning("simulated bus, not refused; a real bus would be: %s", msg)
        return load

    def start_host_sync(self, rate_hz: float) -> None:
        if self._host_sync_users == 0:
            self.network.sync.start(1.0 / rate_hz)
        self._host_sync_users += 1

    def stop_host_sync(self) -> None:
        self._host_sync_users = max(0, self._host_sync_users - 1)
        if self._host_sync_users == 0:
            self.network.sync.stop()

    def close(self) -> None:
        """Stop the SYNC, the receive thread, and shut the bus down."""
        try:
            self.network.sync.stop()
        finally:
            self.network.disconnect()


class Cia404Amplifier(WireDriver):
    """One generic CiA 404 amplifier node (see the module docstring).

    Parameters
    ----------
    channel : CanChannel
        The shared channel (injected).
    node_id : int
    eds : path
        The node's EDS file.
    n_channels : int
        Inputs carrying the cell (the calibration matrix's columns), channels 1..n.
    sync : {"daq", "host"}
        Who sends the SYNC (see the module docstring).
    process_value : {"auto", "0x6130", "0x7130"}
    """

    reopen_hint = "open the load cell again (its backend)"

    def __init__(
        self,
        channel: CanChannel,
        *,
        node_id: int,
        eds: str | Path,
        n_channels: int = 12,
        timeout_s: float = 1.0,
        calibration_matrix: Any = None,
        heartbeat_ms: int = 200,
        heartbeat_factor: float = 5.0,
        sync: str = "daq",
        process_value: str = "auto",
        gauge_unit: str | None = None,
        max_phase_deg: float = 2.0,
        band_hz: float | None = None,
        label: str = "",
    ) -> None:
        if not 1 <= node_id <= 127:
            raise SetupError(f"CANopen node id {node_id}: give 1..127 as set on the amplifier")
        if sync not in ("daq", "host"):
            raise SetupError(f"loadcell_cia404_sync = {sync!r}: give 'daq' or 'host'")
        what = f"CiA 404 amplifier node {node_id}" + (f" ({label})" if label else "")
        super().__init__(what, timeout_s=timeout_s, log=log)
        self.channel = channel
        self.node_id = node_id
        self.eds = Path(eds)
        self.sync = sync
        self.n_channels = int(n_channels)
        self.heartbeat_ms = int(heartbeat_ms)
        self.heartbeat_factor = float(heartbeat_factor)
        self.sample_rate_hz: float | None = None
        self.gauge_unit = gauge_unit
        self.max_phase_deg = float(max_phase_deg)
        self.band_hz = band_hz
        self.timing: HeldSampleTiming | None = None
        self.calibration_matrix: NDArray[np.float64] | None = None
        self.events: list[LoadCellEvent] = []
        self.streaming = False
        try:
            od: Any = canopen.import_od(str(eds), node_id)
        except Exception as err:
            raise SetupError(
                f"{what}: cannot read the EDS file {eds} ({type(err).__name__}: {err}); give the "
                "amplifier's EDS (loadcell_cia404_eds)"
            ) from err
        self.od: Any = od
        self.pv = p.process_value(od, process_value, where=what)
        n_tpdos = sum(1 for k in range(512) if p.TPDO_COMM + k in od and p.TPDO_MAP + k in od)
        self.n_tpdos = n_tpdos
        self.plans = p.plan_tpdos(self.n_channels, self.pv, node_id, n_tpdos, where=what)
        self._cob_index = {t.cob_id: k for k, t in enumerate(self.plans)}
        self._scale: NDArray[np.float64] | None = None
        if calibration_matrix is not None:
            self.set_calibration_matrix(calibration_matrix)
        #: frames in arrival order (EMCY and NMT state changes among them, as markers)
        self._rx: deque[tuple[int, Any]] = deque()
        self._reset_run()
        self._last_heartbeat: float | None = None
        self._hb_lost_reported = False
        self._nmt_state: int | None = None
        self._host_sync = False
        self.node = canopen.RemoteNode(node_id, od)
        self.node.sdo.RESPONSE_TIMEOUT = self.timeout_s
        channel.register(node_id, tuple(t.length for t in self.plans))
        net = channel.network
        net.add_node(self.node)
        self.node.nmt.add_heartbeat_callback(self._on_heartbeat)
        self.node.emcy.add_callback(self._on_emcy)
        for cob in (p.SYNC_COB_ID, *self._cob_index):
            net.subscribe(cob, self._on_frame)

    @property
    def n_gauges(self) -> int:
        return self.n_channels

    # -- wire steps ---------------------------------------------------------------------------
    def _close_transport(self) -> None:
        """Leave the shared network (the channel closes the bus)."""
        net = self.channel.network
        if self._host_sync:
            self._host_sync = False
            self.channel.stop_host_sync()
        for cob in (p.SYNC_COB_ID, *self._cob_index):
            net.unsubscribe(cob, self._on_frame)
        if self.node_id in net:
            del net[self.node_id]
        self.channel.nodes.pop(self.node_id, None)

    def _sdo(self, what: str, index: int, sub: int, fn: Callable[[], T]) -> T:
        name = f"0x{index:04X}:{sub:02X}"

        def attempt(deadline: Deadline) -> T:
            try:
                return fn()
            except SdoAbortedError as err:
                code = int(err.code)
                raise ProtocolError(
                    f"{self.name}: SDO {what} of {name} aborted with 0x{code:08X} "
                    f"({SdoAbortedError.CODES.get(code, 'abort')}); check the EDS "
                    f"({self.eds}) against the amplifier's"
                ) from err
            except SdoCommunicationError as err:
                raise DeviceTimeoutError(
                    f"{self.name}: SDO {what} of {name} got no answer ({err}); check the node's "
                    "power, the bit rate (loadcell_canopen_bitrate) and its node_id in the rig file"
                ) from err
            except can.CanError as err:
                raise DeviceError(
                    f"{self.name}: cannot send the SDO {what} of {name}: {err}"
                ) from err

        return self._exchange(f"SDO {what} {name}", attempt, idempotent=True)

    def _read_u32(self, index: int, sub: int = 0) -> int:
        raw = self._sdo("upload", index, sub, lambda: self.node.sdo.upload(index, sub))
        return int.from_bytes(raw[:4], "little")

    def _write(self, index: int, sub: int, data: bytes) -> None:
        self._sdo("download", index, sub, lambda: self.node.sdo.download(index, sub, data))

    def _nmt(self, command: p.NmtCommand) -> None:
        self._exchange(f"NMT {command.name}", lambda d: self.node.nmt.send_command(int(command)))

    # -- setup ----------------------------------------------------------------------------------
    def _expected(self, index: int, sub: int | None = None) -> int:
        obj = self.od[index] if sub is None else self.od[index][sub]
        return int(obj.default or 0)

    def identify(self) -> LoadCellIdentity:
        """Device type and identity checked against the EDS, heartbeat set, TPDOs mapped.

        Raises
        ------
        SetupError
            The node is another device than the EDS describes (one line naming both).
        DeviceTimeoutError
            No answer.
        """
        dev = self._read_u32(p.DEVICE_TYPE)
        vendor = self._read_u32(p.IDENTITY, 1)
        product = self._read_u32(p.IDENTITY, 2)
        want = (self._expected(p.DEVICE_TYPE), self._expected(p.IDENTITY, 1))
        want_product = self._expected(p.IDENTITY, 2)
        if (dev, vendor) != want or product != want_product:
            raise SetupError(
                f"{self.name} answers device type 0x{dev:08X}, vendor 0x{vendor:08X}, product "
                f"0x{product:08X} but {self.eds.name} describes 0x{want[0]:08X}, "
                f"0x{want[1]:08X}, 0x{want_product:08X}; give that node's own EDS "
                "(loadcell_cia404_eds) or correct node_id in the rig file"
            )
        serial = self._read_u32(p.IDENTITY, 4)
        revision = self._read_u32(p.IDENTITY, 3)
        self._write(p.HEARTBEAT_TIME, 0, self.heartbeat_ms.to_bytes(2, "little"))
        units = self.check_inputs()
        self.configure()
        return LoadCellIdentity(
            self.n_channels,
            f"vendor 0x{vendor:08X} product 0x{product:08X} rev 0x{revision:08X}, "
            f"{self.pv.name} (0x{self.pv.index:04X}) in {len(self.plans)} TPDOs, {units}",
            serial,
        )

    def _has(self, index: int) -> bool:
        return bool(index in self.od)

    def _read_f32(self, index: int, sub: int) -> float:
        raw = self._sdo("upload", index, sub, lambda: self.node.sdo.upload(index, sub))
        return float(struct.unpack("<f", raw[:4])[0])

    def check_inputs(self) -> str:
        """Each input's unit (0x6131), sensor type (0x6110) and scaling (0x6126/0x6127) read
        and checked: the unit against the calibration file's ``gauge_unit``, the others against
        the EDS. Objects the EDS lacks are named in the returned summary as not checked.

        Raises
        ------
        SetupError
            A unit other than the calibration's, a sensor type or scaling other than the EDS's.
        """
        for c in range(1, self.n_channels + 1):
            if self._has(p.AI_PHYSICAL_UNIT):
                code = self._read_u32(p.AI_PHYSICAL_UNIT, c)
                names = [u for u, v in p.UNIT_CODES.items() if v == code]
                if self.gauge_unit is not None and self.gauge_unit not in names:
                    raise SetupError(
                        f"{self.name}: input {c} gives its process value in unit code "
                        f"0x{code:08X} ({names[0] if names else 'not a bridge unit'}, 0x6131) but "
                        f"the calibration file's gauge_unit is {self.gauge_unit!r} (code "
                        f"0x{p.UNIT_CODES.get(self.gauge_unit, 0):08X}); set the amplifier's "
                        "unit to the calibration's or calibrate the cell in the amplifier's unit"
                    )
            if self._has(p.AI_SENSOR_TYPE):
                st = self._read_u32(p.AI_SENSOR_TYPE, c) & 0xFFFF
                want = self._expected(p.AI_SENSOR_TYPE, c)
                if st != want:
                    raise SetupError(
                        f"{self.name}: input {c} sensor type 0x{st:04X} (0x6110) but the EDS "
                        f"{self.eds.name} declares 0x{want:04X}; set the input's sensor type or "
                        "give the amplifier's own EDS"
                    )
            for index, what in ((p.AI_SCALING_FACTOR, "factor"), (p.AI_SCALING_OFFSET, "offset")):
                if not self._has(index):
                    continue
                v = self._read_f32(index, c)
                want_v = float(self.od[index][c].default or 0.0)
                if not np.isclose(v, want_v, rtol=1e-6, atol=1e-9):
                    raise SetupError(
                        f"{self.name}: input {c} scaling {what} {v:g} (0x{index:04X}) but the "
                        f"EDS {self.eds.name} declares {want_v:g}, which the calibration was made "
                        f"through; set 0x{index:04X}:{c} back or calibrate the cell again"
                    )
        checked = [
            n
            for i, n in (
                (p.AI_PHYSICAL_UNIT, "unit"),
                (p.AI_SENSOR_TYPE, "sensor type"),
                (p.AI_SCALING_FACTOR, "scaling"),
            )
            if self._has(i)
        ]
        missing = [
            n
            for i, n in (
                (p.AI_PHYSICAL_UNIT, "unit 0x6131"),
                (p.AI_SENSOR_TYPE, "sensor type 0x6110"),
                (p.AI_SCALING_FACTOR, "scaling 0x6126"),
            )
            if not self._has(i)
        ]
        return ", ".join(
            (["checked: " + ", ".join(checked)] if checked else [])
            + (["not in the EDS: " + ", ".join(missing)] if missing else [])
        )

    def _writable(self, index: int) -> bool:
        return self._has(index) and bool(getattr(self.od[index][1], "writable", False))

    def set_sampling(self, rate_hz: float) -> HeldSampleTiming:
        """The node's own ADC rate and filter: set where the EDS has them writable (the fastest
        rate it allows, a moving average over about one DAQ period), else read.

        Raises
        ------
        SetupError
            No 0x6114 in the EDS (the node's timing unknown).
        """
        if not self._has(p.AI_ADC_SAMPLE_RATE):
            raise SetupError(
                f"{self.name}: the EDS {self.eds.name} has no 0x6114 (AI ADC sample rate): the "
                "node's own sampling, hence the age of the value it sends at each SYNC, is "
                "unknown; give the amplifier's EDS, or read the cell as DAQ inputs "
                "(loadcell = 'daq-channels')"
            )
        chans = range(1, self.n_channels + 1)
        if self._writable(p.AI_ADC_SAMPLE_RATE):
            top = self.od[p.AI_ADC_SAMPLE_RATE][1].max
            adc = int(top if top is not None else self._expected(p.AI_ADC_SAMPLE_RATE, 1))
            for c in chans:
                self._write(p.AI_ADC_SAMPLE_RATE, c, int(adc).to_bytes(4, "little"))
        adc = self._read_u32(p.AI_ADC_SAMPLE_RATE, 1)
        n = 1
        if self._writable(p.AI_FILTER_TYPE) and self._writable(p.AI_FILTER_CONSTANT):
            n = int(min(255, max(1, adc // max(int(rate_hz), 1))))
            kind = p.FILTER_MOVING_AVERAGE if n > 1 else 0
            for c in chans:
                self._write(p.AI_FILTER_TYPE, c, bytes([kind]))
                self._write(p.AI_FILTER_CONSTANT, c, bytes([n]))
        if self._has(p.AI_FILTER_TYPE):
            kind = self._read_u32(p.AI_FILTER_TYPE, 1) & 0xFF
            if kind not in (0, p.FILTER_MOVING_AVERAGE):
                raise SetupError(
                    f"{self.name}: filter type {kind} (0x61A0) is not one whose delay is known "
                    "here (0 none, 1 moving average); set 0x61A0 to 0 or 1"
                )
            n = (self._read_u32(p.AI_FILTER_CONSTANT, 1) & 0xFF) if kind else 1
        return HeldSampleTiming(float(adc), max(int(n), 1), self.name)

    def known_response(self, f_hz: NDArray[np.float64]) -> NDArray[np.complex128]:
        """The factor its held, filtered values put on its FRFs (divided out by the
        acquisition); 1 before :meth:`set_rate`."""
        if self.timing is None:
            return np.ones(np.shape(f_hz), dtype=complex)
        return self.timing.response(f_hz)

    def configure(self) -> None:
        """NMT PRE-OPERATIONAL, then the CiA 301 mapping procedure by SDO (and, for 0x7130,
        each channel's decimal digits ``0x6132`` read)."""
        self._nmt(p.NmtCommand.PRE_OPERATIONAL)
        for index, sub, data in p.mapping_writes(self.plans, self.n_tpdos, self.node_id):
            self._write(index, sub, data)
        if self.pv is p.INT16_PV:
            digits = [
                self._read_u32(p.AI_DECIMAL_DIGITS, c + 1) & 0xFF for c in range(self.n_channels)
            ]
            self._scale = 10.0 ** -np.asarray(digits, dtype=float)

    def set_calibration_matrix(self, matrix: Any) -> None:
        m = np.asarray(matrix, dtype=float)
        if m.shape != (6, self.n_channels) or not np.all(np.isfinite(m)):
            raise SetupError(
                f"{self.name}: calibration matrix has shape {m.shape}; give a finite "
                f"6x{self.n_channels} matrix (loads per process-value unit)"
            )
        self.calibration_matrix = m

    def set_rate(self, rate_hz: int) -> float:
        """The SYNC rate (the DAQ's); the channel refuses a summed load above its limit. The
        node's own sampling is set (:meth:`set_sampling`) and its cost in FRF phase at the
        band's top (``band_hz``, default 0.32 × the rate) checked against ``max_phase_deg``.

        Raises
        ------
        SetupError
            Bus load, unknown node timing, or the phase above the budget.
        """
        self.channel.check_load(float(rate_hz))
        if self.sync == "daq":
            self.timing = self.set_sampling(float(rate_hz))
            band = self.band_hz if self.band_hz is not None else 0.32 * float(rate_hz)
            self.timing.check(band, self.max_phase_deg, where=f"{self.name} at {rate_hz} S/s")
        self.sample_rate_hz = float(rate_hz)
        return self.sample_rate_hz

    # -- a run -----------------------------------------------------------------------------------
    def _reset_run(self) -> None:
        self._count = 0  # SYNCs (or sample starts) seen since start
        self._decided = 0  # samples below this are filed or known incomplete
        self._cur: dict[int, bytes] = {}
        self._last_full = -1  # the last sample filed whole
        self._stream: CounterStream[LoadCellEvent] = CounterStream(
            self.n_channels, flag_dtype=np.bool_
        )
        self._pending_k: list[int] = []
        self._pending: list[tuple[bytes, ...]] = []
        self._bad: list[tuple[int, int | None]] = []  # [first, end) spans; end None: open
        self._final: int | None = None

    def start(self, *, external_clock: bool = True) -> None:
        """NMT OPERATIONAL; the next SYNC is sample 0. Start before the DAQ.

        Raises
        ------
        SetupError
            ``external_clock`` with the host's SYNC (not alignable to the DAQ's samples).
        """
        if self.sample_rate_hz is None:
            raise SetupError("call set_rate() with the DAQ's sample rate before start()")
        if external_clock and self.sync == "host":
            raise SetupError(
                f"{self.name}: loadcell_cia404_sync = 'host' sends SYNC on the PC's timer, not "
                "the DAQ's clock (ms offset, jitter): its samples cannot be aligned with the "
                "DAQ's; wire the DAQ's sample clock to a SYNC producer and set "
                "loadcell_cia404_sync = 'daq', or read the cell as DAQ inputs (loadcell = "
                "'daq-channels')"
            )
        self._require_open()
        self._rx.clear()
        self._reset_run()
        self.events = []
        self._hb_lost_reported = False
        self._last_heartbeat = time.monotonic()
        self._nmt(p.NmtCommand.START)
        # NMT is unconfirmed; an SDO answer comes after the node handled it (one queue), so
        # every heartbeat from now on was sent in the state the command left: OPERATIONAL
        self._read_u32(p.DEVICE_TYPE)
        self._nmt_state = 0x05
        self.streaming = True
        if not external_clock:
            self._host_sync = True
            self.channel.start_host_sync(self.sample_rate_hz)

    # -- receive thread -----------------------------------------------------------------------
    def _on_frame(self, can_id: int, data: bytearray, timestamp: float) -> None:
        # thousands a second: a deque append (thread-safe), no lock, no wake-up (read_until
        # polls; the DAQ's reads pace it)
        if self.streaming:
            self._rx.append((can_id, data))

    def _on_emcy(self, e: Any) -> None:
        if self.streaming and int(e.code) & 0xFF00:  # not an error reset, in a run
            self._rx.append((_EMCY, e))

    def _on_heartbeat(self, state: int) -> None:
        self._last_heartbeat = time.monotonic()
        before, self._nmt_state = self._nmt_state, state
        if self.streaming and before is not None and state != before:
            self._rx.append((_NMT, (before, state)))

    def _emcy_event(self, e: Any) -> None:
        """An EMCY filed in frame order: the sample being taken when it came is rejected."""
        code = int(e.code)
        at = max(self._count - 1, 0)
        desc = e.get_desc() if hasattr(e, "get_desc") else ""
        self._bad.append((at, at + 2))
        self._record(
            LoadCellEvent(
                "device_error",
                at,
                2,
                f"{self.name}: EMCY 0x{code:04X} ({desc or 'see the device manual'}), error "
                f"register 0x{int(e.register):02X}, data {bytes(e.data).hex()} at sample {at}: "
                "the average running then is rejected",
            )
        )

    def _nmt_event(self, before: int, state: int) -> None:
        # the heartbeat tells up to a period late: the node stopped after its last full sample
        at = min(self._count, self._last_full + 1)
        if before == 0x05:
            name = p.NMT_STATES.get(state, f"0x{state:02X}")
            why = (
                "the node reset and lost its PDO mapping: open the load cell again"
                if state == 0x00
                else "it sends no samples until OPERATIONAL again"
            )
            self._bad.append((at, None))
            self._record(
                LoadCellEvent(
                    "device_error",
                    at,
                    max(self._count - at, 1),
                    f"{self.name}: NMT state {name} (was OPERATIONAL) from sample {at}: {why}; "
                    "the average running then is rejected",
                )
            )
        elif state == 0x05 and any(b is None for _, b in self._bad):
            self._bad = [(a, at if b is None else b) for a, b in self._bad]
            log.warning("%s: OPERATIONAL again at sample %d", self.name, at)

    # -- filing ---------------------------------------------------------------------------------
    def _close_sample(self) -> None:
        k = self._count - 1
        cur, self._cur = self._cur, {}
        self._decided = max(self._decided, self._count)
        if k < 0 or len(cur) < len(self.plans):
            return
        self._last_full = k
        self._pending_k.append(k)
        self._pending.append(tuple(cur[j] for j in range(len(self.plans))))

    def _file_pending(self) -> None:
        rx = self._rx
        frames = [rx.popleft() for _ in range(len(rx))]
        host = self.sync == "host" or self._host_sync
        index = self._cob_index
        for cob, data in frames:
            if cob == _EMCY:
                self._emcy_event(data)
                continue
            if cob == _NMT:
                self._nmt_event(*data)
                continue
            if cob == p.SYNC_COB_ID:
                if host:
                    continue
                if self._count > self._decided:
                    self._close_sample()
                self._count += 1
                continue
            j = index.get(cob)
            if j is None:
                continue
            if host and j == 0:
                if self._count > self._decided:
                    self._close_sample()
                self._count += 1
            if self._count == self._decided:
                continue  # sent for no SYNC counted (before start)
            self._cur[j] = data
            if len(self._cur) == len(self.plans):
                self._close_sample()
        self._flush()

    def _flush(self) -> None:
        if not self._pending_k:
            return
        ks = np.asarray(self._pending_k, dtype=np.int64)
        values = np.empty((ks.size, self.n_channels))
        for j, t in enumerate(self.plans):
            cols = list(t.channels)
            scale = None if self._scale is None else self._scale[cols]
            values[:, cols] = p.decode_tpdo(t, [f[j] for f in self._pending], scale)
        self._stream.put_counters(ks, values, np.zeros(ks.size, dtype=bool))
        self._pending_k, self._pending = [], []

    def _record(self, ev: LoadCellEvent) -> None:
        self.events.append(ev)
        self._stream.record(ev)
        log.warning("%s", ev.message)

    def _check_heartbeat(self) -> None:
        last = self._last_heartbeat
        if last is None or not self.heartbeat_ms:
            return
        age = time.monotonic() - last
        if age > self.heartbeat_factor * self.heartbeat_ms / 1000 and not self._hb_lost_reported:
            self._hb_lost_reported = True
            at = self._count
            ev = LoadCellEvent(
                "device_error",
                at,
                0,
                f"{self.name}: no heartbeat for {age:.2f} s (producer time {self.heartbeat_ms} "
                "ms): the node may be lost; check its power and the CAN bus",
            )
            self._record(ev)  # the samples that do arrive stay valid

    def read_until(self, end_sample: int, timeout_s: float | None = None) -> LoadCellBlock:
        """Samples up to ``end_sample − 1`` (waits until the SYNC after it, or the run's end).

        Raises
        ------
        DeviceTimeoutError
            They did not come in time (what came is kept).
        """
        self._require_open()
        deadline = self._deadline(timeout_s)
        while True:
            self._file_pending()
            final = self._final
            if self._decided >= end_sample or (final is not None and end_sample <= final):
                break
            self._check_heartbeat()
            if deadline.passed:
                raise DeviceTimeoutError(
                    f"{self.name}: sample {end_sample - 1} not received within "
                    f"{deadline.timeout_s:g} s ({self._decided} in, {self._count} SYNCs); is "
                    "the SYNC sent on the DAQ's clock and the node OPERATIONAL?"
                )
            time.sleep(min(max(deadline.left(), 0.0), _POLL_S))
        return self._take(end_sample)

    def _take(self, end: int) -> LoadCellBlock:
        st = self._stream
        first = st.next_sample
        if end <= first:
            z = np.zeros((self.n_channels, 0))
            return LoadCellBlock(first, z, z[:6], np.zeros(0, bool), np.zeros(0, bool), ())
        got = st.take(end)
        valid = got.valid.copy()
        data = got.data
        for a, b in self._bad:
            lo, hi = max(a, first), min(end if b is None else b, end)
            if lo < hi:
                if data is got.data:
                    data = data.copy()
                valid[lo - first : hi - first] = False
                data[lo - first : hi - first] = np.nan
        for a, b in false_runs(got.valid):
            st.record(
                LoadCellEvent(
                    "gap",
                    first + a,
                    b - a + 1,
                    f"{self.name}: {b - a + 1} samples from {first + a} incomplete (TPDO frames "
                    "or SYNC lost on the bus)",
                )
            )
        events = st.pop_events(first, end)
        g = data.T
        forces = None if self.calibration_matrix is None else self.calibration_matrix @ g
        over = np.zeros(g.shape[1], dtype=bool)
        return LoadCellBlock(first, g, forces, valid, over, events)

    def stop(self) -> int:
        """After the DAQ stopped: the run's last frames taken, NMT PRE-OPERATIONAL; the SYNCs
        counted."""
        quiet, give_up = Deadline(_QUIET_S), Deadline(max(2.0, self.timeout_s))
        seen = -1
        while not quiet.passed and not give_up.passed:
            self._file_pending()
            if self._count != seen:
                seen, quiet = self._count, Deadline(_QUIET_S)
            time.sleep(_POLL_S)
        if self._host_sync:
            self._host_sync = False
            self.channel.stop_host_sync()
        self._file_pending()
        if self._count > self._decided:
            self._close_sample()
        self.streaming = False
        self._final = self._count
        self._flush()
        self._nmt(p.NmtCommand.PRE_OPERATIONAL)
        return self._count

    def verify_count(self, daq_samples_clocked: int) -> LoadCellEvent | None:
        """SYNCs counted against the DAQ's samples: unequal means misaligned samples."""
        counted = self._final if self._final is not None else self._count
        if counted == daq_samples_clocked:
            return None
        ev = LoadCellEvent(
            "drift",
            min(counted, daq_samples_clocked),
            abs(counted - daq_samples_clocked),
            f"{self.name}: {counted} SYNCs counted but the DAQ clocked {daq_samples_clocked} "
            "samples; the samples are misaligned (a SYNC lost, or not sent on the DAQ's clock)",
        )
        self.events.append(ev)
        return ev

    def read_once(self) -> NDArray[np.float64]:
        """The process values now, by SDO (outside a run), shape (n_channels,)."""
        out = np.empty(self.n_channels)
        for c in range(self.n_channels):
            raw = self._sdo(
                "upload",
                self.pv.index,
                c + 1,
                lambda c=c: self.node.sdo.upload(self.pv.index, c + 1),  # type: ignore[misc]
            )
            if self.pv is p.REAL32_PV:
                out[c] = struct.unpack("<f", raw[:4])[0]
            else:
                s = 1.0 if self._scale is None else float(self._scale[c])
                out[c] = struct.unpack("<h", raw[:2])[0] * s
        return out

    def close(self) -> None:
        self.streaming = False
        super().close()
