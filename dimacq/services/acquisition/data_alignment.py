"""Load cells on their own clock (an ATI Net F/T's RDT) finished from the data: the residual
delay of the cells' FRFs fitted, removed, and checked against the phase budget.

The driver puts the stream on the DAQ's sample grid through the host's clock (a coarse time
base, ~0.1 ms of wall time) and says what is left to do (``delay_budget()``, None when its
samples are final). What is left is (nearly) one delay per run: the DAQ's start window and the
network's latency floor are one per run and the clock fit spans the run. So each input's FRFs
are kept as they come (:meth:`DataAligner.align` fits its own delay, for the record and as the
fallback), and at the end of the run one delay is fitted on every input at once, each with its
own real coefficients of the rigid-body law
(:func:`~dimacq.pipeline.stream_alignment.fit_pooled_delay`), its standard error from the
jackknife over inputs — which counts each input's bias (the bungee's cell fits scatter ~3 times
beyond their own σ) as the random error it is across inputs — together with its drift between
the run's halves (:meth:`DataAligner.finish`). Every input takes
that delay when it meets the budget; otherwise each takes its own fit where that meets it, and
the run is refused (:class:`~dimacq.errors.SetupError`, one line) when one does not: the data
could not support the alignment.

The budget is what the delay's uncertainty may cost the equations DIM solves: ``360 f δτ``
degrees of the cell's FRF phase at ``band_hz``, times the cell's share of the force balance
(:func:`force_share`: 1 for a cell that carries the article, ~1e-3 for the load cell of a
soft suspension, whose loads above the suspension's modes are ~0.1 % of the hammer's force and
whose phase DIM barely uses). On such a cell the run's delay is ill-determined (each input's
cell FRFs of a few averages hold the suspension's swing of earlier strikes, as large as the
strike's own load) and does not need to be well determined.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from dimacq.devices.loadcell import LoadCell
from dimacq.errors import SetupError
from dimacq.pipeline.stream_alignment import (
    DelayBudget,
    DelayFit,
    PooledDelayFit,
    fit_delay,
    fit_pooled_delay,
    phase_error_deg,
)

__all__ = ["DataAligner", "align_rows", "cell_rows", "force_share"]

log = logging.getLogger(__name__)


def align_rows(
    frequencies_hz: NDArray[np.float64],
    H: NDArray[np.complex128],
    coherence: NDArray[np.float64],
    budget: DelayBudget,
    where: str,
    references: NDArray[np.complex128] | None = None,
    line_bandwidth: float = 1.0,
) -> tuple[NDArray[np.complex128], DelayFit, float]:
    """One cell's FRFs ``H`` (n_lines, n_rows) with their fitted delay removed, the fit and the
    phase its uncertainty costs at ``budget.band_hz`` (degrees).

    ``references`` (n_lines, n_responses): the same input's FRFs on the DAQ's clock (the
    accelerometers), the regressors of equation (1) of
    :mod:`~dimacq.pipeline.stream_alignment` with a column of ones (the hammer's own term);
    None: the mass-line basis (2). Each row is scaled to unit RMS over the fit's lines (forces
    and moments count alike); each line is weighted by the median over the rows of
    ``γ² / (1 − γ²)`` (its inverse relative variance; ``1 − γ²`` floored at 1e-4).
    ``line_bandwidth``: the records' window's equivalent noise bandwidth in lines
    (:func:`~dimacq.pipeline.stream_alignment.fit_delay`).

    Raises
    ------
    SetupError
        Too few lines in the fit's band, or the phase above ``budget.max_phase_deg``.
    """
    f = np.asarray(frequencies_hz, dtype=float)
    fm, Hm, w, X = cell_rows(f, H, coherence, budget, references)
    try:
        fit = fit_delay(
            fm, Hm, w, search_s=budget.search_s, regressors=X, line_bandwidth=line_bandwidth
        )
    except ValueError as err:
        raise SetupError(
            f"{budget.label}: {where}: no delay fit from the data ({err}); set netft_fit_lo_hz "
            "well below netft_band_hz in the rig file"
        ) from err
    phase = phase_error_deg(fit.uncertainty_s, budget.band_hz)
    if not phase <= budget.max_phase_deg:
        raise SetupError(_refusal(budget, where, fit.uncertainty_s, phase, fit))
    out = H * np.exp(2j * np.pi * f * fit.delay_s)[:, None]
    return out, fit, phase


def cell_rows(
    frequencies_hz: NDArray[np.float64],
    H: NDArray[np.complex128],
    coherence: NDArray[np.float64],
    budget: DelayBudget,
    references: NDArray[np.complex128] | None,
) -> tuple[
    NDArray[np.float64],
    NDArray[np.complex128],
    NDArray[np.float64],
    NDArray[np.complex128] | None,
]:
    """What the delay fit takes of one input's cell (:func:`align_rows`): the lines of the
    budget's band, the rows scaled to unit RMS, the lines' weights and the regressors (the
    references with a column of ones; None: the mass-line basis)."""
    f = np.asarray(frequencies_hz, dtype=float)
    m = (f >= budget.lo_hz) & (f <= budget.band_hz)
    Hm = H[m]
    g = np.clip(np.nan_to_num(coherence[m], nan=0.0), 0.0, 1.0)
    w = np.zeros(Hm.shape[0])
    if Hm.size:
        rms = np.sqrt(np.mean(np.abs(np.nan_to_num(Hm)) ** 2, axis=0))
        Hm = Hm / np.where(rms > 0, rms, 1.0)
        w = np.median(g / np.maximum(1.0 - g, 1e-4), axis=1)
    X = None
    if references is not None:
        X = np.concatenate([references[m], np.ones((int(m.sum()), 1))], axis=1)
    return f[m], Hm, w, X


def _refusal(
    budget: DelayBudget,
    where: str,
    u_s: float,
    phase: float,
    fit: DelayFit | None,
    pooled: tuple[PooledDelayFit, float, float] | None = None,
) -> str:
    how = (
        f" ({1e6 * fit.sigma_s:.1f} us statistical, {1e6 * fit.spread_s:.1f} us between the "
        "band's halves)"
        if fit is not None
        else " (the run's delay: its error and the alignment's wander between inputs)"
    )
    if pooled is not None:
        p, _wander, share = pooled
        how = (
            f" (the run's delay {1e6 * p.delay_s:+.1f} us fitted on {p.n_inputs} inputs at once: "
            f"jackknife over inputs {1e6 * p.jackknife_s:.1f} us, noise {1e6 * p.sigma_s:.1f} us, "
            f"the inputs' scatter about it {1e6 * p.scatter_s:.1f} us, its drift between the "
            f"run's halves {1e6 * p.drift_s:.1f} us; the cell's share of the force balance "
            f"{share:.3g}: {phase * share:.3g} deg of it)"
        )
    return (
        f"{budget.label}: {where}: the data align its loads to the DAQ's clock within only "
        f"{1e6 * u_s:.1f} us{how}, {phase:.1f} deg of FRF phase at {budget.band_hz:g} Hz "
        f"(limit netft_max_phase_deg = {budget.max_phase_deg:g}): the cell carries too little "
        "of the force for its delay to be told; lower netft_band_hz, or read the cell as "
        "loadcell = 'netft-can' or 'daq-channels'"
    )


#: Moments count in the force balance's share (:func:`force_share`) as forces at this lever
#: arm, m: short, so that a cell's moments weigh more than they do about a larger article.
SHARE_LEVER_M = 0.1


def force_share(
    frequencies_hz: NDArray[np.float64],
    H_cell: NDArray[np.complex128],
    budget: DelayBudget,
    inputs: Sequence[int],
) -> float:
    """The largest share of the force balance one cell carries on the budget's lines, over
    ``inputs``: what a phase error of its loads costs the equations DIM solves.

    Per input and line the DIM balance is ``f_in + F_cell = M a`` (with the moments likewise);
    a delay error ``δτ`` of the cell turns ``F_cell`` by ``ωδτ``, an error ``ωδτ |F_cell|``
    against a balance of size ``|f_in| + |F_cell|`` (the hammer's ``f_in`` is the unit of the
    FRFs). So the phase budget, which asks for ``ωδτ`` itself on a cell that carries the
    article, costs the balance ``ωδτ · s`` with

        s = median over the lines of ‖F_cell‖ / (1 + ‖F_cell‖),   ‖F‖² = |F|² + |T / L|²

    (``L`` = :data:`SHARE_LEVER_M`), the largest over the inputs; ``s`` → 1 for a cell that
    carries the article (the budget unchanged), ~1e-3 on a soft suspension whose cell carries
    ~0.1 % of the hammer's force above its modes (a delay error there changes nothing DIM
    uses). A cell read as anything but its six loads (forces, then moments: ``H_cell`` of 6
    rows) counts as 1.

    Parameters
    ----------
    H_cell : ndarray, shape (n_lines, n_rows, n_inputs)
        The cell's FRFs per unit hammer force.
    """
    if H_cell.shape[1] != 6:
        return 1.0
    f = np.asarray(frequencies_hz, dtype=float)
    m = (f >= budget.lo_hz) & (f <= budget.band_hz)
    Hm = np.nan_to_num(H_cell[m][:, :, list(inputs)])
    if Hm.shape[0] == 0:
        return 1.0
    mag = np.sqrt(
        np.sum(np.abs(Hm[:, :3]) ** 2, axis=1)
        + np.sum(np.abs(Hm[:, 3:] / SHARE_LEVER_M) ** 2, axis=1)
    )  # (lines, inputs)
    s = np.median(mag / (1.0 + mag), axis=0)
    return float(np.max(s))


def _apart(
    fit: DelayFit | None, tau_s: float, u_s: float, share: float, budget: DelayBudget
) -> bool:
    """An input whose own fit says the run's delay ``tau_s`` (uncertainty ``u_s``) is not its
    own: apart by more than three standard errors of the difference, ``3 √(u_own² + u²)``, and
    by more than the budget allows (its phase at ``band_hz`` times the cell's share). Such an
    input's alignment moved between inputs (a coarse alignment that jumped), and the one delay
    would leave it off; its own fit, which met the budget, is the better one. On a cell whose
    share is small, biased own fits stay with the run's delay (the budget part)."""
    if fit is None:
        return False
    diff = abs(fit.delay_s - tau_s)
    return bool(
        diff > 3.0 * float(np.hypot(fit.uncertainty_s, u_s))
        and phase_error_deg(diff, budget.band_hz) * share > budget.max_phase_deg
    )


@dataclass
class _Input:
    """One input of one cell, waiting for the end of the run."""

    j: int
    where: str
    fit: DelayFit | None  # its own fit, where it met the budget
    records: list[tuple[int, int]]


class DataAligner:
    """The cells of one acquisition that ask for it (``delay_budget()``), aligned at the end of
    the run by the delay the clocks had over it.

    The coarse alignment's error is (nearly) one delay per run — the DAQ's start window and
    the network's latency floor are one per run, the clock fit spans the whole run — plus
    what it drifts or wanders between inputs. Each input's own fit of that delay is biased on
    a cell that carries little of the force (the bungee's: its fits scatter ~3 times beyond
    their own σ), so one fit over every input, each with its own coefficients
    (:func:`~dimacq.pipeline.stream_alignment.fit_pooled_delay`), with the standard error of
    the jackknife over inputs (which counts each input's bias as the random error it is
    across inputs), gives the run's delay ``τ̂``. Where the cell says how far its alignment
    was put from its whole-run clock fit at each input's records (``alignment_offsets_s``),
    those offsets are taken as known differences of the inputs' delays when the data fit
    better with them than without. An input taking ``τ̂`` is off by ``τ̂``'s error and by
    how far its own delay lies from the run's: the inputs' scatter about ``τ̂``
    (``scatter_s``, from the jackknife's pseudo-values: a wander between inputs as well as a
    drift; an input that jumped is told apart on its own), at least the drift
    the run's halves fitted apart tell (``drift_s``); every input takes ``τ̂`` when
    ``u = √(se² + max(scatter, drift)²)`` meets the budget (``se`` never below the noise's
    ``σ``; its phase at ``band_hz`` weighed by the cell's share of the force balance,
    :func:`force_share`). Otherwise — the inputs' delays truly
    differ, or the data say too little — each input takes its own fit where that meets the
    budget, and the run is refused (:class:`~dimacq.errors.SetupError`, one line) when any
    input's does not: the data could not support the alignment. One input: its own fit.

    Parameters
    ----------
    loadcells : sequence of LoadCell
    widths : sequence of int
        Rows of each cell in the FRFs.
    first_row : int
        The cells' first row (after the responses, the regressors of equation (1)).
    line_bandwidth : float
        The records' output window's equivalent noise bandwidth, lines (1: none).
    """

    def __init__(
        self,
        loadcells: Sequence[LoadCell],
        widths: Sequence[int],
        first_row: int,
        line_bandwidth: float = 1.0,
    ):
        self.cells: list[tuple[int, slice, LoadCell]] = []
        row = first_row
        for k, (lc, n) in enumerate(zip(loadcells, widths, strict=True)):
            if getattr(lc, "delay_budget", None) is not None:
                self.cells.append((k, slice(row, row + n), lc))
            row += n
        self.first_row = first_row
        self.line_bandwidth = line_bandwidth
        self.inputs: dict[int, list[_Input]] = {k: [] for k, _, _ in self.cells}

    def _refs(self, H: NDArray[np.complex128]) -> NDArray[np.complex128] | None:
        return H[:, : self.first_row] if self.first_row > 0 else None

    def align(
        self,
        j: int,
        frequencies_hz: NDArray[np.float64],
        H: NDArray[np.complex128],
        coherence: NDArray[np.float64],
        where: str,
        records: Sequence[tuple[int, int]] = (),
    ) -> list[str]:
        """Input ``j``'s FRFs ``H`` (n_lines, n_outputs): its own fit, for the record and as the
        fallback; ``H`` is aligned by :meth:`finish`. ``records``: its records' ``(first
        sample, samples)`` on the DAQ's clock. One message per cell."""
        messages = []
        for k, rows, lc in self.cells:
            budget = lc.delay_budget()  # type: ignore[attr-defined]
            if budget is None:
                continue
            fit: DelayFit | None = None
            try:
                _, fit, phase = align_rows(
                    frequencies_hz,
                    H[:, rows],
                    coherence[:, rows],
                    budget,
                    where,
                    self._refs(H),
                    self.line_bandwidth,
                )
            except SetupError as err:
                if "too little of the force" not in str(err):
                    raise
                msg = f"{err}; it takes the run's delay at the end"
            else:
                msg = (
                    f"{budget.label}: {where}: own delay fit {1e6 * fit.delay_s:+.1f} us, within "
                    f"{1e6 * fit.uncertainty_s:.1f} us ({phase:.2f} deg at {budget.band_hz:g} "
                    "Hz); the run's delay is fitted at its end"
                )
            self.inputs[k].append(_Input(j, where, fit, list(records)))
            log.info("%s", msg)
            messages.append(msg)
        return messages

    def finish(
        self,
        frequencies_hz: NDArray[np.float64],
        H_all: NDArray[np.complex128],
        coherence_all: NDArray[np.float64],
    ) -> list[str]:
        """Every input (columns ``j`` of ``H_all``, shape (n_lines, n_outputs, n_inputs), and of
        ``coherence_all``) aligned in place; one message per cell.

        Raises
        ------
        SetupError
            The run's delay does not meet the budget and an input's own fit does not either.
        """
        f = np.asarray(frequencies_hz, dtype=float)
        messages = []
        for k, rows, lc in self.cells:
            entries = self.inputs[k]
            if not entries:
                continue
            budget = lc.delay_budget()  # type: ignore[attr-defined]
            names = ", ".join(e.where for e in entries)
            pooled, wander, u = None, 0.0, float("inf")
            offsets = np.zeros(len(entries))
            if len(entries) >= 2:
                offsets = self._offsets(lc, entries)
                pooled = self._pooled(
                    f, H_all, coherence_all, rows, entries, budget, names, offsets
                )
                if not pooled.offsets_used:
                    offsets = np.zeros(len(entries))
                wander = max(pooled.drift_s, pooled.scatter_s)
                u = float(np.hypot(pooled.uncertainty_s, wander))
            phase = phase_error_deg(u, budget.band_hz)
            share = force_share(f, H_all[:, rows], budget, [e.j for e in entries])
            if pooled is not None and phase * share <= budget.max_phase_deg:
                apart = []
                for e, o in zip(entries, offsets, strict=True):
                    tau = float(pooled.delay_s + o)
                    if _apart(e.fit, tau, u, share, budget):
                        assert e.fit is not None
                        tau = e.fit.delay_s
                        apart.append(f"{e.where} ({1e6 * tau:+.1f} us)")
                    H_all[:, rows, e.j] *= np.exp(2j * np.pi * f * tau)[:, None]
                msg = (
                    f"{budget.label}: the run's delay {1e6 * pooled.delay_s:+.1f} us, fitted on "
                    f"{pooled.n_inputs} inputs at once, within {1e6 * u:.1f} us "
                    f"({phase:.2f} deg at {budget.band_hz:g} Hz; jackknife over inputs "
                    f"{1e6 * pooled.jackknife_s:.1f} us, noise {1e6 * pooled.sigma_s:.1f} us, "
                    f"the inputs' scatter about it {1e6 * pooled.scatter_s:.1f} us, its drift "
                    f"between the run's halves {1e6 * pooled.drift_s:.1f} us; the cell's "
                    f"share of the force balance {share:.3g}: {phase * share:.3g} deg of it), "
                    "removed from every input"
                    + (
                        f" with the clock fit's offset at its records ({1e6 * offsets.min():+.1f}"
                        f" .. {1e6 * offsets.max():+.1f} us: the data fit better with it)"
                        if np.any(offsets != 0.0)
                        else " (the clock fit's offsets at their records, if any, fit the data "
                        "worse)"
                    )
                    + f"; their own fits {1e6 * pooled.own_delays_s.min():+.1f} .. "
                    f"{1e6 * pooled.own_delays_s.max():+.1f} us"
                    + (
                        f"; but {', '.join(apart)} took their own fits: the run's delay does not "
                        "describe them (beyond both fits' uncertainties and the budget)"
                        if apart
                        else ""
                    )
                )
            else:
                weak = [e.where for e in entries if e.fit is None]
                if weak and pooled is None:  # one input, too weak for its own fit
                    raise SetupError(
                        f"{budget.label}: {', '.join(weak)}: the data align its loads to the "
                        "DAQ's clock within the budget on no input (no input's own fit met the "
                        f"budget, netft_max_phase_deg = {budget.max_phase_deg:g} at "
                        f"{budget.band_hz:g} Hz): the cell carries too little of the force for "
                        "its delay to be told; lower netft_band_hz, or read the cell as loadcell "
                        "= 'netft-can' or 'daq-channels'"
                    )
                if weak and pooled is not None:
                    raise SetupError(
                        _refusal(budget, ", ".join(weak), u, phase, None, (pooled, wander, share))
                    )
                for e in entries:
                    assert e.fit is not None
                    H_all[:, rows, e.j] *= np.exp(2j * np.pi * f * e.fit.delay_s)[:, None]
                msg = f"{budget.label}: {names}: each input's own delay fit removed" + (
                    f" (the run's delay {1e6 * pooled.delay_s:+.1f} us within {1e6 * u:.1f} us "
                    "does not meet the budget: the inputs' delays differ)"
                    if pooled is not None
                    else ""
                )
            log.info("%s", msg)
            messages.append(msg)
        return messages

    @staticmethod
    def _offsets(lc: LoadCell, entries: list[_Input]) -> NDArray[np.float64]:
        """The cell's offsets of the inputs' alignment from its whole-run clock fit, about their
        mean (0 where it cannot say)."""
        ask = getattr(lc, "alignment_offsets_s", None)
        got = ask([e.records for e in entries]) if ask is not None else None
        if got is None:
            return np.zeros(len(entries))
        offsets = np.asarray(got, dtype=float)
        known = np.isfinite(offsets)
        return np.where(known, offsets - (offsets[known].mean() if known.any() else 0.0), 0.0)

    def _pooled(
        self,
        f: NDArray[np.float64],
        H_all: NDArray[np.complex128],
        coherence_all: NDArray[np.float64],
        rows: slice,
        entries: list[_Input],
        budget: DelayBudget,
        names: str,
        offsets: NDArray[np.float64],
    ) -> PooledDelayFit:
        Hs, ws, Xs = [], [], []
        for e in entries:
            fm, Hm, w, X = cell_rows(
                f,
                H_all[:, rows, e.j],
                coherence_all[:, rows, e.j],
                budget,
                self._refs(H_all[..., e.j]),
            )
            Hs.append(Hm)
            ws.append(w)
            Xs.append(X)
        try:
            return fit_pooled_delay(
                fm,
                Hs,
                ws,
                search_s=budget.search_s,
                regressors=Xs,
                line_bandwidth=self.line_bandwidth,
                offsets_s=offsets,
            )
        except ValueError as err:
            raise SetupError(
                f"{budget.label}: {names}: no delay fit from the data ({err}); set "
                "netft_fit_lo_hz well below netft_band_hz in the rig file"
            ) from err
