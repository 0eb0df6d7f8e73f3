"""One input's strikes in an impact session: ask for each strike, wait for its trigger, check
the record, take the operator's decision (the DAQ drained while the operator looks) and book the
average; a strike lost to a sample gap is counted and asked again (:class:`ImpactSteps`, a part of
:class:`~dimacq.services.acquisition.session.ImpactSession`, whose module docstring states the
rules). :class:`RunState` is what a run has gathered so far."""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Mapping
from dataclasses import asdict, dataclass, field
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from dimacq.errors import DeviceLostError
from dimacq.pipeline.frf_estimation import double_hit_mask
from dimacq.services.acquisition.impact_result import (
    OPERATOR_OVERRIDE,
    OPERATOR_REDO,
    OPERATOR_REJECT,
    AverageCallback,
    AverageRecord,
    Decision,
    Progress,
    ReviewCallback,
    unusable_reasons,
)
from dimacq.services.acquisition.impact_stream import ImpactStream, StrikeLost

log = logging.getLogger("dimacq.services.acquisition.session")

#: While a hit waits for review, a DAQ that answers every read at once (clocked by the host's
#: reads, or with a backlog in its FIFO) is read at most this many times real time.
DRAIN_SPEED = 32.0


@dataclass
class RunState:
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


class ImpactSteps(ImpactStream):
    """Methods of :class:`~dimacq.services.acquisition.session.ImpactSession` (its state: see there)."""

    if TYPE_CHECKING:  # the state of the ImpactSession it is a part of
        response_rows: list[int]
        operator: Callable[[int, int], None] | None
        progress: Callable[[Progress], None] | None
        on_average: AverageCallback | None
        review: ReviewCallback | None
        should_finish: Callable[[], bool] | None
        on_lost: Callable[[int, str], None] | None
        _n_acc: list[int]
        _lost: list[int]
        _rearmed: bool

        def _restart(self, err: DeviceLostError, input_index: int, kept: str = "") -> None: ...

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

    def _acquire_input(self, j: int, st: RunState, fs: float) -> None:
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

    def _progress(self, j: int, st: RunState, c: _InputCount, msg: str) -> None:
        """Input ``j``'s counts and ``msg`` to the ``progress`` callback, when there is one."""
        if self.progress is not None:
            s = self.settings
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

    def _strike_lost(self, j: int, gap: StrikeLost, c: _InputCount, st: RunState) -> bool:
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
        self._progress(j, st, c, msg)
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

    def _book_average(self, j: int, s0: int, c: _InputCount, st: RunState, fs: float) -> None:
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
        self._progress(j, st, c, msg)
