"""Load cells on their own clock (an ATI Net F/T's RDT) finished from the data: the residual
delay of each input's cell FRFs fitted, removed, and checked against the phase budget.

The driver puts the stream on the DAQ's sample grid through the host's clock (a coarse time
base, ~0.1 ms of wall time) and says what is left to do (``delay_budget()``, None when its
samples are final). Here, once an input's FRFs are estimated, the cell's rows (loads or gauges
per unit hammer force) are fitted for the delay ``τ`` they share
(:func:`~dimacq.pipeline.stream_alignment.fit_delay`: the cell's loads are real combinations of
the accelerometers' FRFs and the hammer's own term — the rigid-body law DIM solves — on the lines
from the budget's ``lo_hz`` to its ``band_hz``), multiplied by ``e^{iωτ}`` on every line, and the
run is refused (:class:`~dimacq.errors.SetupError`, one line) when the fit's uncertainty costs
more FRF phase at ``band_hz`` than allowed — the data could not support the alignment.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from dimacq.devices.loadcell import LoadCell
from dimacq.errors import SetupError
from dimacq.pipeline.stream_alignment import DelayBudget, DelayFit, fit_delay, phase_error_deg

__all__ = ["align_input_by_data", "align_rows"]

log = logging.getLogger(__name__)


def align_rows(
    frequencies_hz: NDArray[np.float64],
    H: NDArray[np.complex128],
    coherence: NDArray[np.float64],
    budget: DelayBudget,
    where: str,
    references: NDArray[np.complex128] | None = None,
) -> tuple[NDArray[np.complex128], DelayFit, float]:
    """One cell's FRFs ``H`` (n_lines, n_rows) with their fitted delay removed, the fit and the
    phase its uncertainty costs at ``budget.band_hz`` (degrees).

    ``references`` (n_lines, n_responses): the same input's FRFs on the DAQ's clock (the
    accelerometers), the regressors of equation (1) of
    :mod:`~dimacq.pipeline.stream_alignment` with a column of ones (the hammer's own term);
    None: the mass-line basis (2). Each row is scaled to unit RMS over the fit's lines (forces
    and moments count alike); each line is weighted by the median over the rows of
    ``γ² / (1 − γ²)`` (its inverse relative variance; ``1 − γ²`` floored at 1e-4).

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
        fit = fit_delay(f[m], Hm, w, search_s=budget.search_s, regressors=X)
    except ValueError as err:
        raise SetupError(
            f"{budget.label}: {where}: no delay fit from the data ({err}); set netft_fit_lo_hz "
            "well below netft_band_hz in the rig file"
        ) from err
    phase = phase_error_deg(fit.uncertainty_s, budget.band_hz)
    if not phase <= budget.max_phase_deg:
        raise SetupError(
            f"{budget.label}: {where}: the data align its loads to the DAQ's clock within only "
            f"{1e6 * fit.uncertainty_s:.1f} us ({1e6 * fit.sigma_s:.1f} us statistical, "
            f"{1e6 * fit.spread_s:.1f} us between the band's halves), {phase:.1f} deg of FRF "
            f"phase at {budget.band_hz:g} Hz (limit netft_max_phase_deg = "
            f"{budget.max_phase_deg:g}): the cell carries too little of the force for its "
            "delay to be told; lower netft_band_hz, or read the cell as loadcell = 'netft-can' "
            "or 'daq-channels'"
        )
    out = H * np.exp(2j * np.pi * f * fit.delay_s)[:, None]
    return out, fit, phase


def align_input_by_data(
    frequencies_hz: NDArray[np.float64],
    H: NDArray[np.complex128],
    coherence: NDArray[np.float64],
    loadcells: Sequence[LoadCell],
    widths: Sequence[int],
    first_row: int,
    where: str,
) -> list[str]:
    """Every cell of ``loadcells`` that asks for it aligned in ``H`` (n_lines, n_outputs: the
    responses first, the cells' rows from ``first_row``, ``widths`` rows each), in place,
    against the responses (equation (1)); one message per cell."""
    messages = []
    row = first_row
    for lc, n in zip(loadcells, widths, strict=True):
        ask = getattr(lc, "delay_budget", None)
        budget = ask() if ask is not None else None
        if budget is not None:
            rows = slice(row, row + n)
            H[:, rows], fit, phase = align_rows(
                frequencies_hz,
                H[:, rows],
                coherence[:, rows],
                budget,
                where,
                references=H[:, :first_row] if first_row > 0 else None,
            )
            msg = (
                f"{budget.label}: {where}: residual delay {1e6 * fit.delay_s:+.1f} us fitted from "
                f"the data, within {1e6 * fit.uncertainty_s:.1f} us ({phase:.2f} deg at "
                f"{budget.band_hz:g} Hz), removed"
            )
            log.info("%s", msg)
            messages.append(msg)
        row += n
    return messages
