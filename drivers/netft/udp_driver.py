"""ATI Net F/T Raw Data Transfer (RDT) over UDP: requests and records of
:mod:`dimacq.drivers.netft.protocol`, on an injected, connected UDP socket.

What it does: one record on demand (:meth:`NetFtUdp.read_once`, :meth:`NetFtUdp.identify`), the
software bias, and, as a :class:`~dimacq.devices.loadcell.LoadCell`, an acquisition: START
buffered streaming (0x0003, until STOP) at the sensor's own rate, each record resampled to the
DAQ's sample grid.

**How its samples meet the DAQ's clock.** The Net F/T has no sync input: it samples on its own
crystal at its configured RDT output rate (its settings page; ``ft_sequence`` counts its
internal samples at ``ft_rate_hz``, so record ``j`` is at sensor time ``ft_sequence / ft_rate_hz``
exactly). The common time base is the host's monotonic clock: every datagram is stamped on
arrival, the lower envelope of the arrivals against ``ft_sequence`` gives the sensor's clock on
the host's (offset and rate: the sensor's crystal error is fitted), and the acquisition reports
the window around the DAQ's start request (:meth:`daq_clock_started`), which holds DAQ sample 0.
DAQ sample ``k`` is then a fractional record index, interpolated by a 4-point Lagrange cubic
(the method, its error and its budget: :mod:`dimacq.pipeline.stream_alignment`). The clock
fit moves as datagrams come in; the positions do not jump with it while a record may be open:
each block of samples continues the last and turns toward the fit by at most :data:`MAX_SLEW`
(a jump inside a hit's record cuts its loads from two delays — a lag that grows with
frequency and differs per load, which no single delay removes); between records
(:meth:`realign`) they go to the fit at once. START waits for 3 s of arrivals so that the fit has a slope. What the
host's clock cannot know — half the DAQ start window, the envelope's scatter and the network's
latency floor ``latency_floor_s`` — is its uncertainty ``δ``; it costs ``360° f δ`` of FRF phase
at frequency ``f`` (~100 µs: 36° at 1 kHz), so the host's clock is a coarse time base. Two ways
to finish (``time_base``):

- ``"data"`` (the rig file's default): the residual delay is estimated from the data, per input,
  by the acquisition (the hammer and the accelerometers are on the DAQ, the cell's loads here:
  the delay shows as a phase ``−2πfτ`` on every cell FRF, fitted against the rigid-body law
  that makes those loads real combinations of the accelerometers' FRFs and the hammer's:
  :func:`~dimacq.pipeline.stream_alignment.fit_delay`), and that estimate's uncertainty is what
  the phase budget ``max_phase_deg`` at ``band_hz`` is checked against (:meth:`delay_budget`).
  Here the driver refuses only a coarse alignment too poor to be refined (``δ`` above
  :data:`MAX_COARSE_S`) and marks later blocks ``drift`` if it becomes that poor;
- ``"host"``: the host's clock is the time base: on the first block the driver refuses the run
  (a :class:`~dimacq.errors.SetupError`) when ``360° band_hz δ`` exceeds ``max_phase_deg``, and
  marks later blocks ``drift`` (rejecting their averages) if it degrades. On a real network and
  DAQ the window is a USB request (~0.1–1 ms) and the DAQ's own crystal drifts against the
  host's (~20 ppm is 1.2 ms per minute): expect a real rig to be refused above a few tens of Hz.

The Net F/T's manual offers no sync input or trigger for RDT (``ft_sequence`` counts its own
clock only); ``netft-can`` (requests on the DAQ's clock) or ``daq-channels`` need no alignment.

A jump of ``rdt_sequence`` is a lost datagram: counted in :attr:`NetFtUdp.lost`, logged, and
every DAQ sample whose four surrounding records are not all in is NaN with a ``gap`` event (the
average is rejected, never interpolated across). A non-zero status word marks its samples
``overload`` with a ``device_error`` event.
"""

from __future__ import annotations

import logging
import socket
import struct
import sys
import time
from typing import Any

import numpy as np

