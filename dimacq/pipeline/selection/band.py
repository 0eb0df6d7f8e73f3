"""Band selection: CMIF (thesis Fig. 37) and an automatic band suggestion that says why.

CMIF: the singular values of the accelerance matrix ``H(ω)`` (outputs × inputs) per line, largest
first; peaks of the first curve mark modes.

Automatic band (needs no known answer). DIM wants lines where the measured structure is one rigid
body whose every external force is measured: above the suspension / support modes (where
unmeasured support forces are not negligible against inertia forces) and below the first elastic
mode (above which parts of the structure no longer follow it: the DIM then sees a different, smaller
body however flat and rigid the data look). Per line we compute

- the rigid-body error ``e(ω) = ‖q − Ψ Ψ⁺ q‖ / ‖q‖`` over the kept channels and inputs (rises
  where the measured points do not move rigidly);
- the DIM residual ``r(ω) = ‖A x(ω) − b‖ / ‖b‖`` of each line solved on its own
  (:func:`~dimacq.pipeline.dim.line_residuals`): rises where the rigid-body equations with the
  measured forces do not hold (unmeasured support forces, the unmeasured inertia force of an elastic
  part near its resonance);
- the per-line DIM estimates, normalised (mass by its median, CG by the sensor array radius ``L``,
  inertia by ``m L²``), and their *roughness* ``ρ(ω)``: the largest deviation from a running median.

Thresholds: ``e`` below ``min(max(3 e₁₀, e₁₀ + 0.02), e_max)`` and ``r`` below
``min(max(3 r₁₀, r₁₀ + 0.02), r_max)`` (``x₁₀`` the 10th percentile over all lines: the noise floor,
assuming only a tenth of the span is rigid), with ABSOLUTE limits ``e_max`` and ``r_max``
(default 0.10 each): whatever the spectrum, a line whose measured motion is more than 10 % non-rigid
or whose rigid-body equations leave more than 10 % unexplained is not usable. Each normalised
estimate within ``max(5 σ, 0.005)`` of its running median (σ its line-to-line noise level, below;
:data:`ROUGH_SIGMA`): noise alone does not break the usable lines apart.

Modes the rigid-body model does not explain: CMIF peaks (first curve) where ``e`` or ``r`` lies
above its threshold within ±2 lines, and peaks of ``r`` itself. Walking up in frequency, the first
run of usable lines (gaps of one line bridged) that keeps at least ``min_lines`` lines after
trimming is the start of the rigid-body band; runs above it join it unless an unexplained peak lies
between (that peak is an elastic mode: the band never crosses it); the longest of those runs wins.
Unexplained peaks below the band are reported as suspension (support) modes, the ones above as
elastic modes. Each run starts clear of the highest peak of the first CMIF curve ``σ₁`` at or below
it: on that peak's falling flank, above the last line where ``σ₁`` is more than twice its mass-line
level (:data:`MASS_LINE_RATIO`). A run whose ``σ₁`` is not yet flat at its start, rising through
its mass line to a maximum and falling back to it (a suspension resonance too damped, or too
smeared by the exponential window, to stand out as a peak), starts above that maximum
(:data:`MASS_LINE_FLATNESS`). The run is trimmed at its ends until every line's normalised
estimates lie within ``max(4 σ, 0.002)`` of the band median (σ the line-to-line noise level from
first differences): slow trends from the suspension or an approaching mode are cut off. Its top
stays at or below 0.6 of the first elastic mode above it (:data:`ELASTIC_CLEARANCE`).

If no run qualifies, the suggestion says so (``qualified = False``) and names the best band found
(the run with the lowest median DIM residual) with its errors; the caller must refuse the answer.
"""

from __future__ import annotations

import itertools
import logging
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from dimacq.errors import DataError, SolverError
from dimacq.model.frf import FrfData
from dimacq.model.setup import TestSetup
from dimacq.pipeline._filters import median_filter_nearest
from dimacq.pipeline.dim import assemble, line_residuals, solve_system
from dimacq.pipeline.line_noise import scatter_sigma
from dimacq.pipeline.rigid_body import response_matrix
from dimacq.pipeline.selection._common import response_geometry

__all__ = [
    "ELASTIC_CLEARANCE",
    "MASS_LINE_FLATNESS",
    "MASS_LINE_RATIO",
    "MAX_RESIDUAL",
    "MAX_RIGID_BODY_ERROR",
    "MIN_BAND_LINES",
    "ROUGH_FLOOR",
    "ROUGH_SIGMA",
    "BandSuggestion",
    "cmif",
    "suggest_band",
]

log = logging.getLogger(__name__)
FloatArray = NDArray[np.float64]

