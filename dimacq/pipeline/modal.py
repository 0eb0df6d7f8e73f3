"""Modal-model correction: the elastic modes identified from the FRFs and taken out of them.

Why
---
Above its first elastic mode a structure no longer moves as one rigid body, and there may be no
flat mass line at all between the suspension and the elastic modes. The DIM's equation holds on
every line for the rigid-body coordinates: with ``U = [u_P; θ]`` the rigid-body motion and ``η``
the (mass-normalised, free-free) elastic coordinates, the structure on its measured supports obeys
(:mod:`dimacq.simulators.lab.forward`; free-free modes carry no momentum)

    s² M U − R(s) = φ_j                                                        (1)

with ``R`` the measured reactions mapped to P and ``φ_j`` the input's unit load, while each
accelerometer reads ``s² (Ψ_RB,i U + ψ_i η)``: the elastic motion enters the DIM only through the
accelerometers. This module fits a modal model to every response/input pair (accelerances and
load-cell reactions), finds which of its modes are elastic, and removes their contribution.

Identification (poles, then residues)
-------------------------------------
*Poles: least-squares complex frequency (LSCF).* One common denominator for every pair,
``H_oj(ω) ≈ N_oj(Ω) / d(Ω)`` with ``Ω = e^{iωΔt}``, ``Δt = 1/(2 f_max)``, ``d`` real of order p,
``N_oj`` complex. Minimising ``Σ |N_oj − H_oj d|²`` over the numerators first leaves the reduced
normal equations ``[Σ_o Re(T_o − S_oᴴ R⁻¹ S_o)] α = 0`` with ``X`` the basis
``X_lk = Ω_l^k``, ``R = XᴴX``, ``S_o = −Xᴴ diag(H_o) X``, ``T_o = Xᴴ diag(|H_o|²) X``; with
``α_p = 1`` it is one small linear solve per order. The pairs enter through their principal
components (each pair scaled by its RMS, the leading left singular vectors of the stacked
pairs × lines matrix): the same poles, a few "virtual" FRFs, and each of the hundreds of pairs
still weighs in. Poles ``λ = ln z / Δt`` of the roots ``z`` of ``d``; the stabilisation over the
orders keeps a pole seen (within 1 % in frequency or one line, and a damping ratio within a
factor 1.5 or 0.005) in at least half of the orders, damping 0 < ζ < 0.2.

*Residues: least squares frequency domain (LSFD).* With the poles fixed every pair is linear in
its residues. Accelerometer pairs (acceleration = s² × displacement, ``s = iω``) and reactions
(force = (k + s c) × displacement: a pole term and a constant) are fitted as

    H_acc(s) = Σ_r s² [A_r/(s − λ_r) + A_r*/(s − λ_r*)] + Σ_k c_k (s/ω_ref)^k
    H_rea(s) = Σ_r    [B_r/(s − λ_r) + B_r*/(s − λ_r*)] + Σ_k c_k (s/ω_ref)^k

``k ∈ {−4 … 2}``, real ``c_k``: the negative powers stand for modes below the span (the
suspension's tails), ``k = 0`` the mass line, ``k = 1, 2`` the residual of modes above the span
(a mode at ``λ`` far above contributes ``s² (−A/λ − A*/λ*)`` to an accelerance). One real
least-squares solve for all pairs of a kind (a shared basis, one right-hand side per pair).

Which modes are elastic
-----------------------
A mode's accelerometer residues ``A_r`` (channels × inputs) are its shape times its participation.
A suspension mode moves the body rigidly: ``A_r`` lies in the column space of the rigid-body matrix
``Ψ_RB``. An elastic mode does not: its rigid-body error ``‖A_r − Ψ Ψ⁺ A_r‖ / ‖A_r‖`` is large. A
mode is elastic when that error exceeds :data:`ELASTIC_SHAPE_ERROR`; only elastic modes are taken out.

The correction (why the reactions keep their static share)
----------------------------------------------------------
For a mode r of the structure on its supports, ``z_r`` its mass-normalised shape ``[U_r; η_r]``
(the support springs couple it: ``U_r ≠ 0``), the contributions ``s² M U^(r)`` and ``R^(r)`` of the
mode to (1) differ by a constant: ``s² M U^(r) − R^(r) = M U_r z_rᵀ q_j = −R^(r)(0)`` (the mode's
equation ``(K − ω_r² M) z_r = 0``, rigid-body rows; exact undamped, to the damping's order
otherwise). So the corrected data

    H_acc,c = H_acc − Σ_elastic a^(r)(s) − c_2 (s/ω_ref)²
    H_rea,c = H_rea − Σ_elastic [R^(r)(s) − R^(r)(0)] − c_1 (s/ω_ref) − c_2 (s/ω_ref)²

satisfy (1) with the rigid-body motion alone: ``R^(r)(s) − R^(r)(0) = B_r [1/(s − λ_r) + 1/λ_r]
+ c.c.``. Subtracting the whole reaction term, as a textbook subtraction would, leaves a constant
force error ``M U_r z_rᵀ q_j`` that grows as the elastic modes near the suspension modes
(``U_r ~ (ω_susp/ω_r)²``), exactly the case this is for. Modes above the span: their residual
terms, expanded the same way (``s²`` for an accelerance, ``s`` and ``s²`` for a reaction).

That subtraction (``ModalFit.correction``) still leaves the elastic deformation the support
forces cause below the modes (the suspension modes carry it): 0.4 % mass, 10 mm CG with hull
modes at 17 Hz over 4.8 Hz suspension. :func:`elastic_shapes` and :func:`project_out` remove any
elastic motion in the span of the identified shapes, whatever drives it: each mode's shape is its
accelerometer residue less its rigid share ``U_r = M⁻¹ W_r / λ_r²`` (the mode's reaction residues
at P), and the accelerances are split per line into ``Ψ K + C η``; the reactions stay as
measured. :func:`dimacq.services.solve.modal_correction.corrected` does this (M from a first solve).

Where the FRFs support a fit (the range, then where the fit holds)
------------------------------------------------------------------
An acquired span runs past what the test excites: above the hammer's spectrum the force is at its
noise floor and the FRF is noise (the anti-alias filter's roll-off, the response noise over a
vanishing force); below the suspension the same. The fit uses only the lines the data support,
judged from the FRFs themselves (a UFF file carries no coherence; :func:`frf_noise`): with
``H_l = G_l + e_l``, ``e`` white over the lines with a slowly varying variance ``σ_l²``, the second
difference ``Δ²H_l = H_{l+1} − 2 H_l + H_{l−1}`` has ``E|Δ²e_l|² = 6 σ_l²`` while ``Δ²G_l ≈ G''Δf²``
is small wherever ``G`` is smooth on the line scale; the RMS over the accelerometer pairs relative
to that of ``H`` on the line, and a running median over :data:`NOISE_WINDOW` lines (which rejects
the few lines of a resonance, where ``Δ²G`` is not small), give the relative random error
``ε_l``. The span's noisy top is dropped: the fit range ends at the last line whose ``ε_l`` is
within :data:`NOISE_RATIO` of the cleanest lines' (the least ``ε_l``, itself a median; 20 dB,
the usual limit of a hammer's force-spectrum drop over the band of interest) or below
:data:`NOISE_FLOOR`. The LSCF orders are capped at an eighth of its lines.
After the fit, the relative LSFD residual of the accelerances per line ``r_l`` (running median
over 9 lines) is compared with ``ε_l`` and with its own median over the fitted lines ``r̃``: the
fit holds where ``r_l ≤`` :data:`FIT_HOLDS` ``· max(ε_l, r̃)`` — the model explains the line
to within its noise, or no worse than it explains the span (a mode just above the span, which
only the residual terms follow, raises ``r`` everywhere; what is left out are the lines where
the model fails locally: an unmodelled mode, the noisy top) — and the corrected FRFs are given
to the DIM only over the longest run of such lines (``ModalFit.band_range_hz``); the DIM's own
band selection then keeps the lines where the corrected accelerances move rigidly.

Uncertainty of the fit
----------------------
Per pair the LSFD residual gives ``σ²`` and the coefficients' covariance ``σ² (BᵀB)⁻¹``;
:func:`residue_draws` draws residues from it (the poles held) for a Monte Carlo through the
projection and the DIM solve.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from dimacq.errors import DataError

__all__ = [
    "ELASTIC_SHAPE_ERROR",
    "ModalFit",
    "Pole",
    "elastic_shapes",
    "fit_modal_model",
    "frf_noise",
    "lscf_poles",
    "project_out",
    "residue_draws",
]

FloatArray = NDArray[np.float64]
ComplexArray = NDArray[np.complex128]

#: Smallest rigid-body error of a mode's accelerometer residues for it to count as elastic.
ELASTIC_SHAPE_ERROR = 0.25
#: Smallest signal-to-noise ratio of a mode's accelerometer residues (their norm over the root sum
#: of their LSFD standard errors) for it to be taken out: a pole fitted to noise has random
#: residues, whose shape is not rigid either.
MIN_SNR = 10.0
#: Powers of ``s / ω_ref`` of the residual terms (below and above the span).
RESIDUAL_POWERS = (-4, -3, -2, -1, 0, 1, 2)
#: The residues are fitted above this multiple of the highest rigid-body (suspension) pole.
CLEARANCE = 1.2
#: Poles above this fraction of the top line are left out: LSCF puts spurious poles at the edge
#: of its span (a real mode there is followed by the residual term of the modes above the span).
EDGE = 0.97
#: Largest damping ratio of a physical pole.
MAX_DAMPING = 0.2
#: Lines of the running median of the FRF noise estimate (:func:`frf_noise`).
NOISE_WINDOW = 33
#: The fit range ends where the FRFs' relative noise exceeds this multiple of the cleanest lines'
#: (20 dB: a hammer's force spectrum that far below its plateau no longer drives the test).
NOISE_RATIO = 10.0
#: Relative noise (and LSFD residual) per line below which a line counts as clean whatever the
#: ratio: 0.1 % of the FRF, far below what moves the DIM (noise-free model FRFs are kept whole).
NOISE_FLOOR = 1e-3
#: The fit holds on a line whose relative LSFD residual is at most this multiple of its noise
#: (:func:`frf_noise`) or of the fit's median residual over the fitted lines, whichever is larger.
FIT_HOLDS = 3.0


@dataclass(frozen=True)
class Pole:
    """A pole ``λ = −ζ ω_n + i ω_n √(1 − ζ²)``: frequency (Hz), damping ratio, and whether the
    mode is elastic (taken out) with the rigid-body error of its shape."""

    frequency_hz: float
    damping_ratio: float
    elastic: bool = False
    shape_rigid_error: float = float("nan")
    stability: float = 1.0
    snr: float = float("nan")

    @property
    def lam(self) -> complex:
        wn = 2 * np.pi * self.frequency_hz
        z = self.damping_ratio
        return complex(-z * wn, wn * np.sqrt(max(1 - z * z, 0.0)))

    def to_json(self) -> dict[str, Any]:
        return {
            "frequency_hz": self.frequency_hz,
            "damping_ratio": self.damping_ratio,
            "elastic": self.elastic,
            "shape_rigid_body_error": self.shape_rigid_error,
            "stability": self.stability,
            "residue_snr": self.snr,
        }


def _pole_of(lam: complex) -> tuple[float, float]:
    wn = abs(lam)
    return wn / (2 * np.pi), -lam.real / wn


def frf_noise(H: ComplexArray, window: int = NOISE_WINDOW) -> FloatArray:
    """Relative random error per line of FRFs, from the FRFs alone (module docstring).

    Parameters
    ----------
    H : ndarray, shape (n_lines, n_pairs)
    window : int
        Lines of the running median.

    Returns
    -------
    ndarray, shape (n_lines,)
        ``ε_l = median_window( RMS_pairs(Δ²H_l) / √6 / RMS_pairs(H_l) )``, the end lines taking
        their neighbour's second difference (:func:`dimacq.pipeline.line_noise.line_sigma`).
    """
    from dimacq.pipeline._filters import median_filter_nearest
    from dimacq.pipeline.line_noise import line_sigma

    H = np.asarray(H, complex).reshape(H.shape[0], -1)
    if H.shape[0] < 3:
        return np.full(H.shape[0], np.inf)
    d2 = line_sigma(H, 2)
    mag = np.sqrt(np.mean(np.abs(H) ** 2, axis=1))
    rel = d2 / np.where(mag > 0, mag, np.inf)
    rel[mag == 0] = np.inf
    return median_filter_nearest(rel, min(window, H.shape[0]))


def clean_span(noise: FloatArray) -> tuple[int, int, float]:
    """First and last line (inclusive) of the span the fit uses, and the noise limit: up to the
    last line whose noise is within :data:`NOISE_RATIO` of the cleanest lines' or below
    :data:`NOISE_FLOOR`. The span's bottom stays: the LSCF needs the suspension poles, whose
    closely spaced peaks raise the estimate there, and the residues are fitted above them."""
    finite = noise[np.isfinite(noise)]
    if finite.size == 0:
        raise DataError("the FRFs are zero or not finite on every line; nothing to fit")
    limit = max(NOISE_RATIO * float(np.min(finite)), NOISE_FLOOR)
    ok = np.nonzero(noise <= limit)[0]
    return 0, int(ok[-1]), limit


def _longest_run(mask: NDArray[np.bool_]) -> tuple[int, int]:
    """First and last index (inclusive) of the longest run of True (-1, -1: none)."""
    d = np.diff(np.concatenate([[0], mask.astype(np.int8), [0]]))
    starts, ends = np.nonzero(d == 1)[0], np.nonzero(d == -1)[0]
    if starts.size == 0:
        return -1, -1
    k = int(np.argmax(ends - starts))
    return int(starts[k]), int(ends[k] - 1)


def lscf_poles(
    frequencies_hz: FloatArray,
    H: ComplexArray,
    *,
    orders: tuple[int, ...] | None = None,
    n_components: int = 16,
    band_hz: tuple[float, float] | None = None,
) -> list[Pole]:
    """Stable poles of FRFs by LSCF with a stabilisation over model orders (module docstring).

    Parameters
    ----------
    frequencies_hz : ndarray, shape (n_lines,)
    H : ndarray, shape (n_lines, n_pairs)
        Every pair's FRF (any units: each pair is scaled by its RMS).
    orders : tuple of int, optional
        Denominator orders tried (default 16, 20, … 48).
    band_hz : (lo, hi), optional
        Keep poles in this range (default: the span, less its top 3 %, :data:`EDGE`).

    Returns
    -------
    list of Pole, ascending in frequency
    """
    f = np.asarray(frequencies_hz, float)
    Hp = np.asarray(H, complex).reshape(f.size, -1)
    if f.size < 16:
        raise DataError(f"{f.size} lines are too few for a modal fit; give at least 16 lines")
    rms = np.sqrt(np.mean(np.abs(Hp) ** 2, axis=0))
    ok = rms > 0
    Hn = Hp[:, ok] / rms[ok]
    # principal components over the lines: eigenvectors of the (n_lines × n_lines) Gram matrix
    ev, u = np.linalg.eigh(Hn @ Hn.conj().T)
    ev, u = ev[::-1], u[:, ::-1]
    sv = np.sqrt(np.clip(ev, 0, None))
    k = int(min(n_components, np.sum(sv > sv[0] * 1e-6)))
    Hc = u[:, :k] * sv[:k]  # (n_lines, k) principal FRFs
    dt = 1.0 / (2.0 * f[-1] * 1.05)
    omega = 2 * np.pi * f
    orders = orders or tuple(range(16, 50, 4))
    lo, hi = band_hz or (f[0], f[-1])
    found: list[list[tuple[float, float]]] = []
    # S_o = −Xᴴ diag(H_o) X for every component at once, at the top order: X of order p is the
    # top order's first p + 1 columns, so its S_o is the leading (p + 1) × (p + 1) block
    top = max(orders)
    X_top = np.exp(1j * omega[:, None] * dt * np.arange(top + 1)[None, :])
    S_top = -np.einsum("lk,lo,lm->okm", X_top.conj(), Hc, X_top, optimize=True)
    for p in orders:
        X = np.exp(1j * omega[:, None] * dt * np.arange(p + 1)[None, :])  # (n_lines, p+1)
        R = X.conj().T @ X
        S = np.ascontiguousarray(S_top[:, : p + 1, : p + 1])
        # and T_o = Xᴴ diag(|H_o|²) X
        T = np.einsum("lk,lo,lm->km", X.conj(), np.abs(Hc) ** 2, X, optimize=True)
        Rinv_S = np.linalg.solve(R[None], S)
        Mm = np.real(T - np.einsum("okj,okm->jm", S.conj(), Rinv_S))
        alpha = np.linalg.solve(Mm[:p, :p], -Mm[:p, p])
        z = np.roots(np.concatenate([[1.0], alpha[::-1]]))
        z = z[np.abs(z) > 0]
        lam = np.log(z.astype(complex)) / dt
        lam = lam[lam.imag > 0]
        poles = [_pole_of(complex(v)) for v in lam]
        found.append(
            [(fr, ze) for fr, ze in poles if 0 < ze < MAX_DAMPING and lo <= fr <= hi * EDGE]
        )
    return _stable(found, len(orders), float(np.median(np.diff(f))))


def _stable(
    found: list[list[tuple[float, float]]], n_orders: int, line_hz: float = 0.0
) -> list[Pole]:
    """Cluster the poles of every order (1 % in frequency or one line, whichever is wider: a
    pole a few lines above 0 Hz is not located better than a line; damping within a factor 1.5
    or 0.005) and keep the clusters seen in at least half of the orders (their medians)."""
    allp = sorted((fr, ze, i) for i, ps in enumerate(found) for fr, ze in ps)
    # per cluster: its frequencies, damping ratios, orders, and their medians (kept current)
    clusters: list[tuple[list[float], list[float], set[int], list[float]]] = []
    for fr, ze, i in allp:
        best = None
        for c in clusters:
            fm, zm = c[3]
            if abs(fr - fm) <= max(0.01 * fm, line_hz) and abs(ze - zm) <= max(0.5 * zm, 0.005):
                if i not in c[2]:
                    best = c
                    break
        if best is None:
            clusters.append(([fr], [ze], {i}, [fr, ze]))
        else:
            best[0].append(fr)
            best[1].append(ze)
            best[2].add(i)
            best[3][:] = [float(np.median(best[0])), float(np.median(best[1]))]
    out = [
        Pole(c[3][0], c[3][1], stability=len(c[2]) / n_orders)
        for c in clusters
        if len(c[2]) >= 0.5 * n_orders
    ]
    return sorted(out, key=lambda p: p.frequency_hz)


@dataclass(frozen=True, eq=False)
class ModalFit:
    """A fitted modal model of every pair and the correction it gives.

    Attributes
    ----------
    poles : list of Pole
        Every stable pole (``elastic`` marks the ones taken out).
    frequencies_hz : ndarray, shape (n_lines,)
    correction : ndarray, shape (n_lines, n_outputs, n_inputs), complex
        What is subtracted from each FRF (zero for modes left in).
    coef_cov_chol : ndarray, shape (n_basis, n_basis) per kind
        Cholesky factor of ``(BᵀB)⁻¹`` of each kind's basis (acceleration, reaction).
    sigma : ndarray, shape (n_outputs, n_inputs)
        Per pair, the LSFD residual's standard deviation (real and imaginary parts).
    fit_error : float
        RMS of the LSFD residual over every pair, relative to each pair's RMS.
    fit_range_hz : (lo, hi)
        The lines fitted: above the suspension, within the FRFs' clean span.
    band_range_hz : (lo, hi)
        Where the fit holds (``r_l ≤ FIT_HOLDS · max(ε_l, median r)``, the longest run): the
        corrected FRFs' lines.
    noise_rel, residual_rel : ndarray, shape (n_lines,)
        ``ε_l`` of the accelerances (:func:`frf_noise`) and the LSFD residual per line relative to
        ``H`` (running median; NaN off the fitted lines).
    clean_span_hz : (lo, hi)
        The span whose noise is within the limit (:func:`clean_span`), and ``noise_limit``.
    """

    poles: list[Pole]
    frequencies_hz: FloatArray
    correction: ComplexArray
    sub_basis: dict[str, ComplexArray]
    coef_cov_chol: dict[str, FloatArray]
    sigma: FloatArray
    kind_index: dict[str, NDArray[np.intp]]
    fit_error: float
    fit_range_hz: tuple[float, float]
    residues: ComplexArray
    upper_acc: ComplexArray
    band_range_hz: tuple[float, float] = (0.0, 0.0)
    noise_rel: FloatArray | None = None
    residual_rel: FloatArray | None = None
    clean_span_hz: tuple[float, float] = (0.0, 0.0)
    noise_limit: float = float("nan")
    top_line: int = -1

    def quality(self) -> dict[str, Any]:
        """The fit's quality check, for the report: the clean span, where the fit holds, and the
        residual against the noise on the fitted lines."""
        out: dict[str, Any] = {
            "clean_span_hz": list(self.clean_span_hz),
            "noise_limit_rel": self.noise_limit,
            "fit_range_hz": list(self.fit_range_hz),
            "holds_range_hz": list(self.band_range_hz),
            "holds_limit": FIT_HOLDS,
        }
        if self.noise_rel is not None and self.residual_rel is not None:
            f = self.frequencies_hz
            lo, hi = self.fit_range_hz
            sel = (f >= lo) & (f <= hi) & np.isfinite(self.residual_rel)
            r = self.residual_rel[sel]
            ratio = r / np.maximum(self.noise_rel[sel], np.median(r)) if r.size else r
            out.update(
                {
                    "lines_fitted": int(sel.sum()),
                    "lines_held": int(np.sum(ratio <= FIT_HOLDS)),
                    "residual_median_rel": float(np.median(r)) if r.size else None,
                    "residual_to_limit_max": float(np.max(ratio)) / FIT_HOLDS if r.size else None,
                }
            )
        return out

    @property
    def elastic_poles(self) -> list[Pole]:
        return [p for p in self.poles if p.elastic]

    def size_per_line(self, H: ComplexArray, rows: NDArray[np.intp]) -> FloatArray:
        """‖correction‖ / ‖H‖ per line over the given output rows (all inputs)."""
        c = self.correction[:, rows]
        h = np.asarray(H)[:, rows]
        den = np.sqrt(np.sum(np.abs(h) ** 2, axis=(1, 2)))
        return np.asarray(
            np.sqrt(np.sum(np.abs(c) ** 2, axis=(1, 2))) / np.where(den > 0, den, 1.0)
        )


def _basis(
    s: ComplexArray, poles: list[Pole], weight: ComplexArray, omega_ref: float
) -> tuple[ComplexArray, ComplexArray, ComplexArray]:
    """Complex basis columns (n_lines, n_basis) of the LSFD model, and the columns subtracted
    for accelerometers and for reactions (same shape; zero where a column is not subtracted)."""
    cols, sub_acc, sub_rea = [], [], []
    for p in poles:
        lam = p.lam
        g1 = weight * (1 / (s - lam) + 1 / (s - np.conj(lam)))
        g2 = weight * (1j / (s - lam) - 1j / (s - np.conj(lam)))
        # reactions: the term minus its static value (module docstring)
        r1 = g1 - (-1 / lam - 1 / np.conj(lam))
        r2 = g2 - (-1j / lam + 1j / np.conj(lam))
        cols += [g1, g2]
        el = 1.0 if p.elastic else 0.0
        sub_acc += [el * g1, el * g2]
        sub_rea += [el * r1, el * r2]
    for k in RESIDUAL_POWERS:
        v = (s / omega_ref) ** k
        cols.append(v)
        sub_acc.append(v if k == 2 else 0 * v)
        sub_rea.append(v if k in (1, 2) else 0 * v)
    return np.stack(cols, 1), np.stack(sub_acc, 1), np.stack(sub_rea, 1)


def _lsfd(
    B: ComplexArray, Y: ComplexArray
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """Real least squares of complex data: coefficients (n_basis, n_pairs), residual σ per pair,
    Cholesky factor of (BᵀB)⁻¹ and the relative RMS residual per pair."""
    Br = np.concatenate([B.real, B.imag], 0)
    Yr = np.concatenate([Y.real, Y.imag], 0)
    scale = np.sqrt(np.sum(Br**2, axis=0))
    scale[scale == 0] = 1.0
    Bs = Br / scale
    coef, *_ = np.linalg.lstsq(Bs, Yr, rcond=1e-10)
    resid = Yr - Bs @ coef
    dof = max(Br.shape[0] - Br.shape[1], 1)
    sigma = np.sqrt(np.sum(resid**2, axis=0) / dof)
    G = np.linalg.pinv(Bs.T @ Bs, rcond=1e-12, hermitian=True)
    w, v = np.linalg.eigh(G)
    chol = (v * np.sqrt(np.clip(w, 0, None))) / scale[:, None]
    rms = np.sqrt(np.mean(Yr**2, axis=0))
    rel = np.sqrt(np.mean(resid**2, axis=0)) / np.where(rms > 0, rms, 1.0)
    return coef / scale[:, None], sigma, chol, rel


def fit_modal_model(
    frequencies_hz: FloatArray,
    H: ComplexArray,
    kinds: tuple[str, ...],
    rigid_basis: FloatArray,
    *,
    poles: list[Pole] | None = None,
    elastic_shape_error: float = ELASTIC_SHAPE_ERROR,
) -> ModalFit:
    """Fit poles and residues of every pair and build the elastic-mode correction.

    Parameters
    ----------
    frequencies_hz : ndarray, shape (n_lines,)
    H : ndarray, shape (n_lines, n_outputs, n_inputs)
        Accelerances ((m/s²)/N) and reactions (N/N, N·m/N).
    kinds : tuple of {"acceleration", "reaction"}, length n_outputs
    rigid_basis : ndarray, shape (n_acc, 6)
        ``Ψ_RB`` of the accelerometer outputs (in their order among the outputs): rows
        ``[dᵀ, (r × d)ᵀ]`` with r relative to any point (the column space is what matters).
    poles : list of Pole, optional
        Poles to use (default: :func:`lscf_poles` on every pair).

    Returns
    -------
    ModalFit
    """
    f = np.asarray(frequencies_hz, float)
    H = np.asarray(H, complex)
    n_l, _, n_i = H.shape
    kind_index = {
        k: np.array([i for i, x in enumerate(kinds) if x == k], dtype=np.intp)
        for k in ("acceleration", "reaction")
    }
    acc = kind_index["acceleration"]
    if acc.size == 0:
        raise DataError("a modal correction needs accelerometer outputs; the FRFs have none")
    # the span the FRFs support: the noisy top (above the hammer's
    # spectrum) are left out of every step of the fit (module docstring)
    H_acc = H[:, acc].reshape(n_l, -1)
    noise = frf_noise(H_acc)
    i0, i1, noise_limit = clean_span(noise)
    span = np.zeros(n_l, bool)
    span[i0 : i1 + 1] = True
    n_span = int(span.sum())
    top_order = min(48, n_span // 8)
    if top_order < 16:
        raise DataError(
            f"the FRFs are clean (relative noise ≤ {100 * noise_limit:.2g} %) on only {n_span} "
            f"lines ({f[i0]:.4g}–{f[i1]:.4g} Hz); a modal fit needs at least 128: measure with a "
            "finer resolution, more averages or a hammer tip that excites the band"
        )
    if poles is None:
        poles = lscf_poles(
            f[span], H[span].reshape(n_span, -1), orders=tuple(range(16, top_order + 1, 4))
        )
    s = 2j * np.pi * f
    omega_ref = 2 * np.pi * f[i1]
    # the basis columns do not depend on which poles are elastic: one per kind serves every step
    weights = {"acceleration": s**2, "reaction": np.ones_like(s)}
    B_acc = _basis(s, poles, weights["acceleration"], omega_ref)[0]
    coef_a0, *_ = _lsfd(B_acc[span], H_acc[span])
    classified = _by_shape(coef_a0, poles, rigid_basis, n_i, elastic_shape_error)
    f_lo, fit_lines = _fit_lines(f, classified, span, i0, i1, noise_limit)
    fits = {}
    for kind, idx in kind_index.items():
        if idx.size == 0:
            continue
        B = B_acc if kind == "acceleration" else _basis(s, poles, weights[kind], omega_ref)[0]
        fits[kind] = _lsfd(B[fit_lines], H[fit_lines][:, idx].reshape(-1, idx.size * n_i))
    coef_a = fits["acceleration"][0]
    classified = _by_snr(classified, fits["acceleration"], elastic_shape_error)
    parts = _corrections(fits, kind_index, classified, s, weights, omega_ref, H.shape)
    resid_rel, band = _where_fit_holds(f, H_acc, B_acc, coef_a, fit_lines, noise)
    if band is None:
        raise DataError(
            f"the modal fit over {f_lo:.3g}–{f[i1]:.4g} Hz holds (LSFD residual ≤ {FIT_HOLDS:g}× "
            "the FRFs' noise or the fit's median residual) on too few consecutive lines for a DIM band: the FRFs do not "
            "support a modal model there (modes missed, a nonlinear or noisy response)"
        )
    return ModalFit(
        poles=classified,
        frequencies_hz=f,
        kind_index=kind_index,
        fit_error=float(np.sqrt(np.mean(np.concatenate([fit[3] for fit in fits.values()]) ** 2))),
        fit_range_hz=(float(f_lo), float(f[i1])),
        band_range_hz=band,
        noise_rel=noise,
        residual_rel=resid_rel,
        clean_span_hz=(float(f[i0]), float(f[i1])),
        noise_limit=noise_limit,
        top_line=i1,
        **parts,
    )


def _by_shape(
    coef: FloatArray,
    poles: list[Pole],
    rigid_basis: FloatArray,
    n_i: int,
    elastic_shape_error: float,
) -> list[Pole]:
    """Each pole with the rigid-body error of its accelerometer residues
    ``‖A_r − Ψ Ψ⁺ A_r‖ / ‖A_r‖`` (``coef``: the LSFD coefficients of the accelerances) and
    marked elastic when that exceeds ``elastic_shape_error`` (the signal to noise is checked
    later, :func:`_by_snr`)."""
    Pq, _ = np.linalg.qr(np.asarray(rigid_basis, float))
    out = []
    for r, p in enumerate(poles):
        A = (coef[2 * r] + 1j * coef[2 * r + 1]).reshape(-1, n_i)
        nrm = np.linalg.norm(A)
        err = float(np.linalg.norm(A - Pq @ (Pq.T @ A)) / nrm) if nrm > 0 else 0.0
        out.append(
            Pole(p.frequency_hz, p.damping_ratio, err > elastic_shape_error, err, p.stability)
        )
    return out


def _fit_lines(
    f: FloatArray,
    poles: list[Pole],
    span: NDArray[np.bool_],
    i0: int,
    i1: int,
    noise_limit: float,
) -> tuple[float, NDArray[np.bool_]]:
    """The lowest line of the residue fit and the lines fitted: above :data:`CLEARANCE` times
    the highest suspension (rigid-body) pole below the first elastic one, within the clean
    span. Their closely spaced peaks are what the lower residual terms cannot follow, and the
    DIM band lies above them anyway."""
    el_f = [p.frequency_hz for p in poles if p.elastic]
    first_el = min(el_f) if el_f else float(f[-1])
    rigid_f = [p.frequency_hz for p in poles if not p.elastic and p.frequency_hz < first_el]
    f_lo = CLEARANCE * max(rigid_f) if rigid_f else 0.5 * first_el
    f_lo = max(f_lo, float(f[i0]))
    fit_lines = (f >= f_lo) & span
    if fit_lines.sum() < 4 * (2 * len(poles) + len(RESIDUAL_POWERS)):
        raise DataError(
            f"{int(fit_lines.sum())} clean lines between {f_lo:.3g} Hz (clear of the suspension "
            f"modes) and {f[i1]:.4g} Hz (where the FRFs' noise exceeds "
            f"{100 * noise_limit:.2g} %) are too few for the modal fit; measure a wider span, a "
            "finer resolution or with a hammer tip that excites higher"
        )
    return f_lo, fit_lines


def _by_snr(
    poles: list[Pole],
    fit: tuple[FloatArray, FloatArray, FloatArray, FloatArray],
    elastic_shape_error: float,
) -> list[Pole]:
    """Each pole with the signal to noise of its accelerometer residues on the fitted lines
    (``‖A_r‖`` over the root sum of their LSFD variances, ``fit`` the accelerances'
    :func:`_lsfd`): elastic when its shape is not rigid and that exceeds :data:`MIN_SNR`."""
    coef, sig, chol, _ = fit
    out = []
    for r, p in enumerate(poles):
        A = coef[2 * r] + 1j * coef[2 * r + 1]
        se2 = (np.sum(chol[2 * r] ** 2) + np.sum(chol[2 * r + 1] ** 2)) * np.sum(sig**2)
        snr = float(np.linalg.norm(A) / np.sqrt(se2)) if se2 > 0 else float("inf")
        elastic = p.shape_rigid_error > elastic_shape_error and snr > MIN_SNR
        out.append(replace(p, elastic=elastic, snr=snr))
    return out


def _corrections(
    fits: dict[str, tuple[FloatArray, FloatArray, FloatArray, FloatArray]],
    kind_index: dict[str, NDArray[np.intp]],
    poles: list[Pole],
    s: ComplexArray,
    weights: dict[str, ComplexArray],
    omega_ref: float,
    shape: tuple[int, int, int],
) -> dict[str, Any]:
    """The fit's per-kind results as :class:`ModalFit` fields: the correction (the elastic
    terms and the residual terms subtracted, module docstring), the residues, the ``s²``
    residual term of the accelerances, σ per pair, the subtracted columns and the coefficients'
    covariance factors."""
    n_l, n_o, n_i = shape
    nr = len(poles)
    correction = np.zeros(shape, complex)
    residues = np.zeros((nr, n_o, n_i), complex)
    upper_acc = np.zeros(shape, complex)
    sigma = np.zeros((n_o, n_i))
    sub_basis: dict[str, ComplexArray] = {}
    chols: dict[str, FloatArray] = {}
    for kind, (coef, sig, chol, _) in fits.items():
        idx = kind_index[kind]
        _, sub_a, sub_r = _basis(s, poles, weights[kind], omega_ref)
        sub = sub_a if kind == "acceleration" else sub_r
        correction[:, idx] = (sub @ coef).reshape(n_l, idx.size, n_i)
        residues[:, idx] = (coef[0 : 2 * nr : 2] + 1j * coef[1 : 2 * nr : 2]).reshape(
            nr, idx.size, n_i
        )
        if kind == "acceleration":
            top = (s / omega_ref) ** 2
            upper_acc[:, idx] = (top[:, None] * coef[-1][None, :]).reshape(n_l, idx.size, n_i)
        sigma[idx] = sig.reshape(idx.size, n_i)
        sub_basis[kind] = sub
        chols[kind] = chol
    return {
        "correction": correction,
        "residues": residues,
        "upper_acc": upper_acc,
        "sigma": sigma,
        "sub_basis": sub_basis,
        "coef_cov_chol": chols,
    }


def _where_fit_holds(
    f: FloatArray,
    H_acc: ComplexArray,
    B: ComplexArray,
    coef: FloatArray,
    fit_lines: NDArray[np.bool_],
    noise: FloatArray,
) -> tuple[FloatArray, tuple[float, float] | None]:
    """Per line the relative LSFD residual of the accelerances (running median over 9 lines,
    NaN off ``fit_lines``) and the longest run of fitted lines where it is within
    :data:`FIT_HOLDS` of the noise (module docstring); None when that run has fewer than 16
    lines."""
    from dimacq.pipeline._filters import median_filter_nearest

    Y = H_acc[fit_lines]
    r = Y - B[fit_lines] @ coef
    mag = np.sqrt(np.mean(np.abs(Y) ** 2, axis=1))
    rel = np.sqrt(np.mean(np.abs(r) ** 2, axis=1)) / np.where(mag > 0, mag, np.inf)
    rel = median_filter_nearest(rel, min(9, rel.size))
    out = np.full(f.size, np.nan)
    out[fit_lines] = rel
    holds = rel <= FIT_HOLDS * np.maximum(noise[fit_lines], np.median(rel))
    a, b = _longest_run(holds)
    if a < 0 or b - a + 1 < 16:
        return out, None
    ff = f[fit_lines]
    return out, (float(ff[a]), float(ff[b]))


def elastic_shapes(
    residues_acc: ComplexArray, rigid_part: ComplexArray, rigid_basis: FloatArray
) -> ComplexArray:
    """Elastic shape at the accelerometers of each elastic mode, shape (n_acc, n_el).

    ``residues_acc`` (n_el, n_acc, n_inputs) are the modes' displacement residues; ``rigid_part``
    (n_el, 6, n_inputs) the rigid-body motion of P in each residue (from the reactions:
    ``U_r = M⁻¹ W_r / λ_r²``). What is left, ``A_r − Ψ U_r``, is the mode's elastic motion
    times its participation: its leading left singular vector is the shape."""
    el = residues_acc - np.einsum("ck,rkj->rcj", rigid_basis, rigid_part)
    out = []
    for A in el:
        u, _, _ = np.linalg.svd(A, full_matrices=False)
        out.append(u[:, 0])
    return np.stack(out, axis=1) if out else np.zeros((residues_acc.shape[1], 0), complex)


def project_out(
    H_acc: ComplexArray, rigid_basis: FloatArray, shapes: ComplexArray
) -> tuple[ComplexArray, ComplexArray]:
    """Per line and input, the accelerances' least-squares split ``a = Ψ K + C η`` over the
    rigid-body shapes and the elastic shapes: returns ``a − C η`` and ``C η``.

    Exact for any elastic motion within the span of ``C`` whatever drives it (the input or the
    measured reactions), with no model of ``η``'s frequency dependence.
    """
    B = np.concatenate([np.asarray(rigid_basis, complex), shapes], axis=1)
    pinv = np.linalg.pinv(B)[6:]  # rows giving η
    eta = pinv @ H_acc  # (n_lines, n_el, n_inputs), one matrix product per line
    corr = shapes @ eta
    return H_acc - corr, corr


def residue_draws(fit: ModalFit, n_draws: int, seed: int = 0) -> tuple[ComplexArray, ComplexArray]:
    """Accelerometer residues and the residual term drawn from the LSFD coefficients'
    covariance ``σ² (BᵀB)⁻¹`` per pair (poles held): shapes (n_draws, n_modes, n_acc, n_inputs)
    and (n_draws, n_acc, n_inputs) (the ``s²`` term at the fit's top line, as ``upper_acc[top_line]``)."""
    rng = np.random.default_rng(seed)
    idx = fit.kind_index["acceleration"]
    chol = fit.coef_cov_chol["acceleration"]
    n_i = fit.sigma.shape[1]
    sig = fit.sigma[idx].reshape(-1)
    z = rng.standard_normal((n_draws, chol.shape[1], sig.size))
    dcoef = np.einsum("bk,dkp->dbp", chol, z) * sig  # (n_draws, n_basis, n_pairs)
    nr = len(fit.poles)
    dres = (dcoef[:, 0 : 2 * nr : 2] + 1j * dcoef[:, 1 : 2 * nr : 2]).reshape(
        n_draws, nr, idx.size, n_i
    )
    res = fit.residues[:, idx][None] + dres
    up = fit.upper_acc[fit.top_line][idx][None] - dcoef[:, -1].reshape(n_draws, idx.size, n_i)
    return res, up
