"""ATI Net F/T on a CAN bus (python-can), as a 6-DOF load cell on the DAQ's sample clock.

The bus is injected (``can.Bus(...)``, filtered to the sensor's identifiers). Frames are built
and read only through :mod:`dimacq.drivers.netft.protocol`.

**How samples meet the DAQ's clock.** The Net F/T has no sync input: it answers each REQUEST
LONG with the force/torque it holds at that moment. On the rig the requests are sent by the bus
interface on every pulse of the DAQ's sample clock (a hardware-triggered transmit, as a CANopen
SYNC producer does), so the ``k``-th request after the DAQ starts *is* DAQ sample ``k`` and its
four answers are that sample: the driver counts the requests it sees on the bus (the other
node's, not its own) and files the answers that follow under that count. A lost answer makes
its sample incomplete (NaN, a ``gap``); a lost request shifts the count, which the check after
the run finds (``verify_count``: requests counted against samples the DAQ clocked, ``drift``).
The driver sends requests itself only outside a run (:meth:`identify`, :meth:`read_once`) and
the BIAS at the start of a run.

**It does not sample at the request.** The Net F/T samples free-running on its own clock
(``adc_rate_hz``, 7000 S/s) and a request copies the set it last sampled: each DAQ sample's
value is 0..1/7000 s old, uniformly (the clocks are unrelated). :attr:`NetFtCan.timing`
(:class:`~dimacq.drivers.held_timing.HeldSampleTiming`) gives the FRF factor that makes
(:meth:`NetFtCan.known_response`, removed from the cell's FRFs by the acquisition) and the
phase its random part costs, checked at :meth:`NetFtCan.set_rate` against ``max_phase_deg`` at
``band_hz`` (default 0.32 × the DAQ's rate): above it the run is refused. No python-can adapter
transmits on a DAQ's clock pulse by itself: the requests on the DAQ's clock need an interface
with a hardware-triggered transmit (or a trigger node), which is the rig's, not this driver's.

The values are counts: the driver's ``calibration_matrix`` is the diagonal of the sensor's own
counts per force and per torque unit (:class:`~dimacq.drivers.netft.protocol.CalibrationInfo`,
read from the device), so ``forces = C g`` as for the strain-gauge amplifiers. A non-zero status
word is a ``device_error`` event and marks its samples ``overload`` (the average is rejected).
"""

from __future__ import annotations

import logging
from typing import Any

import numpy as np

from dimacq.devices.loadcell import LoadCellBlock, LoadCellEvent, LoadCellIdentity
from dimacq.drivers.base import Deadline, WireDriver
from dimacq.drivers.held_timing import HeldSampleTiming
from dimacq.drivers.netft import protocol as p
from dimacq.drivers.stream import CounterStream, false_runs
from dimacq.errors import DeviceError, DeviceTimeoutError, ProtocolError, SetupError

__all__ = ["NetFtCan", "bus_filters"]

log = logging.getLogger(__name__)

#: bits on the wire of one classic 8-byte frame with an 11-bit id (stuffing included, about)
_FRAME_BITS = 130
#: seconds without a frame after which a stopped run is taken as fully received
_QUIET_S = 0.1


def bus_filters(base: int) -> list[dict[str, Any]]:
    """python-can filters of the sensor's identifiers ``base .. base + 6``."""
    return [{"can_id": base + k, "can_mask": 0x7FF, "extended": False} for k in range(7)]


