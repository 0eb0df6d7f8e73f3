"""Impact-test acquisition session: DAQ + load cells → checked averages → FRFs, streamed to disk.

:class:`ImpactSession` runs a roving-hammer test on a :class:`~dimacq.devices.daq.Daq` task and
any number of :class:`~dimacq.devices.loadcell.LoadCell` amplifiers that count the DAQ's sample
clock:

1. **Synchronised start**: every amplifier is armed (counter 0 at the DAQ's next pulse), then the
   DAQ starts; at the end the DAQ stops first, then the amplifiers, and each amplifier's pulse
   count is checked against the DAQ's sample counter (``verify_count``).
2. **Streaming to disk**: every block read (DAQ and load cells, aligned by the sample counter) is
   appended to an :class:`~dimacq.io.acquisition_hdf5.AcquisitionWriter` as it arrives (flushed at
   least every second), with every event and every average's verdict.
3. **Per input, per average**: the operator is asked to strike (``operator(input, sample)``; in
   simulation that strikes the virtual lab), the hammer channel is watched for the trigger level,
   and a record of ``record_samples`` starting ``pretrigger_samples`` before the trigger is cut.
   The trigger is sought from the DAQ's clock at the moment of asking
   (``daq.samples_clocked_now()``), not from what the host has read: when the host is behind
   (a backlog in the DAQ's FIFO), a strike asked for now lands after the clock's present sample,
   and a hit before it is an earlier request's — a strike asked again after a gap that had in fact
   landed after the gap would otherwise be filed as the next request's, and every input after it
   would carry the one before's FRFs (seen at 37× time-lapse on a loaded machine: the inputs
   after the gap shifted by one, a DIM residual of 0.28; the solve refused it). Devices that
   cannot tell (None) are searched from what the host has read.
   It is **rejected** (and the operator asked again) when any channel overloaded, a DAQ or load
   cell sample in it was lost, the load cell reported drift, or the force shows a double hit.
   Rejected averages stay on disk; accepted ones are kept for the FRFs.
   A DAQ gap (FIFO overflow, lost transfer) names its kind and samples in the reason. A gap
   while waiting for the trigger **loses the strike** (it may have been in the gap): it is asked
   again, reported (``on_lost``, an event) and not counted against the strike budget; at most
   ``max_attempts_factor × averages_per_input`` strikes are lost per input.
   **The DAQ drops off the bus** (USB re-enumeration): the run is restarted — load cells
   stopped, the DAQ found again (``daq.reconnect()``), everything armed and started anew (sample
   counters from 0) — and the input struck again; the average in progress is lost (an event and
   a progress message say so), the accepted ones are kept. At most ``max_restarts`` restarts.
4. **Enough averages**: an input is struck until ``averages_per_input`` are accepted or
   ``max_attempts_factor × averages_per_input`` strikes are used; an input left with fewer than
   ``min_averages`` accepted averages is **incomplete**: it gets no FRF (one average would give a
   coherence of 1 identically, whatever the noise) and the result names it
   (:attr:`ImpactResult.incomplete_inputs`); when every input is incomplete the session raises.
5. **FRFs** per input from its accepted averages (:func:`~dimacq.pipeline.frf_estimation.
   estimate_frf`), with the force window on the hammer and the exponential window on everything
   (both starting at the trigger), stacked to ``(n_lines, n_outputs, n_inputs)``.

**Operator review** (optional ``review``): every hit, with the automatic checks' reasons and its
record, is handed to ``review(input_index, average_index, reasons, blocks)``, which returns the
operator's decision: ``"accept"`` (kept, when the checks passed: an overload or a double hit stays
rejected), ``"override"`` (kept although the checks rejected it, with
:data:`OPERATOR_OVERRIDE` among its reasons; never a hit with samples lost, whose record has
holes: :func:`unusable_reasons`), ``"reject`` (rejected "by the operator", strike again) or
``"redo"`` (this hit and every average accepted so far for the input are dropped and the input
starts again: its strike budget too). While the operator looks, the DAQ is drained at its own
pace (:meth:`ImpactSession._ask_review`): no sample is lost to the wait, however long. ``should_finish()`` (optional) is asked before every strike:
when it answers True the session stops striking and estimates FRFs from what it has (the inputs
short of ``min_averages`` are incomplete), the "stop, keep the accepted averages" of the lab page.

``on_average(input_index, average_index, accepted, reasons, blocks)`` is called as soon as an
average is decided (before ``progress`` and before the operator is asked for the next strike), so
a caller can make each average durable on its own; ``progress(Progress)`` is called after it.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import asdict, dataclass, field
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from dimacq.devices.daq import Daq
from dimacq.devices.loadcell import LoadCell
from dimacq.errors import DataError, DeviceError, DeviceLostError, SetupError
from dimacq.io.acquisition_hdf5 import AcquisitionWriter
from dimacq.model.impact import ImpactSettings
from dimacq.pipeline.frf_estimation import (
    double_hit_mask,
    exponential_window,
)
from dimacq.services.acquisition.data_alignment import DataAligner
from dimacq.services.acquisition.impact_result import (
    OPERATOR_OVERRIDE,
    OPERATOR_REDO,
    OPERATOR_REJECT,
    AverageCallback,
    AverageRecord,
    Decision,
    ImpactResult,
    Progress,
    ReviewCallback,
    impact_frf,
    input_frf,
    records_frf,
    unusable_reasons,
)
from dimacq.services.acquisition.impact_stream import ImpactStream, StrikeLost
from dimacq.services.acquisition.known_response import KnownResponses
from dimacq.services.acquisition.sample_window import SampleWindow

__all__ = [
    "OPERATOR_OVERRIDE",
    "OPERATOR_REDO",
    "OPERATOR_REJECT",
    "AverageCallback",
    "AverageRecord",
    "Decision",
    "ImpactResult",
    "ImpactSession",
    "ImpactSettings",
    "Progress",
    "ReviewCallback",
    "impact_frf",
    "input_frf",
    "records_frf",
]

log = logging.getLogger(__name__)

#: While a hit waits for review, a DAQ that answers every read at once (clocked by the host's
#: reads, or with a backlog in its FIFO) is read at most this many times real time.
DRAIN_SPEED = 32.0


def _n_gauges(lc: LoadCell) -> int:
    """Gauges of a load cell: its own count when it says (a cell on DAQ inputs), else 12."""
    n = getattr(lc, "n_gauges", None)
    return int(n) if isinstance(n, int) else 12


@dataclass
class _RunState:
    """What a run has gathered so far: the accepted records per input (one input's at a time:
    dropped once its FRF is in), every average's record, where the next strike is looked for,
    the FRFs filled input by input and the accepted count of each finished input."""

    records: list[list[Mapping[str, NDArray[np.float64]]]]
    history: list[AverageRecord] = field(default_factory=list)
    armed_from: int = 0
    finished_early: bool = False
    H_all: NDArray[np.complex128] | None = None
    coh_all: NDArray[np.float64] | None = None
    freqs: NDArray[np.float64] | None = None
    n_accepted: list[int] = field(default_factory=list)


@dataclass
class _InputCount:
    """One input's strikes: rejected, attempted (the budget) and lost to sample gaps."""

    rejected: int = 0
    attempts: int = 0
    lost: int = 0


