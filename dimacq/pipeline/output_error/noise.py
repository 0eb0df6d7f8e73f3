"""The noise model of the output-error fit, estimated from the measurement.

Holds the FRF noise from the line-to-line scatter (:func:`estimate_noise`), the reactions' noise
covariance (:func:`reaction_noise_cov`), the per-line weights of the line's own noise and of the
load cells' calibration (:func:`line_weights`, its equations in its docstring) and the smooth
projection of the reactions that cuts their noise where it holds (:func:`smooth_reactions`).

Noise model (errors in variables)
---------------------------------
Independent circular complex noise per output, input and line. ``σ_cj`` is estimated from the data by
the line-to-line scatter (:mod:`dimacq.pipeline.line_noise`, order 3): the third difference along
the lines ``Δ³H = H_ℓ − 3H_ℓ₊₁ + 3H_ℓ₊₂ − H_ℓ₊₃`` removes a smooth FRF (the mass line) and has
variance ``20 σ²`` for white noise; a robust (median) estimate ``σ² = median|Δ³H|² / (20 ln 2)``.
The reactions ``R_j`` are regressors with noise:
``E[S_RR] = S_RR⁰ + n_ω Σ_R``, so ``n_ω Σ_R`` (``Σ_R`` from the third difference of ``R_j``) is
subtracted before the fit (bias compensation). Noise on ``H`` sits on the compared quantity and does
not bias the estimate. The reduced ``χ²`` at the solution checks the noise model; the covariance
is scaled by ``max(1, χ²_red)``.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from dimacq.errors import SetupError
from dimacq.pipeline._filters import median_along, uniform_filter_nearest
from dimacq.pipeline.line_noise import (
    difference_gain,
    line_difference,
    scatter_sigma,
    scatter_variance,
)

FloatArray = NDArray[np.float64]
ComplexArray = NDArray[np.complex128]


# ------------------------------------------------------------------------------------------
# Noise
# ------------------------------------------------------------------------------------------
def third_difference_power(H: ComplexArray) -> FloatArray:
    """``|Δ³H|²`` along the lines (axis 0): ``|H_ℓ − 3H_ℓ₊₁ + 3H_ℓ₊₂ − H_ℓ₊₃|²``, (L − 3, ...)."""
    return np.asarray(np.abs(line_difference(H, 3)) ** 2, float)


def estimate_noise(H: ComplexArray, *, d3_power: FloatArray | None = None) -> FloatArray:
    """Noise standard deviation of each FRF from the line-to-line scatter (module docstring).

    Parameters
    ----------
    H : ndarray, shape (n_lines, ...), complex
        FRFs along their lines (axis 0), at least 8 lines.
    d3_power : ndarray, optional
        ``|Δ³H|²`` if already formed (:func:`third_difference_power`; the line weights use it
        too).

    Returns
    -------
    ndarray, shape (...)
        ``σ = sqrt(median|Δ³H|² / (20 ln 2))``, same unit as ``H`` (total complex variance σ²).
    """
    H = np.asarray(H)
    if H.shape[0] < 8:
        raise SetupError(
            f"the band holds {H.shape[0]} lines; the noise estimate from line-to-line scatter "
            "needs at least 8: widen the band"
        )
    d3p = third_difference_power(H) if d3_power is None else d3_power
    return scatter_sigma(None, 3, power=d3p)


def reaction_noise_cov(R: ComplexArray) -> FloatArray:
    """``Σ_R`` per input (J, 6, 6): real covariance per line of the noise on the reactions at P
    (``E Re(e eᴴ)`` = total complex covariance), from the third difference of ``R_j``."""
    d3 = line_difference(R, 3)  # (L-3, 6, J)
    gain = difference_gain(3)
    cov = np.real(np.einsum("lij,lkj->jik", d3, d3.conj())) / (float(gain) * d3.shape[0])
    # robust scale: match the diagonal to the median estimate, keep the correlation structure
    med = scatter_variance(np.abs(d3) ** 2, 3).T  # (J, 6)
    diag = np.einsum("jii->ji", cov)
    with np.errstate(divide="ignore", invalid="ignore"):
        s = np.sqrt(np.where(diag > 0, med / diag, 0.0))
    return np.asarray(cov * s[:, :, None] * s[:, None, :], float)


#: Reactions whose power on a line is at most this multiple of their noise are at noise level.
REACTION_SNR_LOW = 4.0

#: Relative precision floor of an FRF value in the line weights (:func:`line_weights`).
PRECISION_FLOOR_REL = 1e-6

#: Half-width (lines) of the local noise estimate of :func:`line_weights`.
LINE_NOISE_HALF_WIDTH = 16


def line_weights(
    H: ComplexArray,
    R: ComplexArray,
    psi: FloatArray,
    phi: FloatArray,
    A: FloatArray,
    eps_r: float,
    *,
    h_power: FloatArray | None = None,
    d3_power: FloatArray | None = None,
) -> FloatArray | None:
    """Per line and input, the weight ``w_ℓj`` of the line's own noise and of the load cells'
    calibration uncertainty (the noise model from the measurement).

    The channel noise ``σ_cj`` (:func:`estimate_noise`) is one level over the band, but a
    measured test is not that simple. Its random noise is not flat (the hammer's spectrum rolls
    off; a leaky estimate smears a support mode), and the reactions are read through the load
    cells' calibration matrices, known to ``ε_R`` (``loadcell_matrix_rel``): an error *relative*
    to the reaction, which the fit does not model (the cells' six outputs mix through the whole
    matrix), so it weighs most where a support carries much of the force, near a support mode,
    where a white-noise weighting lets those few lines run the fit. The variance of line ``ℓ``
    of input ``j``, relative to the band's mean power, is modelled as

        v_ℓj = n_ℓj + (ε_0² + ε_R² ρ_ℓj²) p_ℓj
        n_ℓj = median_c ⟨|Δ³H_cj|²⟩_ℓ / (20 · mean_ℓ|H_cj|²)        (local scatter: random noise)
        p_ℓj = median_c |H_ℓcj|² / mean_ℓ|H_cj|²                    (the line's relative power)
        ρ_ℓj² = Σ_c |ψ_cᵀ M⁻¹ R_ℓj|² / Σ_c |ψ_cᵀ M⁻¹ (φ_j + R_ℓj)|²  (the reactions' share)

    with ``⟨·⟩_ℓ`` the mean over ±:data:`LINE_NOISE_HALF_WIDTH` lines of the third difference
    (which removes a smooth FRF), ``ψ, φ, M`` the stated geometry and the start's properties,
    ``ε_0`` = :data:`PRECISION_FLOOR_REL` the data's own precision (without it, exact FRFs
    would be weighed by ratios of rounding noise).
    The weight ``w_ℓj² = median_ℓ(v_ℓj) / v_ℓj`` (residual ``w (H − Ĥ)/σ``, σ carrying the band
    level): where the random noise dominates the weights are flat; lines where a support
    carries much of the force count as far as the cells' calibration lets them. One weight for
    every channel of the line keeps the statistics' form (:func:`reduced_statistics`). ``None`` below
    16 lines.

    The accelerometers' and the hammer's certificates are *not* in ``v``: each channel's gain
    is a parameter of the fit with its certificate as prior, so a gain error leaves no misfit
    to weigh, and a relative term for it would only de-weight the lines of most power, where the
    information is (measured on acquired sets of the chain check: with an ``ε_a² p`` term
    the principal moments came out 0.7–2.7 % off on 7 of 16 sets, without it 0.02–1.3 %, every
    interval holding the truth).
    """
    L = H.shape[0]
    if L < 16:
        return None
    # |Δ³H|² and |H|² as the caller may have them (the noise estimate and the band's power)
    d3 = third_difference_power(H) if d3_power is None else d3_power  # (L-3, C, J)
    h2 = np.abs(H) ** 2 if h_power is None else h_power
    loc = uniform_filter_nearest(d3, 2 * LINE_NOISE_HALF_WIDTH + 1)
    loc = np.concatenate([loc[:2], loc, loc[-1:]], axis=0)  # centre the L-3 differences on L lines
    power = np.maximum(np.mean(h2, axis=0), 1e-300)  # (C, J)
    n = median_along(loc / (20.0 * power[None]), axis=1)  # (L, J)
    prel = median_along(h2 / power[None], axis=1)  # (L, J)
    # a floor at the data's own precision (float32 UFF records, 24-bit converters: ~1e-7
    # relative): on exact FRFs the local scatter is rounding noise and the weights would be
    # ratios of it
    rel = np.full_like(prel, PRECISION_FLOOR_REL**2)
    if eps_r > 0 and np.any(R):
        B = psi @ A  # (C, 6)
        # einsum's own summation order: on noise-free FRFs these weights feed quantities made of
        # rounding noise (gauge-mode information, the geometry test), which a BLAS product moves
        pr = np.einsum("ca,laj->lcj", B, R)
        pt = pr + (B @ phi.T)[None]
        rho2 = np.sum(np.abs(pr) ** 2, axis=1) / np.maximum(np.sum(np.abs(pt) ** 2, axis=1), 1e-300)
        rel = rel + eps_r**2 * rho2
    v = np.maximum(n + rel * prel, 1e-300)
    return np.asarray(np.sqrt(np.median(v, axis=0)[None] / v), float)


#: A reaction's projection on the smooth basis is kept when its residual is within this factor
#: of the noise's share (:func:`smooth_reactions`).
SMOOTH_FIT_RATIO = 3.0


def smooth_reactions(
    R: ComplexArray, f_hz: FloatArray, cov_R: FloatArray
) -> tuple[ComplexArray, FloatArray]:
    """Least-squares projection of each reaction ``R_j(ω)`` on a smooth basis over the band,
    where it holds.

    Above the suspension a support's load is ``−(k + iωc) u_cell`` with ``u_cell ≈ −a/ω²``
    (plus a stiffness-line share of modes above the band), so ``R(ω) ≈ Σ_k ρ_k ω^k``,
    ``k ∈ {−2, −1, 0, 1}``, complex ``ρ_k``. The projection keeps the signal and ``n_b = 4`` of the
    ``n_ω`` noise dimensions per component: the noise on the regressors, which would bias the
    output-error estimate (errors in variables), falls by ``n_b / n_ω``; what is left is compensated
    (``n_b Σ_R``). Needs ``n_ω ≥ 12`` lines.

    A band that reaches into the support's modes (a bungee's swing at 0.4–2 Hz, an automatic band
    that starts on a mode's flank) holds reactions that are *not* smooth there: the projection
    would replace the measured reaction by a curve the data do not follow, and the fit would
    explain the difference by moving the inputs (tens of millimetres on exact model FRFs, issue
    22). So an input's reactions are projected only where the residual of the projection,
    ``Σ_ω |R − R̂|²``, is within :data:`SMOOTH_FIT_RATIO` of the noise's share of it,
    ``(n_ω − n_b) tr Σ_R``; otherwise they are kept as measured (``n_b = n_ω``).

    Returns
    -------
    R : ndarray, shape (L, 6, J)
    n_b : ndarray, shape (J,)
        Noise dimensions left per input (the factor of ``Σ_R`` in the compensation).
    """
    n = R.shape[0]
    J = R.shape[2]
    if n < 12:
        return R, np.full(J, float(n))
    w = f_hz / np.sqrt(f_hz[0] * f_hz[-1])
    B = np.stack([w**-2, w**-1, np.ones_like(w), w], axis=1)  # (L, 4)
    Q, _ = np.linalg.qr(B)
    flat = R.reshape(n, -1)
    Rs = (Q @ (Q.T @ flat)).reshape(R.shape)
    resid = np.sum(np.abs(R - Rs) ** 2, axis=(0, 1))  # (J,)
    noise = (n - B.shape[1]) * np.einsum("jii->j", cov_R)
    smooth = resid <= SMOOTH_FIT_RATIO * np.maximum(noise, 1e-300)
    out = np.where(smooth[None, None, :], Rs, R)
    return out, np.where(smooth, float(B.shape[1]), float(n))