from dimacq.devices.loadcell import LoadCellBlock, LoadCellEvent, LoadCellIdentity
from dimacq.drivers.base import Deadline, WireDriver
from dimacq.drivers.netft import protocol as p
from dimacq.drivers.netft.rdt_stream import MIN_WINDOWS as _MIN_WINDOWS
from dimacq.drivers.netft.rdt_stream import WINDOW_S as _WINDOW_S
from dimacq.drivers.netft.rdt_stream import RdtRun as _Run
from dimacq.drivers.stream import false_runs
from dimacq.errors import DeviceError, DeviceTimeoutError, ProtocolError, SetupError
from dimacq.pipeline.stream_alignment import (
    DelayBudget,
    lagrange4,
    phase_error_deg,
)

__all__ = ["NetFtUdp"]

log = logging.getLogger(__name__)

#: seconds without a datagram after STOP before the stream is taken as ended
_QUIET_S = 0.1
#: Linux's SO_TIMESTAMPNS (= SCM_TIMESTAMPNS; the socket module does not name it)
_SO_TIMESTAMPNS = 35
#: how fast the samples' positions may move toward a changed clock fit, s per s of the lab
#: (a crystal's few ppm): a 30 µs change is spread over 6 s, 5 µs across a 1 s record
MAX_SLEW = 5e-6
#: the coarsest host-clock alignment the data's delay fit refines, s of the lab's time: beyond
#: it the cell's response moves by more than a few DAQ samples against the hammer's record
#: window (its pre-trigger, its exponential window), and the fit's search grows long
MAX_COARSE_S = 0.01
#: the widest realtime-clock bracket around a monotonic read that gives the clocks' offset, ns
#: (two clock reads take ~0.1 µs; a preempted read takes milliseconds)
_OFFSET_BRACKET_NS = 20_000
#: the data's delay is sought within this many coarse uncertainties (and at least 1 ms)
_SEARCH_FACTOR = 4.0


def _empty(first: int) -> LoadCellBlock:
    return LoadCellBlock(
        first, np.zeros((6, 0)), np.zeros((6, 0)), np.zeros(0, bool), np.zeros(0, bool), ()
    )


