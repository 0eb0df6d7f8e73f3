"""Band selection: CMIF (thesis Fig. 37) and an automatic band suggestion that says why.

CMIF: the singular values of the accelerance matrix ``H(ω)`` (outputs × inputs) per line, largest
first; peaks of the first curve mark modes.

Automatic band (needs no known answer): DIM wants lines above the suspension modes (where
unmeasured support forces vanish relative to inertia forces) and below the first deformation mode
(where the body still moves rigidly), where the per-line estimates are flat. Per line we compute

- the rigid-body error ``e(ω) = ‖q − Ψ Ψ⁺ q‖ / ‖q‖`` over channels and inputs (rises near and above
  deformation modes);
- the per-line DIM estimates, normalised (mass by its median, CG by the sensor array radius ``L``,
  inertia by ``m L²``), and their *roughness* ``ρ(ω)``: the largest deviation from a running median
  over a window of lines (large near suspension and deformation modes, where the estimates swing).

A line is usable when ``e`` is below ``max(3 e₂₀, e₂₀ + 0.02)`` and ``ρ`` below
``max(3 ρ₂₀, 0.005)`` (``x₂₀`` the 20th percentile over all lines: the level of the good part of the
spectrum). The suggestion is the longest run of usable lines (gaps of one line bridged), then trimmed at
its ends until every line's normalised estimates lie within ``max(4 σ, 0.002)`` of the band median
(σ the line-to-line noise level from first differences): slow trends from the suspension or an
approaching mode, which a running median does not see, are cut off. CMIF peaks
below it with low rigid-body error are reported as suspension (rigid-body) modes, peaks with high
rigid-body error as deformation modes.
"""

from __future__ import annotations

import itertools
import logging
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.ndimage import median_filter
from scipy.signal import find_peaks

from dimacq.errors import DataError, SolverError
from dimacq.model.frf import FrfData
from dimacq.model.setup import TestSetup
from dimacq.pipeline.dim import assemble, solve_system
from dimacq.pipeline.rigid_body import response_matrix
from dimacq.pipeline.selection._common import response_geometry

__all__ = ["BandSuggestion", "cmif", "suggest_band"]

log = logging.getLogger(__name__)
FloatArray = NDArray[np.float64]


def cmif(H: NDArray[np.complexfloating]) -> FloatArray:
    """Complex mode indicator function: singular values of ``H`` per line.

    Parameters
    ----------
    H : ndarray, shape (n_lines, n_outputs, n_inputs), complex

    Returns
    -------
    ndarray, shape (n_lines, min(n_outputs, n_inputs)), descending per line.
    """
    out: FloatArray = np.linalg.svd(np.asarray(H), compute_uv=False)
    return out


@dataclass(frozen=True, eq=False)
class BandSuggestion:
    """A suggested analysis band with its evidence.

    Attributes
    ----------
    band_hz : (lo, hi)
    reason : str
    frequencies_hz : ndarray, shape (n_lines,)
    cmif : ndarray, shape (n_lines, n_sv)
    rigid_body_error : ndarray, shape (n_lines,)
    roughness : ndarray, shape (n_lines,)
    usable : ndarray of bool, shape (n_lines,)
    suspension_peaks_hz, deformation_peaks_hz : tuple of float
    per_line : ndarray, shape (n_lines, 10)
        Per-line DIM estimates over the whole span.
    """

    band_hz: tuple[float, float]
    reason: str
    frequencies_hz: FloatArray
    cmif: FloatArray
    rigid_body_error: FloatArray
    roughness: FloatArray
    usable: NDArray[np.bool_]
    suspension_peaks_hz: tuple[float, ...]
    deformation_peaks_hz: tuple[float, ...]
    per_line: FloatArray

    def to_json(self) -> dict[str, Any]:
        return {
            "band_hz": list(self.band_hz),
            "reason": self.reason,
            "automatic": True,
            "suspension_peaks_hz": list(self.suspension_peaks_hz),
            "deformation_peaks_hz": list(self.deformation_peaks_hz),
        }


def _longest_run(mask: NDArray[np.bool_], bridge: int = 1) -> tuple[int, int]:
    m = mask.copy()
    # bridge gaps of up to `bridge` lines between usable lines
    idx = np.nonzero(m)[0]
    for a, b in itertools.pairwise(idx):
        if 1 < b - a <= bridge + 1:
            m[a:b] = True
    best, start, best_rng = 0, None, (0, -1)
    for i, v in enumerate(np.append(m, False)):
        if v and start is None:
            start = i
        elif not v and start is not None:
            if i - start > best:
                best, best_rng = i - start, (start, i - 1)
            start = None
    return best_rng