class ImpactSession(ImpactStream):
    """A roving-hammer impact test.

    Parameters
    ----------
    daq : Daq
        Configured task (channels and timing set, not started).
    input_channels : sequence of str
        DAQ channel of the hammer force for each input (may repeat: one roving hammer).
    response_channels : sequence of str
        DAQ channels used as outputs.
    loadcells : sequence of LoadCell
    settings : ImpactSettings
    writer : AcquisitionWriter, optional
    operator : callable (input_index, daq_sample) -> None, optional
        Asked to strike input ``input_index`` at about DAQ sample ``daq_sample``.
    progress : callable (Progress) -> None, optional
    on_average : callable (input_index, average_index, accepted, reasons, blocks), optional
        Called with every average as soon as it is decided, before the next strike (see
        :data:`AverageCallback`); an exception raised there stops the session (devices are
        stopped, the averages already handed over stay with the caller).
    loadcell_outputs : {"forces", "gauges"}
        FRF outputs per load cell: its 6 calibrated loads, or its 12 gauge voltages
        (for calibrating it).
    review : callable (input_index, average_index, reasons, blocks, wait_s), optional
        The operator's accept / reject / redo of every hit (see the module docstring); None:
        the automatic checks decide.
    should_finish : callable () -> bool, optional
        Asked before every strike; True ends the striking (FRFs from what is accepted).
    on_input : callable (input_index, coherence), optional
        Called when an input's FRFs are estimated, with its ordinary coherence, shape
        (n_lines, n_outputs) (NaN with one average).
    on_lost : callable (input_index, reason), optional
        Called with every strike lost while waiting for it (DAQ samples lost: the strike may
        have been among them; ``reason`` e.g. ``"DAQ samples lost (FIFO overflow)"``). A lost
        strike is asked again and not counted against the strike budget; at most
        ``max_attempts_factor × averages_per_input`` are lost per input, then the input is
        left as it is (incomplete if short of ``min_averages``).
    on_event : callable (event), optional
        Called with every event the session logs (a dict: ``device``, ``kind``, ``message``,
        …), among them ``kind="restart"`` when the DAQ dropped off the bus and
        ``kind="reconnected"`` when it is back, ``kind="lost"`` when it stopped answering (the
        run fails); on the acquisition's thread, so keep it cheap.
    input_labels : sequence of str, optional
        The inputs' names in messages ("101+X"; default: the hammer channels).
    prior : sequence (one per input) of sequences of records, optional
        Accepted averages kept from an interrupted acquisition (a resumed one): each input
        starts with them and is struck only for the ``averages_per_input`` still missing; its
        FRFs use them and the new ones alike (records as in :data:`AverageCallback`).
    """

    def __init__(
        self,
        daq: Daq,
        input_channels: Sequence[str],
        response_channels: Sequence[str],
        loadcells: Sequence[LoadCell] = (),
        *,
        settings: ImpactSettings | None = None,
        writer: AcquisitionWriter | None = None,
        operator: Callable[[int, int], None] | None = None,
        progress: Callable[[Progress], None] | None = None,
        on_average: AverageCallback | None = None,
        loadcell_outputs: Literal["forces", "gauges"] = "forces",
        review: ReviewCallback | None = None,
        should_finish: Callable[[], bool] | None = None,
        on_input: Callable[[int, NDArray[np.float64]], None] | None = None,
        max_restarts: int = 5,
        on_event: Callable[[dict[str, object]], None] | None = None,
        input_labels: Sequence[str] | None = None,
        prior: Sequence[Sequence[Mapping[str, NDArray[np.float64]]]] | None = None,
        on_lost: Callable[[int, str], None] | None = None,
    ) -> None:
        self.on_input = on_input
        self.on_lost = on_lost
        self._lost: list[int] = []
        self.on_event = on_event
        self.daq = daq
        self.review = review
        self.should_finish = should_finish
        self.max_restarts = max_restarts
        #: runs restarted after the DAQ dropped off the bus
        self.restarts = 0
        self._gaps: list[tuple[int, int, str]] = []
        self.settings = settings or ImpactSettings()
        if prior is not None and len(prior) != len(input_channels):
            raise SetupError(
                f"{len(prior)} lists of kept averages for {len(input_channels)} inputs; give one "
                "per input (empty: none kept)"
            )
        #: accepted averages kept from an interrupted acquisition, per input (a resumed one)
        self.prior = [list(p) for p in prior] if prior is not None else None
        names = list(daq.channel_names)
        missing = [c for c in (*input_channels, *response_channels) if c not in names]
        if missing:
            raise SetupError(f"channels {missing} are not in the DAQ task; add them first")
        self.input_rows = [names.index(c) for c in input_channels]
        self.response_rows = [names.index(c) for c in response_channels]
        # inputs are named by point and direction ("101+X") where the caller knows them: the
        # hammer's channel is one name for every input
        if input_labels is not None and len(input_labels) != len(input_channels):
            raise SetupError(
                f"{len(input_labels)} input labels for {len(input_channels)} inputs; give one each"
            )
        self.input_names = tuple(input_labels if input_labels is not None else input_channels)
        self.response_names = tuple(response_channels)
        self.loadcells = list(loadcells)
        if loadcell_outputs == "forces" and any(lc.calibration_matrix is None for lc in loadcells):
            raise SetupError(
                "a load cell has no calibration matrix; set one (or use loadcell_outputs="
                "'gauges' to calibrate it)"
            )
        self.loadcell_outputs = loadcell_outputs
        self.writer = writer
        self.operator = operator
        self.progress = progress
        self.on_average = on_average
        s = self.settings
        if not 0 <= s.pretrigger_samples < s.record_samples:
            raise SetupError("pretrigger_samples must be in [0, record_samples)")
        if s.min_averages < 1 or s.averages_per_input < 1:
            raise SetupError(
                f"min_averages {s.min_averages} / averages_per_input {s.averages_per_input}: "
                "give at least 1 (2 or more for a coherence)"
            )

    # -- streaming -------------------------------------------------------------------------------

    # -- one average ---------------------------------------------------------------------------------

    def _check(
        self, input_index: int, s0: int, n: int
    ) -> tuple[list[str], dict[str, NDArray[np.float64]]]:
        reasons: list[str] = []
        data, valid, over = self._daq_buf.window(s0, n)
        if not valid.all():
            kinds = sorted(
                {
                    "FIFO overflow" if k == "overflow" else "transfer lost"
                    for a, b, k in self._gaps
                    if a < s0 + n and b > s0
                }
            )
            why = f": {', '.join(kinds)}" if kinds else ""
            reasons.append(f"DAQ samples lost ({int((~valid).sum())}{why})")
        if over.any():
            chans = [self.daq.channel_names[i] for i in np.flatnonzero(over.any(axis=1))]
            reasons.append(f"overload on {', '.join(chans)}")
        force = data[self.input_rows[input_index]]
        if (
            valid.all()
            and double_hit_mask(force[None], threshold=self.settings.double_hit_threshold)[0]
        ):
            reasons.append("double hit")
        lc_rows = []
        for k, buf in enumerate(self._lc_bufs):
            d, v, o = buf.window(s0, n)
            if not v.all():
                reasons.append(f"load cell {k} samples lost ({int((~v).sum())})")
            if o.any():
                reasons.append(f"load cell {k} overload")
            if any(a < s0 + n and b > s0 for a, b in buf.drift):
                reasons.append(f"load cell {k} clock drift")
            errs = {m for a, b, m in buf.errors if a < s0 + n and b > s0}
            reasons.extend(f"load cell {k} device error: {m}" for m in sorted(errs))
            lc_rows.append(d)
        out = np.concatenate([data[self.response_rows], *lc_rows], axis=0)
        return reasons, {"force": force[None], "outputs": out}

    def _ask_review(
        self,
        j: int,
        index: int,
        reasons: tuple[str, ...],
        rec: Mapping[str, NDArray[np.float64]],
        fs: float,
    ) -> Decision:
        """The operator's decision on a hit; the DAQ is drained (read and trimmed) while waiting.

        A free-running DAQ's read blocks until its next block is there, so reading paces this
        loop at the DAQ's own rate, whatever its time scale: between reads the operator's
        answer is only polled (``wait_s`` 0) and the device FIFO never fills, however long the
        decision takes. A DAQ clocked by the host's reads (a kind simulator) answers at once:
        there the loop reads at most :data:`DRAIN_SPEED` times real time and waits on the
        operator in between (at most half a block's time per wait).
        """
        assert self.review is not None
        most_s = 0.5 * self.settings.block_samples / fs
        t0, first = time.monotonic(), self._daq_buf.end
        while True:
            read_s = (self._daq_buf.end - first) / fs
            ahead_s = read_s / DRAIN_SPEED - (time.monotonic() - t0)
            decision = self.review(j, index, reasons, rec, min(most_s, max(0.0, ahead_s)))
            if decision is not None:
                return decision
            try:
                self._read_block()
            except DeviceLostError as err:
                # the hit waiting is cut already (``rec``): it stays for the operator; the run
                # starts anew (sample counters from 0: the caller re-arms from there)
                self._restart(
                    err,
                    j,
                    f"the hit {index + 1} waiting for review is kept, so are the accepted averages",
                )
                self._rearmed = True
                t0, first = time.monotonic(), self._daq_buf.end
                continue
            self._trim(self._daq_buf.end - self.settings.pretrigger_samples)

    # -- run -------------------------------------------------------------------------------------------
    def _start_run(self) -> None:
        """Fresh buffers; arm the load cells (counter 0 at the DAQ's next pulse); start the DAQ."""
        self._daq_buf = SampleWindow(len(self.daq.channel_names))
        # forces: six loads; gauges: the cell's gauges (12 unless it says otherwise)
        self._lc_bufs = [
            SampleWindow(6 if self.loadcell_outputs == "forces" else _n_gauges(lc))
            for lc in self.loadcells
        ]
        self._lc_zero: list[NDArray[np.float64] | None] = [None] * len(self.loadcells)
        self._gaps = []
        assert self.daq.sample_rate_hz is not None
        for lc in self.loadcells:
            lc.set_rate(round(self.daq.sample_rate_hz))
            lc.start(external_clock=True)
        t_before = time.monotonic()
        self.daq.start()
        # a load cell on its own clock (Net F/T RDT) is put on the DAQ's through the host's
        window = getattr(self.daq, "clock_start_window", None) or (t_before, time.monotonic())
        for lc in self.loadcells:
            started = getattr(lc, "daq_clock_started", None)
            if started is not None:
                started(*window)

    def _restart(self, err: DeviceLostError, input_index: int, kept: str = "") -> None:
        """The DAQ dropped off the bus: stop the load cells, find the DAQ again, start anew.

        Raises
        ------
        DeviceLostError
            The DAQ cannot reconnect, or ``max_restarts`` is used up.
        DeviceNotFoundError
            It did not come back.
        """
        reconnect = getattr(self.daq, "reconnect", None)
        if reconnect is None or self.restarts >= self.max_restarts:
            raise DeviceLostError(
                f"{err}; the run was restarted {self.restarts} time(s) (max_restarts "
                f"{self.max_restarts}); check the USB cable and hub, then repeat the missing inputs"
            ) from err
        self.restarts += 1
        msg = (
            f"DAQ lost ({err}); run restarted ({self.restarts} of at most {self.max_restarts}): "
            + (
                kept
                or f"the average in progress of input {self.input_names[input_index]} is struck "
                "again, the accepted averages are kept"
            )
        )
        log.warning(msg)
        self._event({"device": "daq", "kind": "restart", "message": msg})
        for k, lc in enumerate(self.loadcells):
            try:
                counted = lc.stop()
                if counted > self._lc_bufs[k].end:  # read the rest: its gaps are reported too
                    self._ingest_lc(k, lc.read_until(counted))
            except DeviceError:  # the run is over for it anyway
                log.warning("stopping a load cell after the DAQ was lost failed", exc_info=True)
        reconnect()
        self._event(
            {"device": "daq", "kind": "reconnected", "message": "DAQ found again on the bus"}
        )
        self._start_run()
        if self.progress is not None:
            j = input_index
            self.progress(
                Progress(
                    j,
                    len(self.input_rows),
                    self._n_acc[j],
                    self.settings.averages_per_input,
                    0,
                    msg,
                )
            )

    def run(self) -> ImpactResult:
        s = self.settings
        n_in = len(self.input_rows)
        assert self.daq.sample_rate_hz is not None
        fs = self.daq.sample_rate_hz
        self._zero_samples = max(1, min(128, self.settings.hit_delay_samples))
        records: list[list[Mapping[str, NDArray[np.float64]]]] = (
            [list(p) for p in self.prior] if self.prior is not None else [[] for _ in range(n_in)]
        )
        self._n_acc = [len(r) for r in records]
        self._lost = [0] * n_in
        self._rearmed = False
        self._start_run()
        aligner, known = self._aligners(fs)
        # Streamed: an input's FRF is estimated as soon as its averages are in, and its records
        # are dropped (memory: one input's records, not the whole test's).
        st = _RunState(records)
        need = min(s.min_averages, s.averages_per_input)
        stopped = False
        try:
            for j in range(n_in):
                self._acquire_input(j, st, fs)
                self._input_done(j, st, fs, need, known, aligner)
            self._stop_devices()
            stopped = True
        finally:
            if not stopped:
                self._stop_after_error()
            if self.writer is not None:
                self.writer.flush()
        short = self._incomplete(st.n_accepted, need)
        H_all, coh_all, freqs = st.H_all, st.coh_all, st.freqs
        assert H_all is not None and coh_all is not None and freqs is not None
        for msg in aligner.finish(freqs, H_all, coh_all):  # the run's delay, every input
            self._event({"device": "loadcell", "kind": "alignment", "message": msg})
        kept = [j for j in range(n_in) if j not in set(short)]
        if short:  # drop the incomplete inputs' empty columns
            H_all, coh_all = H_all[:, :, kept], coh_all[:, :, kept]
        return self._result(freqs, H_all, coh_all, st.history, st.n_accepted, kept, short, need)

    def _aligners(self, fs: float) -> tuple[DataAligner, KnownResponses]:
        """The load cells' delay fit (:class:`DataAligner`) and held-value correction
        (:class:`KnownResponses`) of this run."""
        s = self.settings
        # the noise of FRF lines under the response window is shared by ~its equivalent noise
        # bandwidth in lines: the delay fit's σ counts the independent ones
        w_out = (
            exponential_window(
                s.record_samples, fs, s.exponential_tau_s, start_sample=s.pretrigger_samples
            )
            if s.exponential_tau_s
            else np.ones(s.record_samples)
        )
        aligner = DataAligner(
            self.loadcells,
            [b.data.shape[0] for b in self._lc_bufs],
            len(self.response_rows),
            line_bandwidth=s.record_samples * float(np.sum(w_out**2)) / float(np.sum(w_out)) ** 2,
        )
        # cells answering with values held from their own clock: their mean effect divided out
        known = KnownResponses(
            self.loadcells, [b.data.shape[0] for b in self._lc_bufs], len(self.response_rows)
        )
        return aligner, known

    def _acquire_input(self, j: int, st: _RunState, fs: float) -> None:
        """Strike input ``j`` until its averages are in, its strike budget is spent or the
        caller asks to finish (``st.finished_early``)."""
        s = self.settings
        c = _InputCount()
        while len(st.records[j]) < s.averages_per_input and not st.finished_early:
            if self.should_finish is not None and self.should_finish():
                st.finished_early = True
                break
            c.attempts += 1
            if c.attempts > s.max_attempts_factor * s.averages_per_input:
                break
            try:
                # a strike asked for now lands after the DAQ's clock now, however far
                # the host is behind it: anything before is an earlier request's
                # (module docstring, step 3)
                now = self.daq.samples_clocked_now()
                search_from = max(st.armed_from, self._daq_buf.end, now or 0)
                if self.operator is not None:
                    self.operator(j, search_from + s.hit_delay_samples)
                t = self._wait_trigger(j, search_from)
                s0 = t - s.pretrigger_samples
                self._until(s0 + s.record_samples)
            except DeviceLostError as err:
                self._restart(err, j)  # bounded by max_restarts, not the strikes
                c.attempts -= 1
                st.armed_from = 0
                continue
            except StrikeLost as gap:
                # not the operator's strike nor the article's: not counted against the
                # strike budget, counted (and reported) on its own, with its own bound
                c.attempts -= 1
                if self._strike_lost(j, gap, c, st):
                    break
                continue
            self._book_average(j, s0, c, st, fs)

    def _strike_lost(self, j: int, gap: StrikeLost, c: _InputCount, st: _RunState) -> bool:
        """Count and report a strike of input ``j`` lost to a sample gap; True when the input
        has lost as many as its strike budget (no more strikes asked for it)."""
        s = self.settings
        c.lost += 1
        self._lost[j] += 1
        st.armed_from = self._daq_buf.end
        msg = f"input {self.input_names[j]}: strike lost ({gap}) while waiting for it; {c.lost} lost on this input"
        out_of_lost = c.lost >= s.max_attempts_factor * s.averages_per_input
        msg += "; no more strikes asked for this input" if out_of_lost else "; asking for it again"
        log.warning("%s", msg)
        self._event({"device": "daq", "kind": "strike_lost", "message": msg})
        if self.on_lost is not None:
            self.on_lost(j, str(gap))
        if self.progress is not None:
            self.progress(
                Progress(
                    j,
                    len(self.input_rows),
                    len(st.records[j]),
                    s.averages_per_input,
                    c.rejected,
                    msg,
                )
            )
        return out_of_lost

    def _decision(
        self,
        j: int,
        number: int,
        reasons: list[str],
        rec: Mapping[str, NDArray[np.float64]],
        fs: float,
    ) -> Decision:
        """The checks' decision on a hit, and the operator's when the hit is reviewed (its
        reason appended to ``reasons``)."""
        decision: Decision = "reject" if reasons else "accept"
        if self.review is not None:
            asked = self._ask_review(j, number, tuple(reasons), rec, fs)
            if asked == "redo":
                decision = "redo"
                reasons.append(OPERATOR_REDO)
            elif asked == "reject" and not reasons:
                decision = "reject"
                reasons.append(OPERATOR_REJECT)
            elif asked == "override" and reasons:
                holes = unusable_reasons(reasons)
                if holes:  # the caller should have refused it: say so, keep it out
                    log.warning("override of %s refused: %s", reasons, holes)
                    reasons.append(f"override refused: {'; '.join(holes)}")
                else:
                    decision = "accept"
                    reasons.append(OPERATOR_OVERRIDE)
        return decision

    def _book_average(self, j: int, s0: int, c: _InputCount, st: _RunState, fs: float) -> None:
        """Check, decide and record the average of input ``j`` starting at DAQ sample ``s0``;
        re-arm after it."""
        s = self.settings
        reasons, rec = self._check(j, s0, s.record_samples)
        decision = self._decision(j, len(st.history), reasons, rec, fs)
        ok = decision == "accept"
        if ok:
            st.records[j].append(rec)
            self._n_acc[j] += 1
        else:
            c.rejected += 1
        if decision == "redo":  # the input starts again: its averages and budget
            st.records[j] = []
            c.rejected, c.attempts, c.lost = 0, 0, 0
            st.history = [
                AverageRecord(h.input_index, h.first_sample, h.n_samples, False, (OPERATOR_REDO,))
                if h.input_index == j and h.accepted
                else h
                for h in st.history
            ]
        ar = AverageRecord(j, s0, s.record_samples, ok, tuple(reasons))
        st.history.append(ar)
        if self.writer is not None:
            self.writer.log_average(asdict(ar))
        if self.on_average is not None:
            self.on_average(j, len(st.history) - 1, ok, ar.reasons, rec)
        st.armed_from = s0 + s.record_samples
        if self._rearmed:  # the run restarted while the hit waited: from its start
            st.armed_from, self._rearmed = 0, False
        self._trim(st.armed_from - s.pretrigger_samples)
        for lc in self.loadcells:  # between records: a cell on its own clock
            realign = getattr(lc, "realign", None)  # may move its alignment now
            if realign is not None:
                realign()
        msg = (
            f"input {self.input_names[j]}: average {len(st.records[j])}/"
            f"{s.averages_per_input}" + (f" rejected: {'; '.join(reasons)}" if reasons else "")
        )
        log.info(msg)
        if self.progress is not None:
            self.progress(
                Progress(
                    j,
                    len(self.input_rows),
                    len(st.records[j]),
                    s.averages_per_input,
                    c.rejected,
                    msg,
                )
            )

    def _input_done(
        self,
        j: int,
        st: _RunState,
        fs: float,
        need: int,
        known: KnownResponses,
        aligner: DataAligner,
    ) -> None:
        """Input ``j``'s FRFs into the run's arrays when it has ``need`` averages (fewer:
        incomplete, no FRF, the coherence would be 1); its records dropped."""
        st.n_accepted.append(len(st.records[j]))
        if len(st.records[j]) >= need:
            f_j, H_j, coh_j = self._frf(st.records[j], fs)
            known.apply(f_j, H_j)
            # a load cell on its own clock: its residual delay fitted from the data
            where = f"input {self.input_names[j]}"
            ranges = [
                (h.first_sample, h.n_samples)
                for h in st.history
                if h.input_index == j and h.accepted
            ]
            for msg in aligner.align(j, f_j, H_j, coh_j, where, ranges):
                self._event({"device": "loadcell", "kind": "alignment", "message": msg})
            if st.H_all is None:  # filled input by input: no stacking copy at the end
                st.H_all = np.zeros((*H_j.shape, len(self.input_rows)), dtype=H_j.dtype)
                st.coh_all = np.zeros((*coh_j.shape, len(self.input_rows)))
                st.freqs = f_j
            assert st.coh_all is not None
            st.H_all[:, :, j] = H_j
            st.coh_all[:, :, j] = coh_j
            if self.on_input is not None:
                self.on_input(j, coh_j)
        st.records[j] = []

    def _stop_devices(self) -> None:
        """Stop the DAQ and the load cells at the run's end; read the cells' rest (so that its
        gaps are reported) and check their pulse counts against the DAQ's clock."""
        self.daq.stop()
        tail = self.daq.read_buffered()
        n_received = self._daq_buf.end if tail is None else tail.first_sample + tail.n_samples
        # the load cells counted every pulse the DAQ clocked, received by the host or not
        n_clocked = self.daq.samples_clocked
        if n_clocked is None:
            n_clocked = n_received
        for k, lc in enumerate(self.loadcells):
            counted = lc.stop()
            if counted > self._lc_bufs[k].end:
                # the rest of the run (after the last average): read so that its gaps are
                # reported too, not kept
                self._ingest_lc(k, lc.read_until(counted))
            ev = lc.verify_count(n_clocked)
            if ev is not None:
                self._event({"device": f"loadcell{k}", **asdict(ev)})

    def _stop_after_error(self) -> None:
        """Stop the DAQ and the load cells after an error, keeping the original error."""
        if self.daq.running:
            self.daq.stop()
        for lc in self.loadcells:
            try:
                lc.stop()
            except Exception:  # keep the original error
                log.exception("stopping load cell after an error failed")

    def _incomplete(self, n_accepted: Sequence[int], need: int) -> list[int]:
        """The inputs with fewer than ``need`` accepted averages (logged).

        Raises
        ------
        DataError
            Every input is incomplete: no FRF at all.
        """
        s = self.settings
        n_in = len(self.input_rows)
        short = [j for j in range(n_in) if n_accepted[j] < need]
        if short:
            log.warning(
                "inputs %s incomplete: accepted %s of %d averages (minimum %d)",
                [self.input_names[j] for j in short],
                [n_accepted[j] for j in short],
                s.averages_per_input,
                need,
            )
        if len(short) == n_in:
            lost_note = (
                f"; strikes lost to DAQ sample gaps: {[self._lost[j] for j in short]}"
                if any(self._lost[j] for j in short)
                else ""
            )
            raise DataError(
                f"inputs {[self.input_names[j] for j in short]}: fewer than {need} acceptable "
                f"averages each ({[n_accepted[j] for j in short]}) after "
                f"{s.max_attempts_factor * s.averages_per_input} strikes{lost_note} (see the "
                "rejected reasons in the acquisition file); fix the cause and repeat those inputs"
            )
        return short

    def _frf(
        self, recs: Sequence[Mapping[str, NDArray[np.float64]]], fs: float
    ) -> tuple[NDArray[np.float64], NDArray[np.complex128], NDArray[np.float64]]:
        """One input's FRFs from its accepted records (:func:`input_frf`)."""
        return input_frf(recs, fs, self.settings)

    def _result(
        self,
        freqs: NDArray[np.float64],
        H: NDArray[np.complex128],
        coherence: NDArray[np.float64],
        history: list[AverageRecord],
        n_accepted: list[int],
        kept: Sequence[int],
        incomplete: Sequence[int],
        need: int,
    ) -> ImpactResult:
        lc_names: list[str] = []
        for k in range(len(self.loadcells)):
            comps = (
                ("Fx", "Fy", "Fz", "Mx", "My", "Mz")
                if self.loadcell_outputs == "forces"
                else tuple(f"g{i + 1:02d}" for i in range(_n_gauges(self.loadcells[k])))
            )
            lc_names += [f"loadcell{k} {c}" for c in comps]
        return ImpactResult(
            frequencies_hz=freqs,
            H=H,
            coherence=coherence,
            output_names=self.response_names + tuple(lc_names),
            input_names=tuple(self.input_names[j] for j in kept),
            averages=tuple(history),
            n_accepted=tuple(n_accepted),
            input_indices=tuple(kept),
            incomplete_inputs=tuple(self.input_names[j] for j in incomplete),
            min_averages=need,
            lost_strikes=tuple(self._lost),
        )
