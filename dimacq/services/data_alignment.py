"""Load cells on their own clock (an ATI Net F/T's RDT) finished from the data: the residual
delay of each input's cell FRFs fitted, removed, and checked against the phase budget.

The driver puts the stream on the DAQ's sample grid through the host's clock (a coarse time
base, ~0.1 ms of wall time) and says what is left to do (``delay_budget()``, None when its
samples are final). Here, once an input's FRFs are estimated, the cell's rows (loads or gauges
per unit hammer force) are fitted for the delay ``τ`` they share
(:func:`~dimacq.pipeline.stream_alignment.fit_delay`: the cell's loads are real combinations of
the accelerometers' FRFs and the hammer's own term — the rigid-body law DIM solves — on the lines
from the budget's ``lo_hz`` to its ``band_hz``) and multiplied by ``e^{iωτ}`` on every line
when the fit's uncertainty costs no more FRF phase at ``band_hz`` than allowed. An input whose
cell carries too little of its force for that takes the run's delay at the end, with the run's
wander between inputs as its uncertainty (:class:`DataAligner`); the run is refused
(:class:`~dimacq.errors.SetupError`, one line) when that does not meet the budget either — the
data could not support the alignment.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from dimacq.devices.loadcell import LoadCell
from dimacq.errors import SetupError
from dimacq.pipeline.stream_alignment import DelayBudget, DelayFit, fit_delay, phase_error_deg

__all__ = ["DataAligner", "align_rows", "run_delay"]

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
    try:
        fit = fit_delay(
            f[m], Hm, w, search_s=budget.search_s, regressors=X, line_bandwidth=line_bandwidth
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


def _refusal(
    budget: DelayBudget, where: str, u_s: float, phase: float, fit: DelayFit | None
) -> str:
    how = (
        f" ({1e6 * fit.sigma_s:.1f} us statistical, {1e6 * fit.spread_s:.1f} us between the "
        "band's halves)"
        if fit is not None
        else " (the run's delay and its wander between inputs)"
    )
    return (
        f"{budget.label}: {where}: the data align its loads to the DAQ's clock within only "
        f"{1e6 * u_s:.1f} us{how}, {phase:.1f} deg of FRF phase at {budget.band_hz:g} Hz "
        f"(limit netft_max_phase_deg = {budget.max_phase_deg:g}): the cell carries too little "
        "of the force for its delay to be told; lower netft_band_hz, or read the cell as "
        "loadcell = 'netft-can' or 'daq-channels'"
    )


def run_delay(
    delays_s: NDArray[np.float64], uncertainties_s: NDArray[np.float64]
) -> tuple[float, float, float]:
    """The run's delay from the inputs' own fits: its mean, that mean's standard error and the
    wander of the delay between inputs, s.

    Each fit ``τ_i ± σ_i`` measures the clocks' delay during its input, ``τ_i = τ̄ + w_i + e_i``:
    ``w_i`` how far the coarse alignment wandered (spread ``ω``), ``e_i`` the fit's own error
    (``σ_i``). The scatter of the ``τ_i`` holds both, so ``ω`` is what is left of it beyond the
    ``σ_i`` — the random-effects estimate of DerSimonian & Laird (1986)::

        w_i = 1/σ_i²,   τ_F = Σ w_i τ_i / Σ w_i,   Q = Σ w_i (τ_i − τ_F)²,
        ω² = max(0, (Q − (k − 1)) / (Σ w_i − Σ w_i² / Σ w_i))

    (``E[Q] = k − 1`` when the inputs differ by their fits' errors alone); then
    ``w*_i = 1 / (σ_i² + ω²)``, ``τ̄ = Σ w*_i τ_i / Σ w*_i``, standard error ``(Σ w*_i)^-½``.
    An input that takes ``τ̄`` is off by its own wander and ``τ̄``'s error: ``√(se² + ω²)``.
    (Taking the weighted scatter of the ``τ_i`` itself as the wander, as before, counted the
    fits' own noise twice.) One fit: ``ω = 0`` (nothing to tell it from).

    Parameters
    ----------
    delays_s, uncertainties_s : ndarray, shape (k,)
    """
    tau = np.asarray(delays_s, dtype=float)
    w = 1.0 / np.maximum(np.asarray(uncertainties_s, dtype=float), 1e-12) ** 2
    fixed = float(np.sum(w * tau) / w.sum())
    q = float(np.sum(w * (tau - fixed) ** 2))
    c = float(w.sum() - np.sum(w**2) / w.sum())
    omega2 = max(0.0, (q - (tau.size - 1)) / c) if tau.size > 1 and c > 0 else 0.0
    ws = 1.0 / (1.0 / w + omega2)
    return (
        float(np.sum(ws * tau) / ws.sum()),
        float(1.0 / np.sqrt(ws.sum())),
        float(np.sqrt(omega2)),
    )


class DataAligner:
    """The cells of one acquisition that ask for it (``delay_budget()``), aligned input by input.

    An input whose own fit meets the budget is aligned at once. One whose cell carries too
    little of that input's force for its own fit (the refusal of :func:`align_rows`) waits for
    the end of the run (:meth:`finish`): it then takes the run's delay — the mean ``τ̄`` of
    the inputs that met the budget, with the uncertainty ``√(se² + ω²)``, ``ω`` how much the
    coarse alignment wanders between inputs beyond their fits' own errors (the delay is the
    clocks', not the input's: :func:`run_delay`);
    the run is refused when that too costs more than the budget, or when no input met it.

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
        self.fits: dict[int, list[tuple[float, float]]] = {k: [] for k, _, _ in self.cells}
        self.waiting: dict[int, list[tuple[int, str]]] = {k: [] for k, _, _ in self.cells}

    def align(
        self,
        j: int,
        frequencies_hz: NDArray[np.float64],
        H: NDArray[np.complex128],
        coherence: NDArray[np.float64],
        where: str,
    ) -> list[str]:
        """Input ``j``'s FRFs ``H`` (n_lines, n_outputs) aligned in place where its own fit meets
        the budget; one message per cell."""
        messages = []
        for k, rows, lc in self.cells:
            budget = lc.delay_budget()  # type: ignore[attr-defined]
            if budget is None:
                continue
            refs = H[:, : self.first_row] if self.first_row > 0 else None
            try:
                H[:, rows], fit, phase = align_rows(
                    frequencies_hz,
                    H[:, rows],
                    coherence[:, rows],
                    budget,
                    where,
                    refs,
                    self.line_bandwidth,
                )
            except SetupError as err:
                if "too little of the force" not in str(err):
                    raise
                self.waiting[k].append((j, where))
                msg = f"{err}; it takes the run's delay at the end"
            else:
                self.fits[k].append((fit.delay_s, fit.uncertainty_s))
                msg = (
                    f"{budget.label}: {where}: residual delay {1e6 * fit.delay_s:+.1f} us fitted "
                    f"from the data, within {1e6 * fit.uncertainty_s:.1f} us ({phase:.2f} deg "
                    f"at {budget.band_hz:g} Hz), removed"
                )
            log.info("%s", msg)
            messages.append(msg)
        return messages

    def finish(
        self, frequencies_hz: NDArray[np.float64], H_all: NDArray[np.complex128]
    ) -> list[str]:
        """The waiting inputs (columns ``j`` of ``H_all``, shape (n_lines, n_outputs, n_inputs))
        aligned in place by the run's delay; one message per cell that had any.

        Raises
        ------
        SetupError
            No input met the budget, or the run's delay does not either.
        """
        f = np.asarray(frequencies_hz, dtype=float)
        messages = []
        for k, rows, lc in self.cells:
            if not self.waiting[k]:
                continue
            budget = lc.delay_budget()  # type: ignore[attr-defined]
            names = ", ".join(w for _, w in self.waiting[k])
            if not self.fits[k]:
                raise SetupError(
                    f"{budget.label}: {names}: the data align its loads to the DAQ's clock "
                    "within the budget on no input (no input's own fit met the budget, "
                    f"netft_max_phase_deg = {budget.max_phase_deg:g} at {budget.band_hz:g} Hz): "
                    "the cell carries too little of the force for its delay to be told; lower "
                    "netft_band_hz, or read the cell as loadcell = 'netft-can' or 'daq-channels'"
                )
            tau = np.array([t for t, _ in self.fits[k]])
            mean, sem, wander = run_delay(tau, np.array([u for _, u in self.fits[k]]))
            u = float(np.hypot(sem, wander))
            phase = phase_error_deg(u, budget.band_hz)
            if not phase <= budget.max_phase_deg:
                raise SetupError(_refusal(budget, names, u, phase, None))
            for j, _ in self.waiting[k]:
                H_all[:, rows, j] *= np.exp(2j * np.pi * f * mean)[:, None]
            msg = (
                f"{budget.label}: {names}: the run's delay {1e6 * mean:+.1f} us (from "
                f"{tau.size} inputs, wander {1e6 * wander:.1f} us beyond their fits' own "
                f"uncertainties), within {1e6 * u:.1f} us "
                f"({phase:.2f} deg at {budget.band_hz:g} Hz), removed"
            )
            log.info("%s", msg)
            messages.append(msg)
        return messages