def suggest_band(
    frf: FrfData,
    setup: TestSetup,
    *,
    known: Mapping[str, float] | None = None,
    response_weights: NDArray[np.floating] | None = None,
    input_keep: NDArray[np.bool_] | None = None,
    window: int | None = None,
    min_lines: int = 5,
    flat_sigma: float = 4.0,
    flat_floor: float = 2e-3,
) -> BandSuggestion:
    """Suggest an analysis band (module docstring).

    Parameters
    ----------
    frf : FrfData
        The whole measured span.
    setup : TestSetup
    known : dict, optional
        Known properties for the per-line solves.
    response_weights : ndarray, shape (n_acceleration_outputs,), optional
        0 for channels already excluded.
    input_keep : ndarray of bool, shape (n_inputs,), optional
    window : int, optional
        Running-median window in lines (default ``max(5, n_lines // 15)``, odd).
    min_lines : int
        The suggested band must hold at least this many lines.
    flat_sigma, flat_floor : float
        Plateau tolerance per normalised parameter: ``max(flat_sigma · σ, flat_floor)`` with σ the
        line-to-line noise level (robust scale of first differences / √2).
    """
    geo = response_geometry(frf, setup)
    data = frf if input_keep is None else frf.select(inputs=np.nonzero(input_keep)[0])
    q = data.H[:, geo.output_index, :]
    w = np.ones(q.shape[1]) if response_weights is None else np.asarray(response_weights, float)
    use = w > 0
    f = data.frequencies_hz
    sv = cmif(q[:, use, :])
    psi = response_matrix(geo.positions_m, geo.directions, setup.reference_point)[use]
    qa = q[:, use, :]
    fit = np.einsum("ck,lkj->lcj", psi @ np.linalg.pinv(psi), qa)
    with np.errstate(divide="ignore", invalid="ignore"):
        e = np.sqrt(
            np.sum(np.abs(qa - fit) ** 2, axis=(1, 2)) / np.sum(np.abs(qa) ** 2, axis=(1, 2))
        )
    system = assemble(data, setup, response_weights=w)
    try:
        res = solve_system(system, known=known, check_plausibility=False)
        pl = res.per_line
    except SolverError:
        pl = np.full((f.size, 10), np.nan)
    L = float(
        np.sqrt(np.mean(np.sum((geo.positions_m - geo.positions_m.mean(axis=0)) ** 2, axis=1)))
    )
    m_med = float(np.nanmedian(pl[:, 0])) if np.any(np.isfinite(pl[:, 0])) else 1.0
    m_ref = abs(m_med) if m_med != 0 else 1.0
    norm = np.concatenate([[m_ref], [L] * 3, [m_ref * L**2] * 6])
    pn = pl / norm
    win = window or max(5, f.size // 15)
    win += 1 - win % 2
    rough = np.full(f.size, np.inf)
    fin = np.all(np.isfinite(pn), axis=1)
    if fin.sum() >= 3:
        med = median_filter(np.where(fin[:, None], pn, 0.0), size=(win, 1), mode="nearest")
        rough = np.where(fin, np.max(np.abs(pn - med), axis=1), np.inf)
    e20 = float(np.nanpercentile(e, 20))
    r20 = (
        float(np.percentile(rough[np.isfinite(rough)], 20)) if np.isfinite(rough).any() else np.inf
    )
    e_thr = max(3 * e20, e20 + 0.02)
    r_thr = max(3 * r20, 0.005)
    usable = (e < e_thr) & (rough < r_thr)
    i0, i1 = _longest_run(usable)
    # plateau: trim the ends of the run until every line lies within tol of the band median
    fin_idx = np.isfinite(pn).all(axis=1)
    dif = np.diff(pn[fin_idx], axis=0)
    sig = (
        1.4826 * np.median(np.abs(dif - np.median(dif, axis=0)), axis=0) / np.sqrt(2)
        if dif.shape[0] > 2
        else np.zeros(10)
    )
    tol = np.maximum(flat_sigma * sig, flat_floor)
    while i1 - i0 + 1 > min_lines:
        d = np.max(np.abs(pn[i0 : i1 + 1] - np.median(pn[i0 : i1 + 1], axis=0)) / tol, axis=1)
        if d[0] <= 1.0 and d[-1] <= 1.0:
            break
        if d[0] >= d[-1]:
            i0 += 1
        else:
            i1 -= 1
    if i1 - i0 + 1 < min_lines:
        raise DataError(
            f"no run of {min_lines} usable lines: the rigid-body error or the per-line estimates "
            "vary everywhere; check the data or give the band by hand"
        )
    peaks, _ = find_peaks(np.log10(sv[:, 0] + 1e-300), prominence=0.3)
    susp = tuple(float(f[p]) for p in peaks if e[p] < e_thr and f[p] < f[i0])
    deform = tuple(float(f[p]) for p in peaks if e[p] >= e_thr)
    lo, hi = float(f[i0]), float(f[i1])
    in_band = np.arange(i0, i1 + 1)
    m_var = float(np.nanstd(pl[in_band, 0]) / m_ref * 100)
    parts = [
        f"{lo:g}–{hi:g} Hz ({i1 - i0 + 1} lines): the longest run where the rigid-body error "
        f"is below {e_thr:.3g} and the per-line estimates are flat (within the plateau tolerance); "
        f"per-line mass varies {m_var:.2g} % there"
    ]
    if i0 > 0:
        below = f"below {lo:g} Hz the per-line estimates drift off the plateau"
        if susp:
            below += (
                f" near the suspension (rigid-body) peaks at {', '.join(f'{x:g}' for x in susp)} Hz"
            )
        parts.append(below)
    if i1 < f.size - 1:
        k = i1 + 1
        above = (
            f"above {hi:g} Hz the rigid-body error rises to {e[k]:.3g}"
            if e[k] >= e_thr
            else f"above {hi:g} Hz the per-line estimates drift off the plateau"
        )
        up = [x for x in deform if x > hi]
        if up:
            above += f" towards the first deformation mode at {up[0]:g} Hz"
        parts.append(above)
    reason = "; ".join(parts)
    log.info("suggested band %s", reason)
    return BandSuggestion(
        band_hz=(lo, hi),
        reason=reason,
        frequencies_hz=f,
        cmif=sv,
        rigid_body_error=e,
        roughness=rough,
        usable=usable,
        suspension_peaks_hz=susp,
        deformation_peaks_hz=deform,
        per_line=pl,
    )