#: Absolute limit of the rigid-body error of a usable line (and of a band's worst line).
MAX_RIGID_BODY_ERROR = 0.10
#: Absolute limit of the per-line DIM residual of a usable line.
MAX_RESIDUAL = 0.10
#: Fewest lines of an automatic band. The plateau test and the line-to-line scatter behind the
#: interval need them: from n lines the scatter's standard deviation is known to ±1/√(2(n−1))
#: (±27 % at 8, ±35 % at 5) and a 5-line run cannot show a trend from a mode nearby (an X-38-like
#: case with a chute mode 3× above a 5-line band measured 1 % light with every check flat).
#: Finer resolution (longer records) gives more lines in the same band.
MIN_BAND_LINES = 8
#: Roughness limit of a usable line, in line-to-line noise levels σ of each normalised estimate:
#: a local disturbance (a mode the rigid-body model half explains, a bad line) moves the estimates
#: off their running median by many σ, noise by a few. The limit was ``3 ×`` the 10th percentile of
#: the roughness, which noise alone crossed on a third of the lines of a 1 %-noise X-38-like
#: spectrum (``tests/scripts/accuracy_must_show.py``): the usable lines fell apart into runs of 2–
#: 10 lines, and the longest, where chance put it, won — 17.9–19.3 Hz, just below a 23 Hz elastic
#: mode, 28 mm CG error reported ok. At 5 σ noise alone crosses on about one line in 10⁵ per
#: estimate.
ROUGH_SIGMA = 5.0
#: Smallest roughness limit (normalised units), for noise-free data.
ROUGH_FLOOR = 0.005
#: Highest band line, as a fraction of the first elastic mode above the band. Below an elastic mode
#: at ``f_e`` its part's dynamic mass adds ``(f/f_e)² / (1 − (f/f_e)²)`` times the part's modal mass
#: to what the DIM sees — 0.56 at 0.6 ``f_e``, 0.96 at 0.7, 1.8 at 0.8 — as a smooth trend the
#: per-line plateau test misses in noisy data. Measured on the shipped x38 at 3 % FRF noise: the
#: band reached 18–19 Hz, 0.8 of the 23 Hz tail mode, and the CG came out up to 5.5 mm off, up to
#: 2 half-widths outside its interval, verdict ok.
ELASTIC_CLEARANCE = 0.6
#: Clearance of the band from a resonance below it (a suspension or support mode): on the falling
#: flank of the highest peak of the first CMIF curve ``σ₁`` at or below the run, the band starts
#: above the last line where ``σ₁`` exceeds this many times its lowest level between that peak and
#: the run's top (the mass line). Next to a lightly damped suspension mode every input drives
#: that one mode: each line's system is nearly rank one (``σ₁/σ₆`` 26 one line above an X-38-like
#: vehicle's 4.25 Hz bounce mode, 5.7 on its mass line), so the stated geometry's errors are
#: amplified, and the line's large motion gives it the weight of ten mass-line lines in the joint
#: solve. Measured (``tests/scripts/accuracy_must_show.py``, flexible case, seed 5): the band
#: 4.375–6.625 Hz, one line (σ₁ 8× the mass line) next to the mode, gave −0.32 % mass and 3.5 mm
#: CG; from 4.5 Hz 0.009 % and 0.5 mm. At twice the mass line the suspension mode still carries
#: as much motion as the rigid body's inertia (``(f_s/f)² / (1 − (f_s/f)²) ≈ 1``), a clearance
#: of about 15 % in frequency for a 3 %-damped mode. The check is one-sided: only the falling
#: flank of a peak at or below the run trims it, so a run with no resonance below it (free-free,
#: or ``σ₁`` rising from the lowest line) keeps its start. A structure on stiff measured supports
#: whose support modes lie inside the span is trimmed above them like any other (the calibration
#: mass standing on its cell: 133.5 → 221 Hz; that case fails the band checks either way).
MASS_LINE_RATIO = 2.0
#: Flatness of the mass line: ``σ₁`` within this fraction of its level (its median over the run)
#: is on the mass line. The suspension (rigid-body) modes are where it is not yet: a rigid body on
#: a support of stiffness ``k`` has the accelerance ``a/F = (1/m) s² / (s² + ω_s²)``, below the
#: mass line ``1/m`` under ``f_s`` (stiffness-controlled, rising as ``f²``), above it over the
#: resonance and falling back as ``1/(1 − (f_s/f)²)`` (within 5 % from ``4.6 f_s``). Lightly
#: damped modes are peaks the resonance clearance finds; the exponential window of an impact test
#: (``s = iω + 1/τ``) smears them: on the calibration mass hung on a bungee (suspension modes
#: 0.43–2.05 Hz, τ = 0.25 s, 0.5 Hz lines) ``σ₁`` rises from 0.3× its mass line at 0.5 Hz to
#: 1.3× at 2.5 Hz and is back within 5 % from 8 Hz: no peak of twice the mass line, and the band
#: started at 0.5 Hz, under every suspension mode. A run whose ``σ₁`` is off its level by more
#: than this fraction at its first line, reaches more than this fraction above it and comes back
#: within it inside the run starts one line above that maximum (the top suspension mode as the
#: window shows it); a curve that rises and never comes back (towards an elastic mode above)
#: moves nothing.
MASS_LINE_FLATNESS = 0.05