class NetFtCan(WireDriver):
    """One Net F/T on ``bus`` (see the module docstring).

    Parameters
    ----------
    bus : can.BusABC
        Classic CAN at the sensor's bit rate.
    base : int
        The base address its DIP switches set.
    calibration : CalibrationInfo
        Its counts per force and torque unit (read from the device).
    serial_number : int
        What :meth:`identify` reports (the rig's name of the cell: the CAN protocol carries none).
    bitrate : int
        The bus's bit rate (for the bus-load warning of :meth:`set_rate`).
    adc_rate_hz : float
        Its own free-running sample rate (7000 S/s on a Net F/T).
    band_hz, max_phase_deg : float
        The band's top (None: 0.32 × the DAQ's rate) and the FRF phase the held value's random
        age may cost there, degrees.
    """

    def __init__(
        self,
        bus: Any,
        *,
        base: int,
        calibration: p.CalibrationInfo,
        serial_number: int = 0,
        timeout_s: float = 1.0,
        bitrate: int = 1_000_000,
        adc_rate_hz: float = 7000.0,
        band_hz: float | None = None,
        max_phase_deg: float = 2.0,
        label: str = "Net F/T",
    ) -> None:
        super().__init__(f"{label} (CAN base {base:#x})", timeout_s=timeout_s, log=log)
        self.bus = bus
        self.base = p.check_base(base)
        self.calibration = calibration
        self.calibration_matrix: np.ndarray | None = calibration.matrix()
        self.serial_number = serial_number
        self.bitrate = bitrate
        self.timing = HeldSampleTiming(float(adc_rate_hz), 1, self.name)
        self.band_hz = band_hz
        self.max_phase_deg = float(max_phase_deg)
        self.sample_rate_hz: float | None = None
        self.events: list[LoadCellEvent] = []
        self.streaming = False
        self._reset_run()

    _REQUEST_LONG = p.Request(p.Command.REQUEST_LONG).encode()

    @property
    def n_gauges(self) -> int:
        return 6

    # -- wire steps ------------------------------------------------------------------------------
    def _send(self, command: p.Command) -> None:
        import can

        try:
            self.bus.send(
                can.Message(
                    arbitration_id=self.base,
                    data=p.Request(command).encode(),
                    is_extended_id=False,
                )
            )
        except can.CanError as err:
            raise DeviceError(f"{self.name}: cannot send {command.name}: {err}") from err

    def _recv(self, timeout_s: float) -> tuple[int, bytes] | None:
        msg = self.bus.recv(max(timeout_s, 0.0))
        if msg is None:
            return None
        return int(msg.arbitration_id), bytes(msg.data)

    def _wire_error(self, err: Exception, what: str, deadline: Deadline) -> DeviceError | None:
        import can

        if isinstance(err, can.CanError):
            return DeviceError(f"{self.name}: {what}: {err}")
        return None

    def _close_transport(self) -> None:
        """The bus belongs to whoever opened it (the backend closes it)."""

    # -- outside a run ---------------------------------------------------------------------------
    def read_once(self, timeout_s: float | None = None) -> tuple[np.ndarray, int, int]:
        """One REQUEST LONG answered: ``(counts (6,) in AXES order, status, sample number)``.

        Raises
        ------
        DeviceTimeoutError
            The four answers did not all arrive in time.
        """
        if self.streaming:
            raise SetupError(f"{self.name}: streaming; read_once() outside a run only")

        def attempt(deadline: Deadline) -> tuple[np.ndarray, int, int]:
            self._drain()
            self._send(p.Command.REQUEST_LONG)
            got: dict[int, p.Message] = {}
            while len(got) < 4:
                frame = self._recv(deadline.left())
                if frame is None:
                    raise DeviceTimeoutError(
                        f"{self.name} did not answer REQUEST LONG within {deadline.timeout_s:g} s "
                        f"(answers {sorted(got)} of base+1..+4); check its power, CAN Bus on its "
                        "Communications page, the bit rate and the base address DIP switches"
                    )
                if not 0 <= frame[0] - self.base <= 6:
                    continue  # another sensor's on a shared bus
                msg = p.decode(self.base, *frame)
                if isinstance(msg, (p.LongPair, p.LongStatus)):
                    off = msg.offset if isinstance(msg, p.LongPair) else p.LongStatus.OFFSET
                    got[off] = msg
            pairs = [got[k] for k in (1, 2, 3)]
            st = got[4]
            assert isinstance(st, p.LongStatus)
            counts = np.array(
                [m.force for m in pairs if isinstance(m, p.LongPair)]
                + [m.torque for m in pairs if isinstance(m, p.LongPair)],
                dtype=float,
            )
            return counts, st.status, st.sample

        return self._exchange("REQUEST LONG", attempt, timeout_s=timeout_s, idempotent=True)

    def identify(self) -> LoadCellIdentity:
        """The sensor answers a REQUEST LONG (the CAN protocol has no identity message)."""
        _, status, _ = self.read_once()
        return LoadCellIdentity(
            n_gauges=6,
            firmware=f"Net F/T CAN base {self.base:#x}, status {status:#010x}",
            serial_number=self.serial_number,
        )

    def bias(self) -> None:
        """BIAS: zero the readings at the current load."""
        self._send(p.Command.BIAS)

    def _drain(self) -> None:
        while self._recv(0.0) is not None:
            pass

    # -- a run -----------------------------------------------------------------------------------
    def known_response(self, f_hz: np.ndarray) -> np.ndarray:
        """The factor its held values put on its FRFs (divided out by the acquisition)."""
        return self.timing.response(f_hz)

    def set_rate(self, rate_hz: int) -> float:
        """The requests come at the DAQ's rate; warns when they fill more than 80 % of the bus
        (a request and four answers per sample).

        Raises
        ------
        SetupError
            The held value's random age costs more than ``max_phase_deg`` at the band's top.
        """
        band = self.band_hz if self.band_hz is not None else 0.32 * float(rate_hz)
        self.timing.check(band, self.max_phase_deg, where=f"{self.name} at {rate_hz} S/s")
        load = rate_hz * 5 * _FRAME_BITS / self.bitrate
        if load > 0.8:
            log.warning(
                "%s: %d S/s of REQUEST LONG and its four answers is %.0f %% of a %d bit/s bus; "
                "samples will be lost on a real bus (lower the DAQ rate)",
                self.name,
                rate_hz,
                100 * load,
                self.bitrate,
            )
        self.sample_rate_hz = float(rate_hz)
        return self.sample_rate_hz

    def _reset_run(self) -> None:
        self._count = 0  # requests seen since start: sample count − 1 is being answered
        self._decided = 0  # samples 0 .. decided − 1 are filed or known incomplete
        self._cur: dict[int, tuple[int, int]] = {}
        self._stream: CounterStream[LoadCellEvent] = CounterStream(6, flag_dtype=np.bool_)
        self._pending_k: list[int] = []
        self._pending_v: list[list[float]] = []
        self._pending_bad: list[bool] = []
        self._last_sample: int | None = None
        self._status_seen = 0
        self._final: int | None = None

    def start(self, *, external_clock: bool = True) -> None:
        """Armed: the next request on the bus is sample 0. BIAS is sent first."""
        if not external_clock:
            raise SetupError(
                f"{self.name}: samples come with the requests sent on the DAQ's clock; start the "
                "DAQ (external_clock=True)"
            )
        self._require_open()
        self._drain()
        self.bias()
        self._reset_run()
        self.events = []
        self.streaming = True

    def _close_sample(self) -> None:
        """Sample ``count − 1`` is decided: filed when its four answers are in, else a hole
        (NaN, a gap)."""
        k = self._count - 1
        cur, self._cur = self._cur, {}
        self._decided = max(self._decided, self._count)
        if k < 0 or len(cur) < 4:
            return
        (fx, tx), (fy, ty), (fz, tz) = cur[1], cur[2], cur[3]
        status, sample = cur[4]
        bad = status != 0
        if bad and self._status_seen != status:
            self._record(
                LoadCellEvent(
                    "device_error",
                    k,
                    1,
                    f"{self.name}: system status word {status:#010x} at sample {k} (see the "
                    "manual's system status code); its samples are marked overload",
                )
            )
        self._status_seen = status
        if self._last_sample is not None and sample == self._last_sample:
            bad = True  # the same measurement twice: the sensor's own rate is below the DAQ's
        self._last_sample = sample
        self._pending_k.append(k)
        self._pending_v.append([fx, fy, fz, tx, ty, tz])
        self._pending_bad.append(bad)

    def _file(self, frame: tuple[int, bytes]) -> None:
        off = frame[0] - self.base
        if off == 0:
            if frame[1] == self._REQUEST_LONG:  # the next sample's SYNC
                if self._count > self._decided:
                    self._close_sample()
                self._count += 1
            return
        if self._count == self._decided or not 1 <= off <= 4:
            return  # an answer to no open request (the host's, a late repeat), or short data
        try:
            self._cur[off] = p.decode_long(off, frame[1])
        except ProtocolError as err:
            log.warning("%s: %s", self.name, err)
            return
        if len(self._cur) == 4:
            self._close_sample()

    def _flush(self) -> None:
        if not self._pending_k:
            return
        ks = np.asarray(self._pending_k, dtype=np.int64)
        self._stream.put_counters(
            ks, np.asarray(self._pending_v, dtype=float), np.asarray(self._pending_bad)
        )
        self._pending_k, self._pending_v, self._pending_bad = [], [], []

    def _record(self, ev: LoadCellEvent) -> None:
        self.events.append(ev)
        self._stream.record(ev)
        log.warning("%s", ev.message)

    def read_until(self, end_sample: int, timeout_s: float | None = None) -> LoadCellBlock:
        """Samples up to ``end_sample − 1`` (waits for their answers).

        Raises
        ------
        DeviceTimeoutError
            They did not come in time (what came is kept).
        """
        deadline = self._deadline(timeout_s)
        final = self._final
        while self._decided < end_sample and not (final is not None and end_sample <= final):
            frame = self._recv(min(deadline.left(), 0.05))
            if frame is not None:
                self._file(frame)
            elif deadline.passed:
                raise DeviceTimeoutError(
                    f"{self.name}: sample {end_sample - 1} not received within "
                    f"{deadline.timeout_s:g} s ({self._decided} in); are the requests sent on "
                    "the DAQ's clock?"
                )
        self._flush()
        st = self._stream
        first = st.next_sample
        if end_sample <= first:
            return LoadCellBlock(
                first,
                np.zeros((6, 0)),
                np.zeros((6, 0)),
                np.zeros(0, bool),
                np.zeros(0, bool),
                (),
            )
        got = st.take(end_sample)
        for a, b in false_runs(got.valid):
            st.record(
                LoadCellEvent(
                    "gap",
                    got.first + a,
                    b - a + 1,
                    f"{self.name}: {b - a + 1} samples from {got.first + a} incomplete (answers "
                    "lost on the bus)",
                )
            )
        events = st.pop_events(got.first, end_sample)
        gauges = got.data.T
        assert self.calibration_matrix is not None
        return LoadCellBlock(
            got.first,
            gauges,
            self.calibration_matrix @ gauges,
            got.valid,
            got.flags.astype(bool, copy=False),
            events,
        )

    def stop(self) -> int:
        """After the DAQ stopped: take the rest of the run's frames; the requests counted."""
        quiet = Deadline(_QUIET_S)
        give_up = Deadline(max(2.0, self.timeout_s))
        while not quiet.passed and not give_up.passed:
            frame = self._recv(min(quiet.left(), 0.02))
            if frame is not None:
                self._file(frame)
                quiet = Deadline(_QUIET_S)
        if self._count > self._decided:
            self._close_sample()
        self.streaming = False
        self._final = self._count
        self._flush()
        return self._count

    def verify_count(self, daq_samples_clocked: int) -> LoadCellEvent | None:
        """Requests counted against the DAQ's samples: unequal means the samples are not the
        DAQ's (a request lost or one too many)."""
        counted = self._final if self._final is not None else self._count
        if counted == daq_samples_clocked:
            return None
        ev = LoadCellEvent(
            "drift",
            min(counted, daq_samples_clocked),
            abs(counted - daq_samples_clocked),
            f"{self.name}: {counted} requests counted but the DAQ clocked {daq_samples_clocked} "
            "samples; the samples are misaligned (a request frame lost?)",
        )
        self.events.append(ev)
        return ev

    def close(self) -> None:
        self.streaming = False
        super().close()