class NetFtUdp(WireDriver):
    """A Net F/T's RDT interface on ``sock`` (``socket.socket(AF_INET, SOCK_DGRAM)`` connected
    to its address, port 49152).

    Parameters
    ----------
    sock : socket.socket
    calibration : CalibrationInfo
        Its counts per force and torque unit.
    serial_number : int
        What :meth:`identify` reports.
    rdt_rate_hz : float
        Its RDT output rate as its settings page says (records per second of its clock).
    ft_rate_hz : float
        Its internal sample rate: ``ft_sequence`` counts per second (7000 on a Net F/T).
    time_scale : float
        Seconds of the lab per second of the host's clock (1; a time-lapse simulation: more).
    band_hz, max_phase_deg : float
        The top of the band analysed (None: 0.32 × the DAQ's rate, the automatic band's top)
        and the FRF phase error allowed there.
    latency_floor_s : float
        The network's least latency, s (unknown to the host; in the budget).
    time_base : {"host", "data"}
        What the phase budget is checked against: the host clock's uncertainty (the driver
        refuses), or the data's delay fit (the acquisition refuses; see the module doc).
    fit_lo_hz : float
        ``"data"``: the lowest line of the delay fit, Hz.
    """

    def __init__(
        self,
        sock: Any,
        *,
        calibration: p.CalibrationInfo,
        serial_number: int = 0,
        timeout_s: float = 1.0,
        label: str = "Net F/T",
        rdt_rate_hz: float = 7000.0,
        ft_rate_hz: float = 7000.0,
        time_scale: float = 1.0,
        band_hz: float | None = None,
        max_phase_deg: float = 2.0,
        latency_floor_s: float = 20e-6,
        time_base: str = "host",
        fit_lo_hz: float = 50.0,
    ) -> None:
        if time_base not in ("host", "data"):
            raise SetupError(
                f"{label}: time base {time_base!r}; give netft_time_base = 'data' (the delay "
                "fitted from the data) or 'host' (the host's clock)"
            )
        ratio = ft_rate_hz / rdt_rate_hz if rdt_rate_hz > 0 else 0.0
        if rdt_rate_hz <= 0 or ratio < 1 or abs(ratio - round(ratio)) > 1e-9:
            raise SetupError(
                f"{label}: RDT rate {rdt_rate_hz:g} Hz and internal rate {ft_rate_hz:g} Hz: "
                "give the settings page's values (the internal rate a whole multiple of the "
                "RDT rate)"
            )
        peer = "?"
        try:
            host, port = sock.getpeername()[:2]
            peer = f"{host}:{port}"
        except (OSError, TypeError):
            pass
        super().__init__(f"{label} (RDT {peer})", timeout_s=timeout_s, log=log)
        self.sock = sock
        self.calibration = calibration
        self.calibration_matrix: np.ndarray | None = calibration.matrix()
        self.serial_number = serial_number
        self.sample_rate_hz: float | None = None
        self.events: list[LoadCellEvent] = []
        #: datagrams lost in the current stream (rdt_sequence jumps)
        self.lost = 0
        self._next_seq: int | None = None
        self.rdt_rate_hz = float(rdt_rate_hz)
        self.ft_rate_hz = float(ft_rate_hz)
        self.ft_per_record = round(ratio)
        self.time_scale = float(time_scale)
        self._band_hz = band_hz
        self.max_phase_deg = float(max_phase_deg)
        self.latency_floor_s = float(latency_floor_s)
        self.time_base = time_base
        self.fit_lo_hz = float(fit_lo_hz)
        self.streaming = False
        self._run: _Run | None = None
        self._daq_window: tuple[float, float] | None = None
        self._final: int | None = None
        self._rt_offset_ns: int | None = None
        self._stamps = self._enable_stamps()

    @property
    def n_gauges(self) -> int:
        return 6

    # -- wire steps ------------------------------------------------------------------------------
    def _send(self, req: p.RdtRequest) -> None:
        try:
            self.sock.send(req.encode())
        except OSError as err:
            raise DeviceError(f"{self.name}: cannot send {req.command.name}: {err}") from err

    def _recv(self, timeout_s: float) -> bytes | None:
        self.sock.settimeout(max(timeout_s, 1e-4))
        try:
            return bytes(self.sock.recv(65535))
        except (TimeoutError, BlockingIOError):
            return None
        except OSError as err:  # ICMP port unreachable on a connected socket, ...
            raise DeviceError(f"{self.name}: {err}") from err

    def _enable_stamps(self) -> bool:
        """Ask the kernel to stamp each datagram on arrival (Linux ``SO_TIMESTAMPNS``): the
        stamp does not wait for the reader, so the queue does not bias the clock fit."""
        if not sys.platform.startswith("linux"):
            return False
        try:  # room for a second of records between reads
            self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4 << 20)
        except (OSError, AttributeError):
            log.debug("%s: SO_RCVBUF not raised", self.name)
        try:
            self.sock.setsockopt(socket.SOL_SOCKET, _SO_TIMESTAMPNS, 1)
        except (OSError, AttributeError):
            return False
        return True

    def _recv_stamped(self, timeout_s: float) -> tuple[bytes, float] | None:
        """A datagram and its arrival on the host's monotonic clock (the kernel's stamp when it
        gives one, else the time it was read)."""
        if not self._stamps:
            data = self._recv(timeout_s)
            return None if data is None else (data, time.monotonic())
        self.sock.settimeout(max(timeout_s, 1e-4))
        try:
            data, anc, _flags, _addr = self.sock.recvmsg(65535, 64)
        except (TimeoutError, BlockingIOError):
            return None
        except OSError as err:
            raise DeviceError(f"{self.name}: {err}") from err
        for level, kind, payload in anc:
            if level == socket.SOL_SOCKET and kind == _SO_TIMESTAMPNS and len(payload) >= 16:
                sec, nsec = struct.unpack_from("@qq", payload)
                return bytes(data), 1e-9 * (sec * 1_000_000_000 + nsec - self._realtime_offset_ns())
        return bytes(data), time.monotonic()

    def _realtime_offset_ns(self) -> int:
        """``CLOCK_REALTIME − CLOCK_MONOTONIC``, ns: what turns the kernel's arrival stamps (on
        the realtime clock) into the monotonic clock the DAQ's start window is on.

        Read as ``r1, m, r2`` (the realtime clock on both sides of the monotonic one): the
        offset is ``(r1 + r2)/2 − m`` within ``(r2 − r1)/2``. A thread preempted between two
        reads (the scheduler, another thread taking the GIL: milliseconds under load) would
        put the stamp that far early — below the arrivals' floor, where the clock fit's lower
        envelope rests on it — so a read wider than :data:`_OFFSET_BRACKET_NS` is tried again
        (three times), and the last narrow one is kept otherwise (the offset moves only when
        the realtime clock is stepped)."""
        best: tuple[int, int] | None = None
        for _ in range(3):
            r1 = time.time_ns()
            m = time.monotonic_ns()
            r2 = time.time_ns()
            if best is None or r2 - r1 < best[0]:
                best = (r2 - r1, (r1 + r2) // 2 - m)
            if best[0] <= _OFFSET_BRACKET_NS:
                self._rt_offset_ns = best[1]
                break
        assert best is not None
        if self._rt_offset_ns is None:  # never a narrow read yet: the narrowest
            return best[1]
        return self._rt_offset_ns

    def _drain(self) -> None:
        while self._recv(1e-4) is not None:
            pass

    # -- commands ----------------------------------------------------------------------------------
    def bias(self) -> None:
        """Set the software bias: zero the readings at the current load."""
        self._require_open()
        self._send(p.RdtRequest(p.RdtCommand.SET_BIAS))

    def start_streaming(self, sample_count: int = 0, *, buffered: bool = False) -> None:
        """Start records (``sample_count`` of them, 0: until :meth:`stop_streaming`)."""
        self._require_open()
        cmd = p.RdtCommand.START_BUFFERED if buffered else p.RdtCommand.START_REALTIME
        self._next_seq = None
        self.lost = 0
        self._send(p.RdtRequest(cmd, sample_count))

    def stop_streaming(self) -> None:
        self._send(p.RdtRequest(p.RdtCommand.STOP))

    def read_records(self, timeout_s: float | None = None) -> list[p.RdtRecord]:
        """The records of the next datagram (empty when none came in time); sequence jumps are
        counted in :attr:`lost`."""
        data = self._recv(self.timeout_s if timeout_s is None else timeout_s)
        if data is None:
            return []
        recs = p.RdtRecord.decode_all(data)
        for r in recs:
            if self._next_seq is not None and r.rdt_sequence != self._next_seq:
                missed = (r.rdt_sequence - self._next_seq) & 0xFFFFFFFF
                self.lost += missed
                log.warning(
                    "%s: rdt_sequence jumped from %d to %d: %d record(s) lost",
                    self.name,
                    self._next_seq - 1,
                    r.rdt_sequence,
                    missed,
                )
            self._next_seq = (r.rdt_sequence + 1) & 0xFFFFFFFF
        return recs

    def read_once(self, timeout_s: float | None = None) -> p.RdtRecord:
        """One record: START with sample_count 1, its answer.

        Raises
        ------
        DeviceTimeoutError
            No record in time (names the port and the fix).
        """

        def attempt(deadline: Deadline) -> p.RdtRecord:
            self._drain()
            self.start_streaming(1)
            while True:
                recs = self.read_records(deadline.left())
                if recs:
                    return recs[-1]
                if deadline.passed:
                    raise DeviceTimeoutError(
                        f"{self.name} sent no RDT record within {deadline.timeout_s:g} s; check "
                        f"its IP address, that RDT is enabled, and UDP port {p.RDT_PORT}"
                    )

        return self._exchange("RDT read", attempt, timeout_s=timeout_s, idempotent=True)

    def loads(self, record: p.RdtRecord) -> np.ndarray:
        """A record's loads: N (Fx Fy Fz) and N·m (Tx Ty Tz)."""
        assert self.calibration_matrix is not None
        return self.calibration_matrix @ np.asarray(record.counts, dtype=float)

    def identify(self) -> LoadCellIdentity:
        rec = self.read_once()
        return LoadCellIdentity(
            n_gauges=6,
            firmware=f"Net F/T RDT, status {rec.status:#010x}",
            serial_number=self.serial_number,
        )

    # -- the LoadCell protocol: a buffered stream put on the DAQ's sample grid ---------------------
    def daq_clock_started(self, t_before_s: float, t_after_s: float) -> None:
        """The host's monotonic clock before and after the request that started the DAQ's sample
        clock: DAQ sample 0 lies between (the acquisition calls this after the DAQ's start)."""
        if not t_before_s <= t_after_s:
            raise SetupError(
                f"{self.name}: DAQ start window {t_before_s}..{t_after_s} s is reversed; give "
                "the time before the start request first"
            )
        self._daq_window = (t_before_s, t_after_s)

    def set_rate(self, rate_hz: int) -> float:
        """The DAQ's rate: the grid the records are resampled to (the sensor keeps its own)."""
        if rate_hz <= 0:
            raise SetupError(f"{self.name}: DAQ rate {rate_hz} S/s; give a positive rate")
        self.sample_rate_hz = float(rate_hz)
        return self.sample_rate_hz

    def start(self, *, external_clock: bool = True) -> None:
        """Bias, then START buffered streaming until STOP; returns once records flow (the DAQ
        is started right after)."""
        if not external_clock:
            raise SetupError(
                f"{self.name}: its records are put on the DAQ's clock; start the DAQ "
                "(external_clock=True)"
            )
        if self.sample_rate_hz is None:
            raise SetupError(f"{self.name}: call set_rate(the DAQ's rate) before start()")
        self._require_open()
        self._drain()
        self.bias()
        self.events = []
        self._run = _Run(self.rdt_rate_hz, 1.0 / self.time_scale)
        self._daq_window = None
        self._final = None
        self.start_streaming(0, buffered=True)
        self.streaming = True
        # the stream runs before the DAQ starts: its first samples have records on both sides,
        # and the clock fit has the windows it needs for a slope (~1.5 s of the host's time)
        deadline = self._deadline()
        while self._run.end < 4:
            if not self._receive(min(deadline.left(), 0.05)) and deadline.passed:
                raise DeviceTimeoutError(
                    f"{self.name} sent no RDT records within {deadline.timeout_s:g} s of START; "
                    f"check that RDT is enabled and UDP port {p.RDT_PORT}"
                )
        settle = Deadline(_MIN_WINDOWS * _WINDOW_S + self.timeout_s)
        while self._run.n_windows < _MIN_WINDOWS:
            if not self._receive(min(settle.left(), 0.05)) and settle.passed:
                raise DeviceTimeoutError(
                    f"{self.name}: RDT records stopped within {settle.timeout_s:g} s of START "
                    f"({self._run.end} in); check the network and UDP port {p.RDT_PORT}"
                )

    def _receive(self, timeout_s: float) -> bool:
        """One datagram into the run (False: none in time)."""
        got = self._recv_stamped(timeout_s)
        if got is None:
            return False
        data, t = got
        try:
            blk = p.decode_rdt(data)
        except ProtocolError as err:
            log.warning("%s: %s", self.name, err)
            return True
        run = self._run
        assert run is not None
        j = blk.rdt_sequence - 1  # rdt_sequence is 1 for the first record after START
        if run.ft0 is None:
            run.ft0 = int(blk.ft_sequence[0]) - int(j[0]) * self.ft_per_record
        expect = run.ft0 + j * self.ft_per_record
        if np.any(blk.ft_sequence != expect):
            raise SetupError(
                f"{self.name}: ft_sequence advances by "
                f"{int(np.median(np.diff(blk.ft_sequence))) if blk.ft_sequence.size > 1 else '?'}"
                f" per record, not {self.ft_per_record}: give the sensor's RDT output rate "
                "(netft_rdt_rate_hz) and internal rate (netft_ft_rate_hz) as its settings page "
                "shows them"
            )
        if self._next_seq is not None and int(blk.rdt_sequence[0]) != self._next_seq:
            missed = (int(blk.rdt_sequence[0]) - self._next_seq) & 0xFFFFFFFF
            self.lost += missed
            log.warning(
                "%s: rdt_sequence jumped from %d to %d: %d record(s) lost",
                self.name,
                self._next_seq - 1,
                int(blk.rdt_sequence[0]),
                missed,
            )
        self._next_seq = (int(blk.rdt_sequence[-1]) + 1) & 0xFFFFFFFF
        run.put(j, blk.counts, blk.status, t, float(expect[-1]) / self.ft_rate_hz)
        return True

    def _positions(self, ks: np.ndarray, *, fit_only: bool = False) -> tuple[np.ndarray, float]:
        """Fractional record indices of DAQ samples ``ks`` and the alignment's uncertainty (s
        of the lab's time): see :mod:`dimacq.pipeline.stream_alignment`; the clock fit's
        positions plus the run's correction (``fit_only``: without it)."""
        run = self._run
        assert run is not None and self.sample_rate_hz is not None
        if self._daq_window is None:
            raise SetupError(
                f"{self.name}: no DAQ start time: RDT records can only be put on the DAQ's "
                "clock through the host's clock (the acquisition reports the DAQ's start)"
            )
        fit = run.fit(1.0 / self.time_scale)
        t_a, t_b = self._daq_window
        t0 = 0.5 * (t_a + t_b)
        t_k = t0 + ks / (self.sample_rate_hz * self.time_scale)  # host time of DAQ sample k
        s_k = (t_k - fit.offset_s) / fit.slope  # sensor seconds
        assert run.ft0 is not None
        u = (s_k - run.ft0 / self.ft_rate_hz) * self.rdt_rate_hz
        if not fit_only:
            u = u + run.corr
        wall = 0.5 * (t_b - t_a) + fit.scatter_s + self.latency_floor_s
        return u, wall * self.time_scale

    def _block_positions(
        self, first: int, end_sample: int, *, commit: bool = True
    ) -> tuple[np.ndarray, float]:
        """Positions of DAQ samples ``first .. end_sample − 1``, continuous with the block
        before: the clock fit changes as windows come in (its line rests on the datagrams
        that waited least; a new one moves it), and a move applied at once would be a jump of
        the samples' times inside a hit's record — its loads mixed from two delays, an error
        that grows with frequency and differs per load. So the block starts where the last
        one ended and its correction ``c`` (records added to the fit's positions) ramps
        toward the fit, by at most :data:`MAX_SLEW` s per s of the lab::

            c(k) = c_0 + (c_1 − c_0) (k − first) / n,   c_0 = u_prev(first) − u_fit(first),
            c_1 = c_0 − clip(c_0, ±MAX_SLEW · n / f_DAQ · f_RDT)

        (``n`` samples in the block, ``f_RDT`` records per second of the lab); ``commit``:
        the block is delivered (the next one continues from it)."""
        run = self._run
        assert run is not None and self.sample_rate_hz is not None
        ks = np.arange(first, end_sample + 1, dtype=float)
        u_fit, delta = self._positions(ks, fit_only=True)
        c0 = 0.0 if run.u_next is None else run.u_next - float(u_fit[0])
        n = end_sample - first
        step = MAX_SLEW * n / self.sample_rate_hz * self.rdt_rate_hz
        c1 = c0 - float(np.clip(c0, -step, step))
        u = u_fit + c0 + (c1 - c0) * (ks - first) / n
        if commit:
            run.corr, run.u_next = c1, float(u[-1])
            run.blocks.append((first, float(u[0]), float(u[-1] - u[0]) / n))
        return u[:-1], delta

    def realign(self) -> None:
        """No record is open (the acquisition calls this once a hit's record is cut, before it
        asks for the next): the next block's positions go to the clock fit at once instead of
        turning toward it at :data:`MAX_SLEW` — the jump falls between records, and the
        inputs are not left behind a moved fit for seconds."""
        if self._run is not None:
            self._run.u_next, self._run.corr = None, 0.0

    @property
    def band_hz(self) -> float:
        """Where the alignment's phase is checked, Hz."""
        if self._band_hz is not None:
            return float(self._band_hz)
        return 0.32 * (self.sample_rate_hz or 0.0)

    def alignment_phase_deg(self) -> float:
        """The phase error, degrees, that the host clock's uncertainty costs at ``band_hz``."""
        _, delta = self._positions(np.zeros(1))
        return phase_error_deg(delta, self.band_hz)

    def delay_budget(self) -> DelayBudget | None:
        """With ``time_base = "data"``: what the acquisition's delay fit needs and is checked
        against (None with ``"host"``: the samples are final)."""
        if self.time_base != "data":
            return None
        delta = MAX_COARSE_S
        if self._run is not None and self._run.n_arrivals and self._daq_window is not None:
            delta = self._positions(np.zeros(1))[1]
        return DelayBudget(
            search_s=max(_SEARCH_FACTOR * delta, 1e-3),
            lo_hz=self.fit_lo_hz,
            band_hz=self.band_hz,
            max_phase_deg=self.max_phase_deg,
            label=self.name,
        )

    def _too_coarse(self, delta: float, phase: float) -> bool:
        return delta > MAX_COARSE_S if self.time_base == "data" else phase > self.max_phase_deg

    def read_until(self, end_sample: int, timeout_s: float | None = None) -> LoadCellBlock:
        """DAQ samples up to ``end_sample − 1``, resampled from the records around them (waits
        for the records that follow the last one).

        Raises
        ------
        SetupError
            The alignment's phase error at ``band_hz`` is above ``max_phase_deg`` (checked on
            the first block: the run is refused).
        DeviceTimeoutError
            The records did not come in time.
        """
        run = self._run
        if run is None:
            raise SetupError(f"{self.name}: start() before read_until()")
        deadline = self._deadline(timeout_s)
        first = run.next_sample
        if end_sample <= first:
            return _empty(first)
        while True:
            if run.n_arrivals:
                u_last = float(self._block_positions(first, end_sample, commit=False)[0][-1])
                if run.end > np.floor(u_last) + 2 or self._final is not None:
                    break
            if not self._receive(min(deadline.left(), 0.05)) and deadline.passed:
                raise DeviceTimeoutError(
                    f"{self.name}: DAQ sample {end_sample - 1} not covered by RDT records within "
                    f"{deadline.timeout_s:g} s ({run.end} records in); is it streaming?"
                )
        ks = np.arange(first, end_sample, dtype=float)
        u, delta = self._block_positions(first, end_sample)
        phase = phase_error_deg(delta, self.band_hz)
        if not run.checked:
            run.checked = True
            log.info(
                "%s: aligned to the DAQ's clock within %.1f us (%.2f deg at %g Hz)",
                self.name,
                1e6 * delta,
                phase,
                self.band_hz,
            )
            if self.time_base == "data" and delta > MAX_COARSE_S:
                raise SetupError(
                    f"{self.name}: the host's clock aligns its records to the DAQ's within only "
                    f"{1e3 * delta:.1f} ms, more than the {1e3 * MAX_COARSE_S:g} ms the data's "
                    "delay fit refines (a loaded host, a slow network?); lower the load or "
                    "read the cell as loadcell = 'netft-can' or 'daq-channels'"
                )
            if self.time_base == "host" and phase > self.max_phase_deg:
                raise SetupError(
                    f"{self.name}: its records are aligned to the DAQ's clock within only "
                    f"{1e6 * delta:.0f} us, {phase:.1f} deg of FRF phase at {self.band_hz:g} Hz "
                    f"(limit netft_max_phase_deg = {self.max_phase_deg:g}); lower netft_band_hz "
                    "to the band you analyse, or read the cell as loadcell = 'netft-can' or "
                    "'daq-channels'"
                )
        vals = run.values()
        forces_counts = lagrange4(vals, u).T  # (6, n)
        valid = np.all(np.isfinite(forces_counts), axis=0)
        flagged = lagrange4(run.flags(), u)[:, 0]
        overload = np.nan_to_num(flagged, nan=0.0) != 0.0
        events: list[LoadCellEvent] = []
        for a, b in false_runs(valid):
            events.append(
                LoadCellEvent(
                    "gap",
                    first + a,
                    b - a + 1,
                    f"{self.name}: {b - a + 1} samples from {first + a} not resampled: RDT "
                    f"records around them lost ({self.lost} lost so far, rdt_sequence jumps); "
                    "the average is rejected",
                )
            )
        if np.any(overload):
            k = int(np.argmax(overload))
            events.append(
                LoadCellEvent(
                    "device_error",
                    first + k,
                    int(overload.sum()),
                    f"{self.name}: status word {run.last_bad_status:#010x} (see the manual's "
                    "status code); its samples are marked overload",
                )
            )
        if self._too_coarse(delta, phase):
            events.append(
                LoadCellEvent(
                    "drift",
                    first,
                    len(ks),
                    f"{self.name}: alignment to the DAQ's clock degraded to {1e6 * delta:.0f} us "
                    f"({phase:.1f} deg at {self.band_hz:g} Hz)",
                )
            )
        for ev in events:
            self.events.append(ev)
            log.warning("%s", ev.message)
        run.next_sample = end_sample
        gauges = np.where(np.isfinite(forces_counts), forces_counts, np.nan)
        assert self.calibration_matrix is not None
        return LoadCellBlock(
            first,
            gauges,
            self.calibration_matrix @ gauges,
            valid,
            overload,
            tuple(events),
        )

    def alignment_offsets_s(self, records: list[list[tuple[int, int]]]) -> np.ndarray | None:
        """How far each input's records were put from where the whole run's clock fit puts them
        now, as a delay (s of the lab's time; None before a run): per input, over its records
        ``(first_sample, n_samples)`` (nine points each), ``−mean(u_delivered − u_fit) /
        f_RDT`` — the positions delivered (the fit of their time, slewed) against the fit over
        every arrival. What the inputs share (the start window, the latency floor) is the
        run's delay's, not theirs: take them about their mean. NaN: an input without records
        of this run."""
        run = self._run
        if run is None or not run.blocks or self._daq_window is None:
            return None
        b_first, b_u, b_step = (np.array(c) for c in zip(*run.blocks, strict=True))
        out = np.full(len(records), np.nan)
        for i, recs in enumerate(records):
            if not recs:
                continue
            ks = np.concatenate([s0 + np.linspace(0.0, n - 1, 9) for s0, n in recs])
            b = np.clip(np.searchsorted(b_first, ks, side="right") - 1, 0, None)
            u = b_u[b] + b_step[b] * (ks - b_first[b])
            out[i] = -float(np.mean(u - self._positions(ks, fit_only=True)[0])) / self.rdt_rate_hz
        return out

    def stop(self) -> int:
        """STOP; the records still on their way taken; the DAQ samples they cover."""
        self.stop_streaming()
        run = self._run
        if run is None:
            return 0
        quiet = Deadline(_QUIET_S)
        while not quiet.passed:
            if self._receive(min(quiet.left(), 0.02)):
                quiet = Deadline(_QUIET_S)
        self.streaming = False
        covered = 0
        if run.n_arrivals and self._daq_window is not None and run.end >= 4:
            # the last DAQ sample with two records after it
            lo, hi = run.next_sample, run.next_sample + 1
            while float(self._positions(np.array([float(hi)]))[0][0]) < run.end - 3:
                lo, hi = hi, 2 * hi + 1
            while hi - lo > 1:
                mid = (lo + hi) // 2
                if float(self._positions(np.array([float(mid)]))[0][0]) < run.end - 3:
                    lo = mid
                else:
                    hi = mid
            covered = lo + 1
        self._final = covered
        return covered

    def verify_count(self, daq_samples_clocked: int) -> LoadCellEvent | None:
        """The stream must cover every sample the DAQ clocked."""
        covered = self._final if self._final is not None else 0
        if covered >= daq_samples_clocked:
            return None
        ev = LoadCellEvent(
            "gap",
            covered,
            daq_samples_clocked - covered,
            f"{self.name}: RDT records cover {covered} DAQ samples of {daq_samples_clocked} "
            "clocked (the stream stopped early?)",
        )
        self.events.append(ev)
        return ev

    def _close_transport(self) -> None:
        """The socket belongs to whoever opened it (the backend closes it)."""