def find_peaks(x: NDArray[np.floating], prominence: float) -> NDArray[np.intp]:
    """Peaks of ``x`` with a topographic prominence of at least ``prominence``.

    The peaks ``scipy.signal.find_peaks(x, prominence=prominence)[0]`` returns, the same way:
    a peak is a sample (the middle one of a flat top, rounded down) above its left neighbour
    and above the first different sample on its right; its prominence is its height above the
    higher of the lowest samples between it and the first strictly higher sample (or NaN, or the
    end) on either side. Written out because importing ``scipy.signal`` costs ``dimacq solve``
    about 0.6 s of CPU at start-up, longer than the rest of the band search.

    Parameters
    ----------
    x : ndarray, shape (n,)
    prominence : float

    Returns
    -------
    ndarray of int, ascending
    """
    v = np.ascontiguousarray(x, dtype=np.float64)
    n = v.size
    if n < 3:
        return np.zeros(0, dtype=np.intp)
    # Runs of equal samples (NaN ends a run: NaN != NaN). A run is a peak when the samples
    # before and after it are lower; the first and last runs touch the ends and never are.
    change = np.flatnonzero(v[1:] != v[:-1]) + 1
    starts = np.concatenate([[0], change])
    ends = np.concatenate([change - 1, [n - 1]])
    top = v[starts]
    k = np.arange(1, starts.size - 1)
    is_peak = (top[k - 1] < top[k]) & (top[k + 1] < top[k])
    out = ((starts[k] + ends[k]) // 2)[is_peak].astype(np.intp)
    prom = np.empty(out.size)
    for m, pk in enumerate(out.tolist()):
        h = v[pk]
        stop_l = np.flatnonzero(~(v[:pk] <= h))  # higher samples, or NaN, on the left
        lo = int(stop_l[-1]) + 1 if stop_l.size else 0
        stop_r = np.flatnonzero(~(v[pk + 1 :] <= h))
        hi = pk + 1 + int(stop_r[0]) if stop_r.size else n
        left_min = float(np.min(v[lo : pk + 1]))
        right_min = float(np.min(v[pk:hi]))
        prom[m] = h - (left_min if left_min > right_min else right_min)
    return out[prominence <= prom]


def cmif(H: NDArray[np.complexfloating]) -> FloatArray:
    """Complex mode indicator function: singular values of ``H`` per line.

    ``σ_k = √λ_k`` of the Gram matrix ``HᴴH`` (or ``HHᴴ``, the smaller), one Hermitian
    eigenvalue problem per line: a quarter less work than the SVD (57 against 74 ms on an
    acquired test's 2048 lines of 24 × 24). ``σ₁``, the curve the band search reads, comes out
    within a few ``ε`` relative of the SVD's; a smaller ``σ_k`` within ``ε σ₁²/σ_k`` (what a
    log-scale plot cannot show).

    Parameters
    ----------
    H : ndarray, shape (n_lines, n_outputs, n_inputs), complex

    Returns
    -------
    ndarray, shape (n_lines, min(n_outputs, n_inputs)), descending per line.
    """
    h = np.asarray(H)
    hh = np.swapaxes(h, -1, -2).conj()
    gram = hh @ h if h.shape[-2] >= h.shape[-1] else h @ hh
    lam = np.linalg.eigvalsh(gram)[..., ::-1]  # ascending → descending
    out: FloatArray = np.sqrt(np.clip(lam, 0.0, None))
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
        Peaks the rigid-body model does not explain, below and above the band (the latter are
        the elastic modes).
    per_line : ndarray, shape (n_lines, 10)
        Per-line DIM estimates over the whole span.
    residual : ndarray, shape (n_lines,)
        Per-line DIM residual ``r(ω)``.
    qualified : bool
        False when no band meets the limits: ``band_hz`` is then the best band found, not one to
        solve in, and ``reason`` says why.
    band_rigid_body_error, band_residual : float
        Largest ``e`` and median ``r`` over the band's lines.
    limits : dict
        The thresholds used (``rigid_body_error``, ``residual``, absolute maxima).
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
    residual: FloatArray | None = None
    qualified: bool = True
    band_rigid_body_error: float = float("nan")
    band_residual: float = float("nan")
    limits: dict[str, float] | None = None

    def to_json(self) -> dict[str, Any]:
        return {
            "band_hz": list(self.band_hz),
            "reason": self.reason,
            "automatic": True,
            "qualified": self.qualified,
            "rigid_body_error": self.band_rigid_body_error,
            "residual": self.band_residual,
            "limits": dict(self.limits or {}),
            "suspension_peaks_hz": list(self.suspension_peaks_hz),
            "deformation_peaks_hz": list(self.deformation_peaks_hz),
            "elastic_modes_hz": list(self.deformation_peaks_hz),
        }


def _runs(mask: NDArray[np.bool_], bridge: int = 1) -> list[tuple[int, int]]:
    """Runs ``(first, last)`` of True lines, gaps of up to ``bridge`` lines bridged, ascending."""
    m = mask.copy()
    idx = np.nonzero(m)[0]
    for a, b in itertools.pairwise(idx):
        if 1 < b - a <= bridge + 1:
            m[a:b] = True
    out: list[tuple[int, int]] = []
    start: int | None = None
    for i, v in enumerate(np.append(m, False)):
        if v and start is None:
            start = i
        elif not v and start is not None:
            out.append((start, i - 1))
            start = None
    return out


@dataclass(frozen=True, eq=False)
class _LineEvidence:
    """Per-line evidence over the whole span: CMIF, rigid-body error, DIM estimates, residual."""

    f: FloatArray
    sv: FloatArray
    e: FloatArray
    pl: FloatArray
    r: FloatArray
    m_ref: float
    pn: FloatArray


def _line_evidence(
    frf: FrfData,
    setup: TestSetup,
    known: Mapping[str, float] | None,
    response_weights: NDArray[np.floating] | None,
    input_keep: NDArray[np.bool_] | None,
) -> _LineEvidence:
    """CMIF, rigid-body error ``e = ‖q − Ψ Ψ⁺ q‖ / ‖q‖``, per-line DIM and residual per line.

    The estimates are normalised: mass by its median, CG by ``L``, inertia by ``m L²``.
    """
    geo = response_geometry(frf, setup)
    # every input kept (the first pass): the FRFs as they are, not a copy of them (23 MB on an
    # acquired test)
    data = (
        frf
        if input_keep is None or bool(np.all(input_keep))
        else frf.select(inputs=np.nonzero(input_keep)[0])
    )
    w = (
        np.ones(geo.output_index.size)
        if response_weights is None
        else np.asarray(response_weights, float)
    )
    use = w > 0
    f = data.frequencies_hz
    n = f.size
    # np.take: numpy's fancy indexing on the middle axis of a complex array is several times
    # slower. The rigid-body fit Ψ Ψ⁺ q is one real matmul on the (re, im) view, and the
    # squared norms are sums over that view.
    qa = np.take(data.H, geo.output_index[use], axis=1)  # (L, n_used, n_in)
    sv = cmif(qa)
    psi = response_matrix(geo.positions_m, geo.directions, setup.reference_point)[use]
    qv = qa.view(np.float64)  # (L, n_used, 2 n_in): |z|² summed as re² + im²
    dv = qv - (psi @ np.linalg.pinv(psi)) @ qv
    with np.errstate(divide="ignore", invalid="ignore"):
        e = np.sqrt(np.einsum("lcx,lcx->l", dv, dv) / np.einsum("lcx,lcx->l", qv, qv))
    e = np.where(np.isfinite(e), e, np.inf)
    system = assemble(data, setup, response_weights=w)
    try:
        res = solve_system(system, known=known, check_plausibility=False)
        pl = res.per_line
    except SolverError:
        pl = np.full((n, 10), np.nan)
    r = line_residuals(system, known=known)
    r = np.where(np.isfinite(r), r, np.inf)
    L = float(
        np.sqrt(np.mean(np.sum((geo.positions_m - geo.positions_m.mean(axis=0)) ** 2, axis=1)))
    )
    m_med = float(np.nanmedian(pl[:, 0])) if np.any(np.isfinite(pl[:, 0])) else 1.0
    m_ref = abs(m_med) if m_med != 0 else 1.0
    norm = np.concatenate([[m_ref], [L] * 3, [m_ref * L**2] * 6])
    return _LineEvidence(f=f, sv=sv, e=e, pl=pl, r=r, m_ref=m_ref, pn=pl / norm)


def _roughness(
    pn: FloatArray, window: int | None, rough_sigma: float
) -> tuple[FloatArray, FloatArray, NDArray[np.bool_]]:
    """Line-to-line noise level ``σ``, roughness ``ρ`` and the lines within ``max(5 σ, floor)``.

    ``σ = 1.4826 MAD(Δp) / √2`` per normalised estimate (first differences,
    :func:`dimacq.pipeline.line_noise.scatter_sigma`); ``ρ = max |p − median_win(p)|``.

    Returns
    -------
    sig : ndarray, shape (10,)
    rough : ndarray, shape (n_lines,)
    rough_ok : ndarray of bool, shape (n_lines,)
    """
    n = pn.shape[0]
    win = window or max(5, n // 15)
    win += 1 - win % 2
    fin = np.all(np.isfinite(pn), axis=1)
    # line-to-line noise level of each normalised estimate (robust scale of first differences)
    sig = scatter_sigma(pn[fin], 1) if fin.sum() > 3 else np.zeros(10)
    rough = np.full(n, np.inf)
    if fin.sum() >= 3:
        med = median_filter_nearest(np.where(fin[:, None], pn, 0.0), win)
        dev = np.abs(pn - med)
        rough = np.where(fin, np.max(dev, axis=1), np.inf)
        rough_ok = fin & np.all(dev < np.maximum(rough_sigma * sig, ROUGH_FLOOR), axis=1)
    else:
        rough_ok = np.zeros(n, bool)
    return sig, rough, rough_ok


def _threshold(x: FloatArray, limit: float) -> float:
    """Usable-line threshold ``min(max(3 x₁₀, x₁₀ + 0.02), limit)``, ``x₁₀`` the 10th percentile."""
    x10 = float(np.percentile(x[np.isfinite(x)], 10)) if np.isfinite(x).any() else np.inf
    return min(max(3 * x10, x10 + 0.02), limit)


def _unexplained_peaks(
    sv: FloatArray, e: FloatArray, r: FloatArray, e_thr: float, r_thr: float
) -> tuple[NDArray[np.intp], list[int]]:
    """CMIF peaks, and the peaks the rigid-body model does not explain.

    Unexplained: CMIF peaks where ``e`` or ``r`` reaches its threshold within ±2 lines, and peaks
    of ``r`` itself above its threshold.

    Returns
    -------
    cpk : ndarray of int
        Peaks of the first CMIF curve.
    unexplained : list of int, ascending
    """

    def _near_max(x: FloatArray, i: int) -> float:
        return float(np.max(x[max(i - 2, 0) : i + 3]))

    cpk = find_peaks(np.log10(sv[:, 0] + 1e-300), prominence=0.3)
    rlog = np.log10(np.where(np.isfinite(r), r, np.nanmax(r[np.isfinite(r)], initial=1.0)) + 1e-12)
    rpk = find_peaks(rlog, prominence=np.log10(2.0))
    unexplained = sorted(
        {int(p) for p in cpk if _near_max(e, p) >= e_thr or _near_max(r, p) >= r_thr}
        | {int(p) for p in rpk if r[p] >= r_thr}
    )
    return cpk, unexplained


@dataclass
class _BandSearch:
    """The walk up the usable runs: resonance clearance, plateau trim, elastic clearance.

    ``cleared`` maps a band start moved by the resonance clearance to that CMIF peak, ``capped``
    a band top moved by the elastic clearance to that elastic peak.
    """

    f: FloatArray
    pn: FloatArray
    s1: FloatArray
    cpk: NDArray[np.intp]
    unexplained: list[int]
    tol: FloatArray
    min_lines: int
    mass_line_ratio: float
    elastic_clearance: float
    mass_line_flatness: float = MASS_LINE_FLATNESS
    cleared: dict[int, int] = field(default_factory=dict)
    capped: dict[int, int] = field(default_factory=dict)
    risen: dict[int, int] = field(default_factory=dict)

    def suspension_top(self, i0: int, i1: int) -> int | None:
        """The maximum of ``σ₁`` over the run's first not-flat stretch when it is a resonance.

        With ``M`` the median of ``σ₁`` over ``[i0, i1]`` (its mass-line level) and ``δ``
        :data:`MASS_LINE_FLATNESS`, the stretch is the lines from ``i0`` on with
        ``|σ₁/M − 1| > δ``. When it ends inside the run (``σ₁`` comes back to its mass line) and
        its maximum lies above its first line and above ``(1 + δ) M`` (``σ₁`` rose through the
        mass line to a resonance and fell back), that maximum's line; otherwise None.
        """
        if i1 - i0 < 2:
            return None
        seg = self.s1[i0 : i1 + 1]
        level = float(np.median(seg))
        if not level > 0:
            return None
        off = np.abs(seg / level - 1.0) > self.mass_line_flatness
        if not off[0] or off.all():
            return None
        n_off = int(np.argmin(off))
        k = int(np.argmax(seg[:n_off]))
        if k == 0 or seg[k] <= (1.0 + self.mass_line_flatness) * level:
            return None
        return i0 + k

    def clear_of_resonance(self, i0: int, i1: int) -> int:
        """First line of ``[i0, i1]`` clear of the highest resonance at or below it: on that
        peak's falling flank, the last line where ``σ₁`` exceeds :data:`MASS_LINE_RATIO` times its
        lowest level between the peak and ``i1`` (the mass line) bounds the band from below. A
        suspension resonance at the run's start that is no CMIF peak
        (:meth:`suspension_top`) counts as one, and the band starts above it."""
        below = [int(p) for p in self.cpk if p <= i1]
        top = self.suspension_top(i0, i1)
        if top is not None:
            self.risen[top + 1] = top
            i0 = top + 1
            below = sorted({*below, top})
        if i1 < i0 or not below:
            return i0
        pk = below[-1]
        seg = self.s1[pk : i1 + 1]
        k = int(np.argmin(seg))  # the falling flank only: σ₁ may rise again towards a mode above
        high = np.nonzero(seg[:k] > self.mass_line_ratio * seg[k])[0]
        start = max(i0, pk + int(high[-1]) + 1) if high.size else i0
        if start > i0:
            self.cleared[start] = pk
        return start

    def suspension_peaks_hz(self, i0: int) -> list[float]:
        """The resonances below a band starting at line ``i0``, ascending: the unexplained
        peaks, the CMIF peaks the rigid-body model explains, and the maximum of ``σ₁`` the band
        was started above (:meth:`suspension_top`)."""
        f = self.f
        peaks = {float(f[p]) for p in self.unexplained if p < i0}
        peaks |= {float(f[p]) for p in self.cpk if p < i0 and int(p) not in self.unexplained}
        if i0 in self.risen:
            peaks.add(float(f[self.risen[i0]]))
        return sorted(peaks)

    def trim(self, i0: int, i1: int) -> tuple[int, int]:
        """Trim ``[i0, i1]`` at its ends until both end lines lie within ``tol`` of the median."""
        pn, tol = self.pn, self.tol
        while i1 - i0 + 1 > self.min_lines:
            seg = pn[i0 : i1 + 1]
            if not np.all(np.isfinite(seg)):
                bad = ~np.all(np.isfinite(seg), axis=1)
                if bad[0]:
                    i0 += 1
                    continue
                if bad[-1]:
                    i1 -= 1
                    continue
                seg = seg[~bad]
            d = np.max(np.abs(pn[i0 : i1 + 1] - np.median(seg, axis=0)) / tol, axis=1)
            d = np.where(np.isfinite(d), d, np.inf)
            if d[0] <= 1.0 and d[-1] <= 1.0:
                break
            if d[0] >= d[-1]:
                i0 += 1
            else:
                i1 -= 1
        return i0, i1

    def below_elastic(self, i0: int, i1: int) -> int:
        """Top line of ``[i0, i1]`` at most :data:`ELASTIC_CLEARANCE` times the frequency of the
        first unexplained peak above it (an elastic mode)."""
        f = self.f
        above = [int(p) for p in self.unexplained if p > i1]
        if not above:
            return i1
        cap = self.elastic_clearance * f[above[0]]
        top = i1
        while top >= i0 and f[top] > cap + 1e-9:
            top -= 1
        if top < i1:
            self.capped[top] = above[0]
        return top

    def candidates(self, usable: NDArray[np.bool_]) -> list[tuple[int, int]]:
        """Qualifying bands, walking up the usable runs until an elastic mode ends the walk."""
        unexplained, min_lines = self.unexplained, self.min_lines
        candidates: list[tuple[int, int]] = []
        for a, b in _runs(usable):
            if candidates and any(candidates[-1][1] < p < a for p in unexplained):
                break  # an elastic mode lies between: the band never crosses it
            # a run that holds an unexplained peak (bridged gap) is cut there
            inside = [p for p in unexplained if a <= p <= b]
            pieces = []
            lo_i = a
            for p in inside:
                pieces.append((lo_i, p - 1))
                lo_i = p + 1
            pieces.append((lo_i, b))
            for k, (i0, i1) in enumerate(pieces):
                i0 = self.clear_of_resonance(i0, i1)
                if i1 - i0 + 1 < min_lines:
                    if candidates and k < len(pieces) - 1:
                        break
                    continue
                t0, t1 = self.trim(i0, i1)
                t1 = self.below_elastic(t0, t1)
                if t1 - t0 + 1 >= min_lines:
                    candidates.append((t0, t1))
                    if k < len(pieces) - 1:  # an unexplained peak follows inside the run
                        break
            if candidates and inside and candidates[-1][1] < inside[-1]:
                break
        return candidates


def _best_band(
    e: FloatArray,
    r: FloatArray,
    min_lines: int,
    max_rigid_body_error: float,
    max_residual: float,
) -> tuple[int, int]:
    """Best band found when none qualifies: the window with the lowest median score.

    Over runs of lines with finite ``e`` and ``r``, a window of ``max(min_lines, n/20)`` lines
    slides to the lowest running median of ``max(e/e_max, r/r_max)``.
    """
    n = e.size
    cand = [(a, b) for a, b in _runs(np.isfinite(r) & np.isfinite(e)) if b - a + 1 >= min_lines]
    if not cand:
        raise DataError(
            "no frequency line has a finite rigid-body error and DIM residual; check the data"
        )
    best, best_score = cand[0], np.inf
    for a, b in cand:
        # slide a window of max(min_lines, 5 %) lines: lowest median of max(e/e_max, r/r_max)
        wl = max(min_lines, n // 20)
        score = np.maximum(e[a : b + 1] / max_rigid_body_error, r[a : b + 1] / max_residual)
        if b - a + 1 <= wl:
            s0, sc = a, float(np.median(score))
        else:
            med = median_filter_nearest(score, wl)
            k = int(np.argmin(med[wl // 2 : b - a + 1 - wl // 2])) + wl // 2
            s0, sc = a + k - wl // 2, float(med[k])
            b = s0 + wl - 1
            a = s0
        if sc < best_score:
            best, best_score = (a, b), sc
    return best


def _qualified_reason(
    ev: _LineEvidence,
    search: _BandSearch,
    i0: int,
    i1: int,
    e_thr: float,
    r_thr: float,
    susp_peaks: list[float],
    deform: tuple[float, ...],
) -> str:
    """Why the band: its errors, what bounds it below (resonance, drift) and above (mode, error)."""
    f, e, r, pl = ev.f, ev.e, ev.r, ev.pl
    n = f.size
    lo, hi = float(f[i0]), float(f[i1])
    band_e = float(np.max(e[i0 : i1 + 1]))
    band_r = float(np.median(r[i0 : i1 + 1]))
    in_band = np.arange(i0, i1 + 1)
    m_var = (
        float(np.nanstd(pl[in_band, 0]) / ev.m_ref * 100)
        if np.isfinite(pl[in_band, 0]).any()
        else float("nan")
    )
    parts = [
        f"{lo:g}–{hi:g} Hz ({i1 - i0 + 1} lines): rigid-body error ≤ {band_e:.3g} "
        f"(limit {e_thr:.3g}), DIM residual median {band_r:.3g} (limit {r_thr:.3g}), per-line "
        f"estimates flat (per-line mass varies {m_var:.2g} % there)"
    ]
    if i0 > 0:
        if i0 in search.cleared:
            below = (
                f"below {lo:g} Hz the resonance at {f[search.cleared[i0]]:g} Hz still dominates "
                f"the motion (first CMIF curve above {search.mass_line_ratio:g}× its mass-line "
                "level)"
            )
        elif i0 in search.risen:
            below = (
                f"below {lo:g} Hz the first CMIF curve is not yet on its mass line: it rises "
                f"to its maximum at {f[search.risen[i0]]:g} Hz (the suspension modes) and "
                f"comes back within {search.mass_line_flatness:g} of its level above"
            )
        else:
            below = (
                f"below {lo:g} Hz the per-line estimates drift off the plateau (suspension / "
                "support effects)"
            )
        peaks = susp_peaks
        if peaks:
            below += (
                f" near the suspension (support) modes at {', '.join(f'{x:g}' for x in peaks)} Hz"
            )
        parts.append(below)
    if i1 < n - 1:
        k = i1 + 1
        if i1 in search.capped:
            above = (
                f"above {hi:g} Hz the band keeps below {search.elastic_clearance:g} of the elastic "
                f"mode at {f[search.capped[i1]]:g} Hz (its part's dynamic mass grows like (f/f_e)²)"
            )
        elif deform:
            above = (
                f"above {hi:g} Hz the first deformation mode at {deform[0]:g} Hz (an elastic "
                "mode: a resonance the rigid-body model does not explain) ends the rigid-body band"
            )
        elif e[k] >= e_thr:
            above = f"above {hi:g} Hz the rigid-body error rises to {e[k]:.3g}"
        elif r[k] >= r_thr:
            above = f"above {hi:g} Hz the DIM residual rises to {r[k]:.3g}"
        else:
            above = f"above {hi:g} Hz the per-line estimates drift off the plateau"
        parts.append(above)
    return "; ".join(parts)


def _unqualified_reason(
    min_lines: int,
    e_thr: float,
    r_thr: float,
    limits: dict[str, float],
    lo: float,
    hi: float,
    *,
    band_e: float,
    band_r: float,
) -> str:
    """Why no band qualifies, with the best band found and its errors."""
    return (
        f"no band qualifies: no run of {min_lines} lines with rigid-body error below "
        f"{e_thr:.3g} and DIM residual below {r_thr:.3g} (absolute limits "
        f"{limits['max_rigid_body_error']:g} and {limits['max_residual']:g}) and flat per-line "
        f"estimates lies below the first elastic mode; best band found {lo:g}–{hi:g} Hz with "
        f"rigid-body error {band_e:.3g} and DIM residual {band_r:.3g}; check the channels, the "
        "support and the span, or give the band by hand (--band)"
    )


def suggest_band(
    frf: FrfData,
    setup: TestSetup,
    *,
    known: Mapping[str, float] | None = None,
    response_weights: NDArray[np.floating] | None = None,
    input_keep: NDArray[np.bool_] | None = None,
    window: int | None = None,
    min_lines: int = MIN_BAND_LINES,
    flat_sigma: float = 4.0,
    flat_floor: float = 2e-3,
    max_rigid_body_error: float = MAX_RIGID_BODY_ERROR,
    max_residual: float = MAX_RESIDUAL,
    mass_line_ratio: float = MASS_LINE_RATIO,
    mass_line_flatness: float = MASS_LINE_FLATNESS,
    rough_sigma: float = ROUGH_SIGMA,
    elastic_clearance: float = ELASTIC_CLEARANCE,
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
        The suggested band must hold at least this many lines (default :data:`MIN_BAND_LINES`).
    flat_sigma, flat_floor : float
        Plateau tolerance per normalised parameter: ``max(flat_sigma · σ, flat_floor)`` with σ the
        line-to-line noise level (robust scale of first differences / √2).
    max_rigid_body_error, max_residual : float
        Absolute limits of a usable line's rigid-body error and DIM residual (dimensionless).
    rough_sigma : float
        A line is rough (unusable) where a normalised estimate leaves the running median by more
        than this many line-to-line noise levels σ (at least :data:`ROUGH_FLOOR`).
    elastic_clearance : float
        The band's top line at most this fraction of the first elastic mode above it
        (:data:`ELASTIC_CLEARANCE`); 1 turns the cap off.
    mass_line_ratio : float
        Lowest usable line above a resonance below the run: the first CMIF curve at most this
        many times its lowest level in the run (:data:`MASS_LINE_RATIO`).
    mass_line_flatness : float
        ``σ₁`` within this fraction of its median over a run is on the mass line; a run starting
        with ``σ₁`` off it, rising to a maximum and coming back, starts above that maximum
        (:data:`MASS_LINE_FLATNESS`); ``inf`` turns the rule off.

    Returns
    -------
    BandSuggestion
        ``qualified = False`` (with the best band found and its errors in ``reason``) when no
        band meets the limits.
    """
    ev = _line_evidence(frf, setup, known, response_weights, input_keep)
    f, sv, e, r = ev.f, ev.sv, ev.e, ev.r
    sig, rough, rough_ok = _roughness(ev.pn, window, rough_sigma)
    e_thr = _threshold(e, max_rigid_body_error)
    r_thr = _threshold(r, max_residual)
    usable = (e < e_thr) & (r < r_thr) & rough_ok
    limits = {
        "rigid_body_error": e_thr,
        "residual": r_thr,
        "max_rigid_body_error": max_rigid_body_error,
        "max_residual": max_residual,
    }
    cpk, unexplained = _unexplained_peaks(sv, e, r, e_thr, r_thr)
    search = _BandSearch(
        f=f,
        pn=ev.pn,
        s1=median_filter_nearest(sv[:, 0], 3),
        cpk=cpk,
        unexplained=unexplained,
        tol=np.maximum(flat_sigma * sig, flat_floor),
        min_lines=min_lines,
        mass_line_ratio=mass_line_ratio,
        elastic_clearance=elastic_clearance,
        mass_line_flatness=mass_line_flatness,
    )
    candidates = search.candidates(usable)
    qualified = bool(candidates)
    if candidates:
        i0, i1 = max(candidates, key=lambda ab: ab[1] - ab[0])
    else:
        i0, i1 = _best_band(e, r, min_lines, max_rigid_body_error, max_residual)
    lo, hi = float(f[i0]), float(f[i1])
    band_e = float(np.max(e[i0 : i1 + 1]))
    band_r = float(np.median(r[i0 : i1 + 1]))
    peaks = search.suspension_peaks_hz(i0)
    deform = tuple(float(f[p]) for p in unexplained if p > i1)
    if qualified:
        reason = _qualified_reason(ev, search, i0, i1, e_thr, r_thr, peaks, deform)
    else:
        reason = _unqualified_reason(
            min_lines, e_thr, r_thr, limits, lo, hi, band_e=band_e, band_r=band_r
        )
    log.info("band suggestion: %s", reason)
    return BandSuggestion(
        band_hz=(lo, hi),
        reason=reason,
        frequencies_hz=f,
        cmif=sv,
        rigid_body_error=e,
        roughness=rough,
        usable=usable,
        suspension_peaks_hz=tuple(peaks),
        deformation_peaks_hz=deform,
        per_line=ev.pl,
        residual=r,
        qualified=qualified,
        band_rigid_body_error=band_e,
        band_residual=band_r,
        limits=limits,
    )
