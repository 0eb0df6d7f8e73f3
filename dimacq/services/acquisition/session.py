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
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import asdict, dataclass
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from dimacq.devices.daq import Daq
from dimacq.devices.loadcell import LoadCell
from dimacq.errors import DataError, DeviceError, DeviceLostError, SetupError
from dimacq.io.acquisition_hdf5 import AcquisitionWriter
from dimacq.model.impact import ImpactSettings
from dimacq.pipeline.frf_estimation import exponential_window
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
)
from dimacq.services.acquisition.known_response import KnownResponses
from dimacq.services.acquisition.sample_window import SampleWindow
from dimacq.services.acquisition.session_steps import ImpactSteps, RunState

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


@dataclass(frozen=True)
class _InputFrf:
    """One input's FRFs as the worker estimated them, with the alignment's messages."""

    input_index: int
    freqs: NDArray[np.float64]
    H: NDArray[np.complex128]
    coherence: NDArray[np.float64]
    messages: tuple[str, ...]


def _n_gauges(lc: LoadCell) -> int:
    """Gauges of a load cell: its own count when it says (a cell on DAQ inputs), else 12."""
    n = getattr(lc, "n_gauges", None)
    return int(n) if isinstance(n, int) else 12


class ImpactSession(ImpactSteps):
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
        # An input's FRFs are estimated on a worker thread while the next input is struck: the
        # DAQ free-runs, and its FIFO must be read while they are computed.
        st = RunState(records)
        need = min(s.min_averages, s.averages_per_input)
        stopped = False
        pending: Future[_InputFrf] | None = None
        with ThreadPoolExecutor(max_workers=1, thread_name_prefix="dimacq-input-frf") as pool:
            try:
                for j in range(n_in):
                    self._acquire_input(j, st, fs)
                    self._input_done(st, pending)
                    pending = self._submit_input(pool, j, st, fs, need, known, aligner)
                self._stop_devices()
                stopped = True
                self._input_done(st, pending)
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

    def _submit_input(
        self,
        pool: ThreadPoolExecutor,
        j: int,
        st: RunState,
        fs: float,
        need: int,
        known: KnownResponses,
        aligner: DataAligner,
    ) -> Future[_InputFrf] | None:
        """Input ``j``'s FRFs to the worker when it has ``need`` averages (fewer: incomplete, no
        FRF, the coherence would be 1); its records dropped from the run's state."""
        recs = st.records[j]
        st.n_accepted.append(len(recs))
        st.records[j] = []
        if len(recs) < need:
            return None
        ranges = [
            (h.first_sample, h.n_samples) for h in st.history if h.input_index == j and h.accepted
        ]
        return pool.submit(self._input_frf, j, recs, ranges, fs, known, aligner)

    def _input_frf(
        self,
        j: int,
        recs: Sequence[Mapping[str, NDArray[np.float64]]],
        ranges: list[tuple[int, int]],
        fs: float,
        known: KnownResponses,
        aligner: DataAligner,
    ) -> _InputFrf:
        """Input ``j``'s FRFs (worker thread): estimated, the held values' mean effect divided
        out, a load cell on its own clock aligned from the data (its messages returned)."""
        f_j, H_j, coh_j = self._frf(recs, fs)
        known.apply(f_j, H_j)
        msgs = aligner.align(j, f_j, H_j, coh_j, f"input {self.input_names[j]}", ranges)
        return _InputFrf(j, f_j, H_j, coh_j, tuple(msgs))

    def _input_done(self, st: RunState, pending: Future[_InputFrf] | None) -> None:
        """An input's FRFs from the worker into the run's arrays (this thread: the events and
        ``on_input`` come from the acquisition's own thread, in input order)."""
        if pending is None:
            return
        r = pending.result()
        for msg in r.messages:
            self._event({"device": "loadcell", "kind": "alignment", "message": msg})
        if st.H_all is None:  # filled input by input: no stacking copy at the end
            st.H_all = np.zeros((*r.H.shape, len(self.input_rows)), dtype=r.H.dtype)
            st.coh_all = np.zeros((*r.coherence.shape, len(self.input_rows)))
            st.freqs = r.freqs
        assert st.coh_all is not None
        st.H_all[:, :, r.input_index] = r.H
        st.coh_all[:, :, r.input_index] = r.coherence
        if self.on_input is not None:
            self.on_input(r.input_index, r.coherence)

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
