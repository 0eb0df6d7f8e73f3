"""Output-error (maximum-likelihood) DIM with geometry self-calibration and residual flexibility.

Why
---
The equation-error DIM (:mod:`dimacq.pipeline.dim`) puts the condensed accelerations ``K = Ψ⁺H`` in
its design matrix and treats them, and the geometry behind ``Ψ`` and ``φ``, as exact. Noise on
``H`` then shrinks the estimate (errors in variables), and the stated geometry sets a floor on the
accuracy (``estimation-notes.md``). Here the measured FRFs are *predicted* from the parameters and
compared where the noise is.

Model
-----
For input ``j`` at line ``ω`` the rigid-body motion of the reference point P and the accelerance of
accelerometer channel ``c`` (unit direction ``d_c`` at ``r_c``, both relative to P) are

    [a_j; α_j](ω) = M(x)⁻¹ ( φ_j(g) + R_j(ω) )
    Ĥ_cj(ω)       = ψ_c(g)ᵀ [a_j; α_j](ω) + Σ_k G_cjk b_k(ω),   ψ_c = [d_c; r_c × d_c]

with ``M(x) = [[m E, −m[c]x], [m[c]x, I_P]]`` the rigid mass matrix of the ten properties
(``c`` the CG relative to P, ``I_P`` about P), ``φ_j = [d_j; r_j × d_j]`` the unit input, ``R_j`` the
measured load-cell reactions mapped to P, and — with residual flexibility — free real coefficients
``G`` on the basis ``b(ω) = [(ω/ω_hi)², (ω/ω_hi)⁴]``: the stiffness-line share of elastic modes above
the band (``−ω²/(ω_r² − ω²) = −(ω/ω_r)² − (ω/ω_r)⁴ − …`` per mode) and below nothing else. The
estimate minimises

    Σ_jcω |Ĥ_cj − H_cj|² / σ_cj²  +  Σ_g (δg / σ_g)²

(a MAP / bundle-adjustment cost). ``σ_cj`` is the FRF noise (below); ``δg`` the geometry corrections
with their stated 1σ (:class:`~dimacq.model.setup.GeometryUncertainty`):

- each sensor node (triax): a small rotation ``δθ_n`` (3, rad; prior ``sensor_orientation_deg`` per
  axis) and a position offset ``δp_n`` (3, m; prior ``sensor_position_m``): ``d_c = exp([δθ_n]x) d_c⁰``,
  ``r_c = r_c⁰ + δp_n``;
- each input: its line of action turned about the two axes ``e₁, e₂`` normal to it (2, rad; prior
  ``line_of_action_deg``) and its point moved along ``e₁, e₂`` (2, m; prior ``input_position_m``; a
  move along the line of action changes nothing and is not a parameter).

Sufficient statistics (why it is fast)
--------------------------------------
With ``z_j(ω) = [1; R_j(ω); b(ω); H_:j(ω)/σ_:j]`` the cost of input ``j`` is a quadratic form in the
real second-moment matrix ``S_j = Σ_ω Re(z_j z_jᴴ)`` (all lines of the band), so the number of lines
enters once. The free residual coefficients ``G`` are eliminated exactly by the Schur complement of
``S_j`` on the ``b`` block (variable projection). With ``S'_j = L_j L_jᵀ`` (eigen-factor, numerical
rank columns) the cost is ``‖L_jʰ − W_j Ψ M⁻¹ [φ_j, E] L_jʸ‖²_F``: a residual of ``n_ch × rank``
entries per input, whatever the number of lines. Gauss–Newton / Levenberg–Marquardt on that
residual and the prior residuals with the analytic Jacobian:

- ``∂/∂x_k``: ``W Ψ M⁻¹ M_k G_j`` with ``G_j = M⁻¹ Y_j L_jʸ`` (``∂M⁻¹ = −M⁻¹ ∂M M⁻¹``);
- sensor node: ``−W_jc (∂ψ_c)ᵀ G_j``, ``∂ψ_c/∂δθ_i = [e_i × d_c; r_c × (e_i × d_c)]``,
  ``∂ψ_c/∂δp_i = [0; e_i × d_c]``;
- input: ``−W_j Ψ M⁻¹ ∂φ_j (L_jʸ)₀``, ``∂φ/∂β_i = [e_i × d; r × (e_i × d)]``, ``∂φ/∂γ_i = [0; e_i × d]``.

Noise model (errors in variables)
---------------------------------
Independent circular complex noise per output, input and line. ``σ_cj`` is estimated from the data by
the line-to-line scatter: the third difference along the lines ``Δ³H = H_ℓ − 3H_ℓ₊₁ + 3H_ℓ₊₂ − H_ℓ₊₃``
removes a smooth FRF (the mass line) and has variance ``20 σ²`` for white noise; a robust
(median) estimate ``σ² = median|Δ³H|² / (20 ln 2)``. The reactions ``R_j`` are regressors with noise:
``E[S_RR] = S_RR⁰ + n_ω Σ_R``, so ``n_ω Σ_R`` (``Σ_R`` from the third difference of ``R_j``) is
subtracted before the fit (bias compensation). Noise on ``H`` sits on the compared quantity and does
not bias the estimate. The reduced ``χ²`` at the solution checks the noise model; the covariance
is scaled by ``max(1, χ²_red)``.

Gauge
-----
A common similarity of the whole instrumentation (translation, rotation about P and scale of all
sensors and inputs together, with the body's properties moved with it:
:func:`gauge_property_jacobian`) and a common accelerometer gain leave every FRF unchanged
(``ψᵀ M⁻¹ φ`` is invariant under ``ψ → Sψ``, ``φ → Sφ``, ``M → SMS``); only the load-cell
reactions, whose positions and calibration the model takes as exact, can see it. The priors fix
what the data do not (inner constraint, :func:`_gauge_constraint`): the scale and the common gain
always (the reactions could pin the scale only if modelled to a few 0.1 %), and by default the
translations and rotations too (the reactions tie the frame only to the load cells' stated
positions, themselves measured geometry: ``OutputErrorOptions.gauge_from_reactions``). Frame, scale and gain are then those of the stated
(digitized, registered) geometry and certificates, and their prior variance — the Cramér–Rao
bound of any estimator from these FRFs and priors — is in the intervals
(``tests/scripts/accuracy_diagnose.py`` prints it). Its scale share is
``σ_s = (Σ_i |r_i,⊥|² / σ_p²)^(-1/2)`` over the sensor and input positions (about P; inputs: the
components normal to the line), which sets the principal moments' floor at ``2 σ_s`` whatever the
data; the translation's, ``σ_p / √N`` per axis, the CG's.

Identifiability
---------------
A geometry parameter whose posterior standard deviation (at the start, all others marginalised) is
above ``refuse_ratio`` of its prior is not identified by the data: it is left at the stated value
(not estimated) and reported with that reason. The posterior covariance of the properties is the
inverse of the Gauss–Newton information (data and priors) at the solution (Laplace approximation).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from dimacq.errors import SetupError, SolverError
from dimacq.model.frf import Channel, FrfData
from dimacq.model.setup import PARAMETERS, TestSetup
from dimacq.pipeline._batched import cross3
from dimacq.pipeline._filters import median_along, uniform_filter_nearest
from dimacq.pipeline._special import chi2_ppf, eigh_generalized, null_space
from dimacq.pipeline.dim import DimResult, assemble, solve_system
from dimacq.pipeline.rotations import apply_rotvec
from dimacq.pipeline.selection._common import response_geometry

__all__ = [
    "OutputErrorOptions",
    "OutputErrorResult",
    "estimate_noise",
    "mass_matrix",
    "solve_output_error",
]

log = logging.getLogger("dimacq.pipeline.output_error")


def _chi2_ppf(q: float, dof: int) -> float:
    """χ² quantile, ``scipy.stats.chi2.ppf(q, dof)`` (its ``2·P⁻¹(dof/2, q)``) to ~1e-13, without
    importing scipy (:mod:`dimacq.pipeline._special`)."""
    return chi2_ppf(q, dof)


FloatArray = NDArray[np.float64]
ComplexArray = NDArray[np.complex128]

_E = np.eye(3)
#: Directions of the (bias-compensated) regressor moments below this fraction of the largest are
#: dropped (numerically null: no reaction in that direction).
_EIG_KEEP = 1e-12
#: Weight of the gauge constraint rows (whitened units: × the prior's unit weight); large enough
#: to hold the constraint to ~1e-6 of a prior σ against the data's pull.
_GAUGE_WEIGHT = 1e3


def _skew(v: FloatArray) -> FloatArray:
    out = np.zeros(v.shape + (3,))
    out[..., 0, 1], out[..., 0, 2] = -v[..., 2], v[..., 1]
    out[..., 1, 0], out[..., 1, 2] = v[..., 2], -v[..., 0]
    out[..., 2, 0], out[..., 2, 1] = -v[..., 1], v[..., 0]
    return out


def _left_jacobian(rv: FloatArray) -> FloatArray:
    """Left Jacobian of SO(3), ``J_l(θ) = E + ½[θ]x + ⅙[θ]x²`` (series to second order; the
    corrections are small angles), shape (..., 3, 3)."""
    k = _skew(rv)
    return np.asarray(_E + 0.5 * k + (k @ k) / 6.0, float)


# ------------------------------------------------------------------------------------------
# Mass matrix of the ten properties
# ------------------------------------------------------------------------------------------
_IDX6 = ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))


def mass_matrix(x: FloatArray) -> tuple[FloatArray, FloatArray]:
    """``M(x)`` and its derivatives ``∂M/∂x_k``.

    Parameters
    ----------
    x : ndarray, shape (10,)
        ``[m, cx, cy, cz, Ixx, Ixy, Ixz, Iyy, Iyz, Izz]``, CG relative to P (m), inertia about P.

    Returns
    -------
    M : ndarray, shape (6, 6)
        ``[[m E, −m[c]x], [m[c]x, I_P]]``.
    dM : ndarray, shape (10, 6, 6)
    """
    m, c = x[0], x[1:4]
    M = np.zeros((6, 6))
    M[:3, :3] = m * _E
    M[:3, 3:] = -m * _skew(c)
    M[3:, :3] = m * _skew(c)
    dM = np.zeros((10, 6, 6))
    dM[0, :3, :3] = _E
    dM[0, :3, 3:] = -_skew(c)
    dM[0, 3:, :3] = _skew(c)
    for i in range(3):
        s = _skew(_E[i])
        dM[1 + i, :3, 3:] = -m * s
        dM[1 + i, 3:, :3] = m * s
    for k, (a, b) in enumerate(_IDX6):
        M[3 + a, 3 + b] = M[3 + b, 3 + a] = x[4 + k]
        dM[4 + k, 3 + a, 3 + b] = dM[4 + k, 3 + b, 3 + a] = 1.0
    return M, dM


def gauge_property_jacobian(x: FloatArray) -> FloatArray:
    """How the ten properties follow the gauge modes of :meth:`_Problem.gauge_basis`.

    Parameters
    ----------
    x : ndarray, shape (10,)
        ``[m, c (rel P, m), I_P (kg·m²)]``.

    Returns
    -------
    ndarray, shape (10, 8)
        ``∂x/∂(t, ω, s, g)``: a translation moves the CG, ``δc = t``, and the tensor about P by
        the parallel-axis term ``δI_P = m (2 c·t E − t cᵀ − c tᵀ)``; a rotation turns both,
        ``δc = ω × c``, ``δI_P = [ω]x I_P − I_P [ω]x``; a scale ``s`` of lengths with the same
        FRFs gives ``δc = s c``, ``δI_P = 2 s I_P`` (moment arms ×(1+s), angular accelerations
        ÷(1+s)); a common gain ``g`` on every accelerometer's prediction ``(1+g) ψ M⁻¹ φ`` is
        undone by ``M → (1+g) M``: ``δm = g m``, ``δI_P = g I_P``.
    """
    m, c = float(x[0]), np.asarray(x[1:4], float)
    M, _ = mass_matrix(np.asarray(x, float))
    Ip = M[3:, 3:]
    out = np.zeros((10, 8))

    def put(col: int, dc: FloatArray, dI: FloatArray, dm: float = 0.0) -> None:
        out[0, col] = dm
        out[1:4, col] = dc
        out[4:, col] = [dI[a, b] for a, b in _IDX6]

    for i in range(3):
        t = _E[i]
        put(i, t, m * (2 * (c @ t) * _E - np.outer(t, c) - np.outer(c, t)))
        w = _skew(_E[i])
        put(3 + i, cross3(_E[i], c), w @ Ip - Ip @ w)
    put(6, c, 2 * Ip)
    put(7, np.zeros(3), Ip, m)
    return out


# ------------------------------------------------------------------------------------------
# Noise
# ------------------------------------------------------------------------------------------
def _third_difference_power(H: ComplexArray) -> FloatArray:
    """``|Δ³H|²`` along the lines (axis 0): ``|H_ℓ − 3H_ℓ₊₁ + 3H_ℓ₊₂ − H_ℓ₊₃|²``, (L − 3, ...)."""
    d3 = H[:-3] - 3 * H[1:-2] + 3 * H[2:-1] - H[3:]
    return np.asarray(np.abs(d3) ** 2, float)


def estimate_noise(H: ComplexArray, *, d3_power: FloatArray | None = None) -> FloatArray:
    """Noise standard deviation of each FRF from the line-to-line scatter (module docstring).

    Parameters
    ----------
    H : ndarray, shape (n_lines, ...), complex
        FRFs along their lines (axis 0), at least 8 lines.
    d3_power : ndarray, optional
        ``|Δ³H|²`` if already formed (:func:`_third_difference_power`; the line weights use it
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
    d3p = _third_difference_power(H) if d3_power is None else d3_power
    return np.asarray(np.sqrt(np.median(d3p, axis=0) / (20 * np.log(2))), float)


def _reaction_noise_cov(R: ComplexArray) -> FloatArray:
    """``Σ_R`` per input (J, 6, 6): real covariance per line of the noise on the reactions at P
    (``E Re(e eᴴ)`` = total complex covariance), from the third difference of ``R_j``."""
    d3 = R[:-3] - 3 * R[1:-2] + 3 * R[2:-1] - R[3:]  # (L-3, 6, J)
    cov = np.real(np.einsum("lij,lkj->jik", d3, d3.conj())) / (20.0 * d3.shape[0])
    # robust scale: match the diagonal to the median estimate, keep the correlation structure
    med = np.median(np.abs(d3) ** 2, axis=0).T / (20 * np.log(2))  # (J, 6)
    diag = np.einsum("jii->ji", cov)
    with np.errstate(divide="ignore", invalid="ignore"):
        s = np.sqrt(np.where(diag > 0, med / diag, 0.0))
    return np.asarray(cov * s[:, :, None] * s[:, None, :], float)


#: Reactions whose power on a line is at most this multiple of their noise are at noise level.
REACTION_SNR_LOW = 4.0

#: Relative precision floor of an FRF value in the line weights (:func:`_line_weights`).
PRECISION_FLOOR_REL = 1e-6

#: Half-width (lines) of the local noise estimate of :func:`_line_weights`.
LINE_NOISE_HALF_WIDTH = 16


def _line_weights(
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
    every channel of the line keeps the statistics' form (:func:`_statistics`). ``None`` below
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
    d3 = _third_difference_power(H) if d3_power is None else d3_power  # (L-3, C, J)
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
#: of the noise's share (:func:`_smooth_reactions`).
SMOOTH_FIT_RATIO = 3.0


def _smooth_reactions(
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


# ------------------------------------------------------------------------------------------
# Options and result
# ------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class OutputErrorOptions:
    """What :func:`solve_output_error` estimates.

    Attributes
    ----------
    refine_geometry : bool
        Estimate sensor rotations and offsets and input lines of action (priors from
        ``setup.geometry_uncertainty``). Off: the stated geometry is taken as exact.
    residual_flexibility : bool or None
        ``True``: fit the residual terms (and report the Hausman test of whether they were
        needed); ``False`` (default): never; ``None`` (auto): keep them only when the test says so.
        When they are kept, the difference of the properties with and without them is added to
        the covariance as a model-form term (``dx dxᵀ``).
    refine_positions : bool
        Include the sensor position offsets (where identified).
    refuse_ratio : float
        A geometry parameter whose posterior σ exceeds this fraction of its prior σ is not
        estimated (not identified by the data).
    max_iterations : int
    max_correction_sigma : float
        A refined correction beyond this many stated σ is a gross error: the item (sensor node or
        input) is left out and the solve repeated, at most ``max_gross_items`` times; beyond
        that the model, not the geometry, is wrong: the refinement is refused.
    max_gross_items : int
    fix_gauge : bool
        Fix the gauge modes the data do not identify (:func:`_gauge_constraint`) and add their
        prior variance to the properties' covariance; off: the priors alone hold them.
    gauge_from_reactions : bool
        Let the load-cell reactions identify a common translation or rotation of the
        instrumentation (estimated where their information passes ``refuse_ratio``). Off
        (default): every similarity mode is fixed at the stated geometry's. The reactions tie the
        instrumentation only to the load cells' *stated* positions and orientations, which are
        measured geometry too (digitized or drawn, as uncertain as a sensor's): they cannot pin
        the frame better than those, and a misfit that is not geometry (a load-cell chain error,
        gauge noise on a cell that carries almost no reaction, channel gains) projects onto the
        common translation as if it were information. Seen on acquired data (issue 22): a bungee-
        hung calibration mass, reactions at noise level, came out with the CG moved 5 mm along a
        "identified" translation, intervals 0.5 mm wide, verdict ok; with the frame fixed, 0.2 mm.
        The scale and the common accelerometer gain are fixed either way
        (:func:`_gauge_constraint`).
    geometry_test : bool
        Test whether the data need the geometry moved at all (:func:`_geometry_needed`): when
        the channel gains alone explain the misfit as well, the stated geometry is kept and its
        stated uncertainty propagated into the intervals (default on).
    """

    refine_geometry: bool = True
    residual_flexibility: bool | None = False
    refine_positions: bool = True
    refuse_ratio: float = 0.9
    max_iterations: int = 30
    max_correction_sigma: float = 6.0
    max_gross_items: int = 3
    fix_gauge: bool = True
    gauge_from_reactions: bool = False
    geometry_test: bool = True


@dataclass(frozen=True, eq=False)
class OutputErrorResult:
    """The output-error estimate with its evidence.

    Attributes
    ----------
    parameters : ndarray, shape (10,)
        ``[m, cx, cy, cz, Ixx..Izz]``: CG in the GCS (m), inertia about P (kg·m²).
    covariance : ndarray, shape (10, 10)
        Posterior covariance (geometry marginalised, scaled by ``max(1, χ²_red)``, registration
        residual added to the CG); zero rows for known properties.
    covariance_noise : ndarray, shape (10, 10)
        The same with the geometry held at its estimate: the noise's share; the difference is
        the geometry's (priors, gauge, registration).
    sensor_corrections, input_corrections : list of dict
        Each correction with its standard deviation, or the reason it was not estimated.
    residual_flexibility : dict
        ``fitted``, ``needed``, the likelihood-ratio statistic and the size of the residual.
    noise : dict
        Median FRF noise relative to the band RMS, reduced χ², how σ was estimated.
    setup : TestSetup
        The setup with the refined geometry.
    refine_geometry : bool
        Whether the geometry was refined (False when asked but refused).
    """

    parameters: FloatArray
    covariance: FloatArray
    covariance_noise: FloatArray
    chi2_reduced: float
    iterations: int
    elapsed_s: float
    sensor_corrections: list[dict[str, Any]]
    input_corrections: list[dict[str, Any]]
    residual_flexibility: dict[str, Any]
    noise: dict[str, Any]
    gauge: str
    setup: TestSetup
    refine_geometry: bool
    n_inputs: int
    gross_errors: list[dict[str, Any]] = field(default_factory=list)
    response_weights: FloatArray | None = None
    input_keep: NDArray[np.bool_] | None = None
    extras: dict[str, Any] = field(default_factory=dict)

    @property
    def standard_errors(self) -> FloatArray:
        return np.sqrt(np.clip(np.diag(self.covariance), 0.0, None))

    def to_json(self) -> dict[str, Any]:
        se = self.standard_errors
        return {
            "estimator": "output-error",
            "refine_geometry": self.refine_geometry,
            "parameters": {k: float(v) for k, v in zip(PARAMETERS, self.parameters, strict=True)},
            "standard_errors": {k: float(v) for k, v in zip(PARAMETERS, se, strict=True)},
            "chi2_reduced": self.chi2_reduced,
            "iterations": self.iterations,
            "elapsed_s": self.elapsed_s,
            "gauge": self.gauge,
            "sensor_corrections": self.sensor_corrections,
            "input_corrections": self.input_corrections,
            "residual_flexibility": self.residual_flexibility,
            "noise": self.noise,
            "gross_errors": list(self.gross_errors),
            "gauge_modes": self.extras.get("gauge", {}),
            "adequacy": self.extras.get("adequacy", {}),
            "geometry_test": self.extras.get("geometry_test", {}),
        }


# ------------------------------------------------------------------------------------------
# Problem
# ------------------------------------------------------------------------------------------
@dataclass(eq=False)
class _Problem:
    """Everything the cost needs, in SI units relative to P."""

    r0: FloatArray  # (C, 3) channel positions rel P
    d0: FloatArray  # (C, 3) channel directions
    node_of: NDArray[np.intp]  # (C,) index of the channel's node
    nodes: NDArray[np.int64]  # (Nn,)
    rin0: FloatArray  # (J, 3)
    din0: FloatArray  # (J, 3)
    ebasis: FloatArray  # (J, 2, 3) unit vectors normal to each line of action
    w: FloatArray  # (C, J) 1/σ
    Ly: FloatArray  # (J, 7, k)
    Lh: FloatArray  # (J, C, k)  (already weighted by 1/σ)
    free_x: NDArray[np.intp]
    x_fixed: FloatArray  # (10,)
    free_g: NDArray[np.intp]  # indices into the full geometry vector
    sigma_g: FloatArray  # (n_geom_full,) prior σ
    #: gauge constraint rows on the free geometry (k, n_free_g), whitened units; empty: none
    gauge_rows: FloatArray = field(default_factory=lambda: np.zeros((0, 0)))
    #: the fixed modes as combinations of the live gauge columns (n_live, k)
    gauge_modes: FloatArray = field(default_factory=lambda: np.zeros((0, 0)))
    gauge_live: NDArray[np.bool_] = field(default_factory=lambda: np.zeros(8, bool))
    gauge_information_ratio: FloatArray = field(default_factory=lambda: np.zeros(0))
    #: the last :func:`_line_residual` (its key, the arrays it was computed from, the residual,
    #: then its sum of squares once :func:`_direct_cost` formed it): the variance factor, the
    #: geometry test and χ² ask for the same one
    line_residual_memo: tuple[Any, ...] | None = field(default=None, repr=False)

    @property
    def n_nodes(self) -> int:
        return int(self.nodes.size)

    def geometry(self, g: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
        """Channel positions/directions and input positions/directions for corrections ``g``."""
        nn = self.n_nodes
        gs = g[: 6 * nn].reshape(nn, 6)
        gi = g[6 * nn : 6 * nn + 4 * self.rin0.shape[0]].reshape(-1, 4)
        d = apply_rotvec(gs[self.node_of, :3], self.d0)
        r = self.r0 + gs[self.node_of, 3:]
        axis = np.einsum("ji,jik->jk", gi[:, :2], self.ebasis)
        din = apply_rotvec(axis, self.din0)
        rin = self.rin0 + np.einsum("ji,jik->jk", gi[:, 2:], self.ebasis)
        return r, d, rin, din

    def full_x(self, theta: FloatArray) -> FloatArray:
        x = self.x_fixed.copy()
        x[self.free_x] = theta[: self.free_x.size]
        return x

    def full_g(self, theta: FloatArray) -> FloatArray:
        g = np.zeros(self.sigma_g.size)
        g[self.free_g] = theta[self.free_x.size :] * self.sigma_g[self.free_g]
        return g

    def residual(
        self, theta: FloatArray, jacobian: bool = True
    ) -> tuple[FloatArray, FloatArray | None]:
        """Stacked residual (data then prior) and, optionally, its Jacobian in θ.

        θ = [free properties; free geometry corrections / their prior σ].
        """
        x = self.full_x(theta)
        g = self.full_g(theta)
        r, d, rin, din = self.geometry(g)
        M, dM = mass_matrix(x)
        A = np.linalg.inv(M)
        psi = np.concatenate([d, cross3(r, d)], axis=1)  # (C, 6)
        phi = np.concatenate([din, cross3(rin, din)], axis=1)  # (J, 6)
        Y = np.concatenate([phi[:, :, None], np.broadcast_to(np.eye(6), (phi.shape[0], 6, 6))], 2)
        G = A @ (Y @ self.Ly)  # (J, 6, k)
        C0 = psi.shape[0]
        gain = 1.0 + g[g.size - C0 :]
        wt = self.w.T[:, :, None] * np.reshape(gain, (1, -1, 1))  # (J, C, 1): 1/σ × channel gain
        pred = wt * (psi @ G)  # (J, C, k)
        E = self.Lh - pred  # (J, C, k)
        n_data = E.size
        prior = theta[self.free_x.size :]
        n_c = self.gauge_rows.shape[0] if prior.size else 0
        gauge = _GAUGE_WEIGHT * (self.gauge_rows @ prior) if n_c else np.zeros(0)
        res = np.concatenate([E.ravel(), prior, gauge])
        if not jacobian:
            return res, None
        J_, C_, k_ = E.shape
        n_x, n_g = self.free_x.size, self.free_g.size
        Jac = np.zeros((n_data + n_g + n_c, n_x + n_g))
        # properties
        WPA = wt * (psi @ A)[None]  # (J, C, 6)
        for col, k in enumerate(self.free_x):
            Jac[:n_data, col] = ((WPA @ dM[k]) @ G).ravel()
        if n_g:
            n_full = self.sigma_g.size
            # Every geometry item free (the usual case): the sensitivities are written straight
            # into the Jacobian's block (a view; its zeros are Jac's) and scaled there, instead
            # of into a (J, C, k, n_geom) array gathered and scaled into a third copy (~6 MB per
            # call): the same products, in place.
            in_place = n_g == n_full and bool(np.all(self.free_g == np.arange(n_full)))
            if in_place:
                full = Jac[:n_data, n_x:].reshape(J_, C_, k_, n_full)  # splits rows: a view
                assert np.may_share_memory(full, Jac)
            else:
                full = np.zeros((J_, C_, k_, n_full))
            nn = self.n_nodes
            # sensor nodes: ∂ψ_c for rotation (3) and offset (3)
            # ∂(exp([θ]x) d⁰)/∂θ_i = (J_l(θ) e_i) × d with the left Jacobian of SO(3)
            rv = g[: 6 * nn].reshape(nn, 6)[:, :3]
            jl = _left_jacobian(rv)[self.node_of]  # (C, 3, 3), columns J_l e_i
            ex_d = cross3(np.swapaxes(jl, 1, 2), d[:, None, :])  # (C, 3, 3): (J_l e_i) × d_c
            dpsi = np.zeros((C_, 6, 6))
            dpsi[:, :3, :3] = ex_d
            dpsi[:, :3, 3:] = cross3(r[:, None, :], ex_d)
            dpsi[:, 3:, 3:] = cross3(_E[None, :, :], d[:, None, :])  # e_i × d_c (offsets)
            # −W_jc dψ_c[p]ᵀ G_j
            cols = 6 * self.node_of[:, None] + np.arange(6)[None, :]  # (C, 6)
            for p in range(6):  # each channel belongs to one node: no two writes collide
                sens_p = -wt * (dpsi[:, p, :] @ G)  # (J, C, k)
                full[:, np.arange(C_), :, cols[:, p]] = np.moveaxis(sens_p, 1, 0)
            # inputs: ∂φ for β (2) and γ (2)
            gi = g[6 * nn : 6 * nn + 4 * self.rin0.shape[0]].reshape(-1, 4)
            ax = np.einsum("ji,jik->jk", gi[:, :2], self.ebasis)
            jli = _left_jacobian(ax)  # (J, 3, 3)
            eb_l = np.einsum("jab,jib->jia", jli, self.ebasis)  # J_l e_i for the two normals
            exd = cross3(eb_l, din[:, None, :])  # (J, 2, 3)
            dphi = np.zeros((J_, 4, 6))
            dphi[:, :2, :3] = exd
            dphi[:, :2, 3:] = cross3(rin[:, None, :], exd)
            dphi[:, 2:, 3:] = exd
            base = 6 * nn + 4 * np.arange(J_)
            ly0 = self.Ly[:, None, 0, :]  # (J, 1, k)
            for p in range(4):
                full[np.arange(J_), :, :, base + p] = -(WPA @ dphi[:, p, :, None]) * ly0
            if self.sigma_g.size > 6 * nn + 4 * J_:  # channel gains (relative)
                gcols = 6 * nn + 4 * J_ + np.arange(C_)
                full[:, np.arange(C_), :, gcols] = np.moveaxis(
                    -(self.w.T[:, :, None] * (psi @ G)), 1, 0
                )
            if in_place:
                full *= self.sigma_g
            else:
                sub = full[..., self.free_g] * self.sigma_g[self.free_g]
                Jac[:n_data, n_x:] = sub.reshape(n_data, n_g)
            Jac[n_data : n_data + n_g, n_x:] = np.eye(n_g)
            if n_c:
                Jac[n_data + n_g :, n_x:] = _GAUGE_WEIGHT * self.gauge_rows
        return res, Jac

    def gauge_basis(self) -> FloatArray:
        """The similarity of the whole instrumentation and the common accelerometer gain, as
        directions in the full geometry vector ``g`` (n_geom_full, 8).

        Columns: translation ``t`` (3), rotation ``ω`` about P (3), scale ``s`` of the positions
        about P (1), common relative gain of every accelerometer channel (1). A sensor node at
        ``r_n`` moves by ``δp_n = t + ω × r_n + s r_n`` and turns by ``δθ_n = ω``; an input at
        ``r_j`` with normals ``e_ji`` gets ``β_ji = ω · e_ji`` and ``γ_ji = (t + ω × r_j +
        s r_j) · e_ji``. With the body's properties moved alike (:func:`gauge_property_jacobian`)
        the FRFs do not change, except through the load cells' reactions (taken as exact).
        """
        nn, J = self.n_nodes, self.rin0.shape[0]
        G = np.zeros((self.sigma_g.size, 8))
        rn = np.zeros((nn, 3))
        np.add.at(rn, self.node_of, self.r0)
        rn /= np.bincount(self.node_of, minlength=nn)[:, None]
        Gn = G[: 6 * nn].reshape(nn, 6, 8)  # rows of sensor node n: δp (3), δθ (3)
        Gj = G[6 * nn : 6 * nn + 4 * J].reshape(J, 4, 8)  # rows of input k: β (2), γ (2)
        eb = np.asarray(self.ebasis)  # (J, 2, 3)
        for i in range(3):  # over the three axes; nodes and inputs at once (same bits as per item)
            e = _E[i]
            Gn[:, 3:6, i] = e
            Gn[:, i, 3 + i] = 1.0
            Gn[:, 3:6, 3 + i] = cross3(e, rn)
            be = eb @ e  # (J, 2)
            Gj[:, 2:4, i] = be
            Gj[:, 0:2, 3 + i] = be
            Gj[:, 2:4, 3 + i] = (eb @ cross3(e, self.rin0)[:, :, None])[:, :, 0]
        Gn[:, 3:6, 6] = rn
        Gj[:, 2:4, 6] = (eb @ np.asarray(self.rin0)[:, :, None])[:, :, 0]
        G[6 * nn + 4 * J :, 7] = 1.0
        return G


def _statistics(
    H: ComplexArray,
    R: ComplexArray,
    sigma: FloatArray,
    cov_R: FloatArray,
    basis: ComplexArray | None,
    lw: FloatArray | None = None,
) -> tuple[FloatArray, FloatArray, float]:
    """Factors ``L_jʸ`` (J, 7, 7) and ``T_j`` (J, C, 7) of the reduced statistics (module
    docstring), and the part of the cost that no parameter changes (for χ²).

    ``lw`` (L, J): line weights (:func:`_line_weights`); the residual of line ``ℓ`` and input
    ``j`` is ``w_ℓj (H − Ĥ)/σ``, so ``z_j`` is scaled by ``w_ℓj`` (its prediction is linear in
    ``z_j``) and the statistics keep their form. The reactions' noise compensation is scaled by
    the mean ``w²`` of the input."""
    L, C, J = H.shape
    if lw is not None:
        cov_R = cov_R * np.mean(lw**2, axis=0)[:, None, None]
    nb = 0 if basis is None else basis.shape[1]
    # z_j = [w; w R_j; b; w H_:j/σ] (w = 1 without line weights), written straight into its real
    # and imaginary parts as (J, n, L) arrays: the products of Σ_ω Re(z zᴴ) = Zr Zrᵀ + Zi Ziᵀ.
    # The numbers are those of the complex expressions (w·(1+0i), R·w, H/σ = H·(1/σ) in numpy's
    # complex division, H·(w/σ)) up to the sign of a zero, which no product or sum sees.
    n = 7 + nb + C
    zr = np.empty((J, n, L))
    zi = np.empty((J, n, L))
    w = None if lw is None else lw.T[:, None, :]  # (J, 1, L)
    zr[:, 0:1] = 1.0 if w is None else w
    zi[:, 0:1] = 0.0
    Rt = np.transpose(R, (2, 1, 0))  # (J, 6, L), complex view
    zr[:, 1:7] = Rt.real if w is None else Rt.real * w
    zi[:, 1:7] = Rt.imag if w is None else Rt.imag * w
    if basis is not None:
        zr[:, 7 : 7 + nb] = basis.real.T[None]
        zi[:, 7 : 7 + nb] = basis.imag.T[None]
    scale = (1.0 / sigma).T[:, :, None] if w is None else w / sigma.T[:, :, None]  # (J, C, L)
    Ht = np.transpose(H, (2, 1, 0))  # (J, C, L)
    np.multiply(Ht.real, scale, out=zr[:, 7 + nb :])
    np.multiply(Ht.imag, scale, out=zi[:, 7 + nb :])
    S = zr @ np.swapaxes(zr, 1, 2) + zi @ np.swapaxes(zi, 1, 2)  # Σ_ω Re(z zᴴ), (J, n, n)
    dsc = np.sqrt(np.clip(np.einsum("jii->ji", S), 1e-300, None))  # equilibration (raw S)
    S[:, 1:7, 1:7] -= cov_R  # bias compensation of the noisy reactions (already × n_ω or rank)
    if nb:
        a = np.r_[0:7, 7 + nb : 7 + nb + C]
        b = np.arange(7, 7 + nb)
        Sab = S[:, a][:, :, b]
        Sbb = S[:, b][:, :, b]
        S = S[:, a][:, :, a] - Sab @ np.linalg.solve(Sbb, np.swapaxes(Sab, 1, 2))
        dsc = dsc[:, a]
    # cost_j = tr(S_hh) − 2 tr(B S_yh) + tr(B S_yy Bᵀ) = ‖B L_y − T‖² + tr(S_hh) − ‖T‖²
    # with S_yy = L_y L_yᵀ (7 × k) and T = S_hy L_y⁺ᵀ: 7 columns per channel, whatever n_ω.
    d = dsc[:, :7]
    lam, V = np.linalg.eigh(S[:, :7, :7] / (d[:, :, None] * d[:, None, :]))
    keep = lam > np.clip(lam.max(axis=1, keepdims=True), 0, None) * _EIG_KEEP
    sq = np.sqrt(np.where(keep, lam, 1.0))
    Ly = np.where(keep[:, None, :], d[:, :, None] * V * sq[:, None, :], 0.0)
    T = np.where(keep[:, None, :], (S[:, 7:, :7] / d[:, None, :]) @ V / sq[:, None, :], 0.0)
    const = np.einsum("jii->j", S[:, 7:, 7:]) - np.einsum("jck,jck->j", T, T)
    return Ly, T, float(np.sum(const))


def _gauge_constraint(
    prob: _Problem,
    theta0: FloatArray,
    refuse_ratio: float,
    fix_all: bool = False,
    data_jacobian: FloatArray | None = None,
) -> None:
    """Fix the gauge modes the data do not identify (sets ``prob.gauge_rows``).

    ``data_jacobian``: the data rows of the Jacobian at ``theta0`` when the caller has them
    (:meth:`_Problem.residual`'s, whose data rows do not depend on the constraint rows).

    The similarity of the whole instrumentation and the common accelerometer gain
    (:meth:`_Problem.gauge_basis`, ``G``) change no FRF when the properties move with them; only
    the load cells' reactions (positions and calibration taken as exact) can tie them. In the
    whitened corrections ``θ_g = δg/σ_g`` a gauge motion is ``G_θ c`` with
    ``G_θ = diag(1/σ_g) G``; the prior's information on ``c`` is ``P = G_θᵀG_θ`` and the data's,
    properties marginalised, ``D = G_θᵀ (J_gᵀJ_g − J_gᵀJ_x (J_xᵀJ_x)⁻¹ J_xᵀJ_g) G_θ``.

    - The **scale** and the **common gain** are always fixed: the common gain is an exact
      symmetry even with reactions, and the scale acts on the reactions only as the factor
      ``1/(1+s)`` on their moments about P, so pinning it to the prior's precision (a few
      0.1 %) needs the reactions modelled to that relative accuracy — finer than the reaction
      model (smooth basis, errors-in-variables compensation) and the load cells' own
      calibration and stated positions, which the model takes as exact. Measured
      (``tests/scripts/accuracy_diagnose.py``): let free, the true geometry with 1 % FRF noise
      came out 0.25 % off in scale (principal moments +0.5 %) on a bungee-hung mass.
    - The translations and rotations, in the part of the space ``P``-orthogonal to those two,
      are the modes of ``D v = λ P v``; those the data do not identify by the rule used for
      each item (posterior σ ``1/√(1+λ)`` of the prior's above ``refuse_ratio``) are fixed too
      (all of them with ``fix_all``).

    A fixed mode satisfies ``(G_θ v)ᵀ θ_g = 0``: the corrections have no component along it in
    the prior's metric (the inner constraint of bundle adjustment), and frame, scale and common
    gain are those of the stated geometry and certificates. The fixed modes are ``P``-orthogonal
    to the free ones, so their prior variance ``(VᵀPV)⁻¹`` is their marginal variance; it is
    added to the properties' covariance afterwards (:func:`gauge_property_jacobian`), so the
    intervals keep it — the Cramér–Rao bound of any estimator from these FRFs and priors along
    those modes.
    """
    G = prob.gauge_basis()[prob.free_g] / prob.sigma_g[prob.free_g][:, None]
    live = np.linalg.norm(G, axis=0) > 0
    G = G[:, live]
    prob.gauge_rows = np.zeros((0, prob.free_g.size))
    prob.gauge_modes = np.zeros((int(live.sum()), 0))
    prob.gauge_live = live
    if not G.shape[1]:
        return
    if data_jacobian is None:
        _, J0 = prob.residual(theta0)
        assert J0 is not None
        data_jacobian = J0[: J0.shape[0] - prob.free_g.size]
    nx = prob.free_x.size
    Jd = data_jacobian
    Jx, Jg = Jd[:, :nx], Jd[:, nx:]
    Nxx, Nxg, Ngg = Jx.T @ Jx, Jx.T @ Jg, Jg.T @ Jg
    Dg = Ngg - Nxg.T @ np.linalg.pinv(Nxx) @ Nxg
    # Gauge coordinates c that move nothing (columns of G dependent once items are fixed or
    # left out) carry no prior and no data: work in the row space of G, c = W y, where
    # P_y = Wᵀ GᵀG W is positive definite.
    _, sv, Wt = np.linalg.svd(G, full_matrices=False)
    W = Wt[sv > sv[0] * 1e-9].T
    D = W.T @ (G.T @ Dg @ G) @ W
    P = W.T @ (G.T @ G) @ W
    D, P = 0.5 * (D + D.T), 0.5 * (P + P.T)
    lam_all = eigh_generalized(D, P)[0]
    # always fixed: the scale and common-gain axes (columns 6, 7 of the full basis), in y
    live_idx = np.nonzero(live)[0]
    A = W[np.isin(live_idx, (6, 7)) | fix_all].T  # (r, n_always)
    if A.shape[1]:
        ua, sa, _ = np.linalg.svd(A, full_matrices=False)
        A = ua[:, sa > sa[0] * 1e-9]
    # the rest, P-orthogonal to A: B spans {y : Aᵀ P y = 0}
    B = null_space((P @ A).T) if A.shape[1] else np.eye(W.shape[1])
    fixed_y = A
    if B.shape[1]:
        lam, U = eigh_generalized(B.T @ D @ B, B.T @ P @ B)
        sel = 1.0 / np.sqrt(1.0 + np.clip(lam, 0.0, None)) > refuse_ratio
        fixed_y = np.concatenate([A, B @ U[:, sel]], axis=1)
    fixed = W @ fixed_y
    prob.gauge_information_ratio = lam_all
    if not fixed.shape[1]:
        return
    rows = (G @ fixed).T
    rows /= np.linalg.norm(rows, axis=1, keepdims=True)
    prob.gauge_rows = rows
    prob.gauge_modes = fixed


def _lm(
    prob: _Problem, theta0: FloatArray, max_iter: int
) -> tuple[FloatArray, FloatArray, float, int]:
    """Levenberg–Marquardt with column equilibration; returns θ, Jacobian, cost, iterations."""
    theta = theta0.copy()
    res, Jac = prob.residual(theta)
    assert Jac is not None
    cost = float(res @ res)
    lam = 1e-6
    it = 0
    while it < max_iter:
        it += 1
        N = Jac.T @ Jac
        g = Jac.T @ res
        dsc = np.sqrt(np.diag(N))
        dsc = np.where(dsc > 0, dsc, 1.0)
        Ns = N / np.outer(dsc, dsc)
        improved = False
        for _ in range(12):
            try:
                step = -np.linalg.solve(Ns + lam * np.eye(Ns.shape[0]), g / dsc) / dsc
            except np.linalg.LinAlgError:
                lam *= 10
                continue
            t_new = theta + step
            try:
                r_new, _ = prob.residual(t_new, jacobian=False)
            except np.linalg.LinAlgError:
                lam *= 10
                continue
            c_new = float(r_new @ r_new)
            if np.isfinite(c_new) and c_new <= cost:
                improved = True
                break
            lam *= 10
        if not improved:
            break
        # predicted decrease −gᵀδ (Newton decrement, cost units of χ²/2): below 1e-2 the step is
        # about a tenth of the posterior standard deviations: further iterations change nothing
        dec = float(-(g @ step))
        rel = (cost - c_new) / max(cost, 1e-300)
        log.debug("LM %d: cost %.6g → %.6g, decrement %.3g, λ %.1g", it, cost, c_new, dec, lam)
        theta = t_new
        cost = c_new
        lam = max(lam / 10, 1e-9)
        res, Jac = prob.residual(theta)
        assert Jac is not None
        if dec < 1e-2 or rel < 1e-12 or float(np.max(np.abs(step * dsc))) < 1e-8:
            break
    return theta, Jac, cost, it


# ------------------------------------------------------------------------------------------
# Entry point
# ------------------------------------------------------------------------------------------
def solve_output_error(
    frf: FrfData,
    setup: TestSetup,
    *,
    response_weights: NDArray[np.floating] | None = None,
    input_keep: NDArray[np.bool_] | None = None,
    known: Mapping[str, float] | None = None,
    options: OutputErrorOptions | None = None,
    initial: DimResult | None = None,
    _depth: int = 0,
) -> OutputErrorResult:
    """Output-error DIM over the band of ``frf`` (module docstring).

    An item (sensor node or input) whose refined correction exceeds ``max_correction_sigma`` of
    its stated uncertainty is a gross error: it is left out and the solve repeated (at most
    ``max_gross_items`` times; ``gross_errors`` of the result lists them); beyond that the
    refinement is refused and the stated geometry used.

    Parameters
    ----------
    frf : FrfData
        FRFs of the analysis band (accelerances and load-cell reactions).
    setup : TestSetup
        The stated geometry and its ``geometry_uncertainty`` (priors).
    response_weights : ndarray, shape (n_acceleration_outputs,), optional
        0 drops a channel (selection); any positive value keeps it (the noise sets the weight).
    input_keep : ndarray of bool, shape (n_inputs,), optional
    known : dict, optional
        Known properties (``m`` kg, ``cx..cz`` GCS m, ``Ixx..Izz`` about P kg·m²).
    options : OutputErrorOptions
    initial : DimResult, optional
        Equation-error solution on the same data to start from (solved here if absent).

    Raises
    ------
    SolverError
        The start is not a physical mass matrix, or the fit does not converge to one.
    """
    t0 = time.perf_counter()
    opt = options or OutputErrorOptions()
    known = dict(known or {})
    geo = response_geometry(frf, setup)
    n_acc = geo.output_index.size
    wts = np.ones(n_acc) if response_weights is None else np.asarray(response_weights, float)
    if wts.shape != (n_acc,):
        raise SetupError(f"response_weights must hold {n_acc} values, one per accelerometer")
    keep_in = np.ones(len(frf.inputs), bool) if input_keep is None else np.asarray(input_keep)
    active = wts > 0
    in_idx = np.nonzero(keep_in)[0]
    p = setup.reference_point
    system = assemble(frf, setup, length_unit="m", response_weights=wts).select_inputs(in_idx)
    if initial is None:
        initial = solve_system(system, known=known, check_plausibility=False)
    x0 = initial.parameters.copy()
    x0[1:4] -= p
    # data in SI, relative to P
    H = frf.H[:, geo.output_index[active]][:, :, in_idx]  # (L, C, J)
    R = system.F - system.phi[None].astype(complex)  # (L, 6, J), N and N·m per N
    L_lines = H.shape[0]
    # |H|², its band mean and |Δ³H|² once: the noise, its floor, the line weights and the report
    h_power = np.abs(H) ** 2
    h_mean_power = np.mean(h_power, axis=0)  # (C, J)
    d3_power = _third_difference_power(H) if L_lines >= 8 else None
    sigma = estimate_noise(H, d3_power=d3_power)
    floor = 1e-6 * np.sqrt(h_mean_power)
    sigma = np.maximum(sigma, np.maximum(floor, 1e-300))
    cov_R = _reaction_noise_cov(R) if R.shape[0] >= 8 else np.zeros((len(in_idx), 6, 6))
    # the reactions' power against their own noise, per line and input:
    # S/N_ℓj = Σ_k |R_ℓkj|² / tr Σ_Rj (the share of lines at noise level is reported)
    with np.errstate(divide="ignore", invalid="ignore"):
        reaction_snr = np.sum(np.abs(R) ** 2, axis=1) / np.einsum("jii->j", cov_R)[None]
    R, n_rb = _smooth_reactions(R, frf.frequencies_hz, cov_R)
    cov_R = cov_R * n_rb[:, None, None]  # noise left in Σ_ω Re(R̂ R̂ᴴ) after the projection

    # geometry
    r0 = geo.positions_m[active] - p
    d0 = geo.directions[active]
    nodes_all = geo.nodes[active]
    nodes, node_of = np.unique(nodes_all, return_inverse=True)
    ex = {(e.node, e.direction): e for e in setup.excitations}
    rin0, din0 = [], []
    for j in in_idx:
        ch = frf.inputs[j]
        e = ex.get((ch.node, ch.direction)) or ex.get((ch.node, -ch.direction))
        assert e is not None and e.direction_gcs is not None  # assemble checked
        s = 1.0 if e.direction == ch.direction else -1.0
        rin0.append(np.asarray(e.position_m) - p)
        din0.append(s * np.asarray(e.direction_gcs))
    rin0_a, din0_a = np.asarray(rin0, float), np.asarray(din0, float)
    eb = np.empty((len(in_idx), 2, 3))
    for k, dv in enumerate(din0_a):
        a = _E[int(np.argmin(np.abs(dv)))]
        e1 = cross3(dv, a)
        e1 /= np.linalg.norm(e1)
        eb[k] = (e1, cross3(dv, e1))
    gu = setup.geometry_uncertainty
    nn, J = nodes.size, len(in_idx)
    sig_g = np.concatenate(
        [
            np.tile([np.deg2rad(gu.sensor_orientation_deg)] * 3 + [gu.sensor_position_m] * 3, nn),
            np.tile([np.deg2rad(gu.line_of_action_deg)] * 2 + [gu.input_position_m] * 2, J),
            # each accelerometer axis's sensitivity against its certificate (relative)
            np.full(int(active.sum()), setup.transducer_uncertainty.accel_sensitivity_rel),
        ]
    )
    cand = np.nonzero(sig_g > 0)[0] if opt.refine_geometry else np.zeros(0, np.intp)
    if opt.refine_geometry and not opt.refine_positions:
        cand = cand[~np.isin(cand % 6, (3, 4, 5)) | (cand >= 6 * nn)]
    free_x = np.array([i for i, k in enumerate(PARAMETERS) if k not in known], dtype=np.intp)
    x_fixed = x0.copy()
    for name, v in known.items():
        i = PARAMETERS.index(name)
        x_fixed[i] = v - p[i - 1] if 1 <= i <= 3 else v
    x_start = x_fixed.copy()
    x_start[free_x] = x0[free_x]
    if not np.all(np.linalg.eigvalsh(mass_matrix(x_start)[0]) > 0):
        raise SolverError(
            "the equation-error start is not a physical mass matrix (not positive definite); the "
            "output-error fit needs a plausible start: check the band and the data selection"
        )
    w_hi = 2 * np.pi * float(frf.frequencies_hz[-1])
    wn = 2 * np.pi * frf.frequencies_hz / w_hi
    basis = np.stack([wn**2, wn**4], axis=1).astype(complex)

    eps_r = setup.transducer_uncertainty.loadcell_matrix_rel if setup.load_cells else 0.0
    psi0 = np.concatenate([d0, cross3(r0, d0)], axis=1)
    phi0 = np.concatenate([din0_a, cross3(rin0_a, din0_a)], axis=1)
    A0 = np.asarray(np.linalg.inv(mass_matrix(x_start)[0]), dtype=np.float64)  # typed for mypy

    # from the measured noise and the load cells' certificate; the a posteriori variance factor
    # below scales the whole noise model, not the lines' relative weights
    lw0 = _line_weights(H, R, psi0, phi0, A0, eps_r, h_power=h_power, d3_power=d3_power)
    del h_power, d3_power

    def line_w(use_basis: bool = False) -> FloatArray | None:
        # with residual terms the projection is per channel over all lines: no line weights
        return None if use_basis else lw0

    # The reduced statistics depend on the data, the noise scale and the basis only, not on the
    # free geometry: fits that share them (the first fit, the gains-only fit of the geometry
    # test, the refits) reuse them. Keyed by the very arrays (sigma is rebound when rescaled).
    stats_memo: dict[bool, tuple[tuple[object, ...], tuple[FloatArray, FloatArray, float]]] = {}

    def build(use_basis: bool, free_g: NDArray[np.intp]) -> tuple[_Problem, float]:
        args = (H, R, sigma, cov_R, basis if use_basis else None, line_w(use_basis))
        memo = stats_memo.get(use_basis)
        if memo is not None and all(a is b for a, b in zip(memo[0], args, strict=True)):
            Ly, Lh, const = memo[1]
        else:
            Ly, Lh, const = _statistics(*args)
            stats_memo[use_basis] = (args, (Ly, Lh, const))
        return (
            _Problem(
                r0, d0, node_of, nodes, rin0_a, din0_a, eb, 1.0 / sigma, Ly, Lh,
                free_x, x_fixed, free_g, sig_g,
            ),
            const,
        )  # fmt: skip

    def fit(
        use_basis: bool, cands: NDArray[np.intp] | None = None
    ) -> tuple[_Problem, FloatArray, FloatArray, float, int, list[int]]:
        cand_ = cand if cands is None else cands
        prob, const = build(use_basis, cand_)
        theta0 = np.concatenate([x_start[free_x], np.zeros(cand_.size)])
        refused: list[int] = []
        if cand.size:
            _, J0 = prob.residual(theta0)
            assert J0 is not None
            post = np.linalg.pinv(J0.T @ J0)
            ratio = np.sqrt(np.clip(np.diag(post)[free_x.size :], 0, None))
            ok = ratio <= opt.refuse_ratio
            refused = [int(i) for i in cand_[~ok]]
            prob.free_g = cand_[ok]
            theta0 = np.concatenate([x_start[free_x], np.zeros(prob.free_g.size)])
            if opt.fix_gauge and prob.free_g.size:
                # the data rows of J0 in the columns kept: the Jacobian at theta0 of the items
                # kept, without computing it again (its data rows are the same numbers)
                cols = np.concatenate([np.arange(free_x.size), free_x.size + np.nonzero(ok)[0]])
                _gauge_constraint(
                    prob,
                    theta0,
                    opt.refuse_ratio,
                    fix_all=not opt.gauge_from_reactions,
                    data_jacobian=J0[: prob.Lh.size][:, cols],
                )
        theta, Jac, cost, it = _lm(prob, theta0, opt.max_iterations)
        return prob, theta, Jac, cost + const, it, refused

    rf_mode = opt.residual_flexibility
    n_data = 2 * L_lines * H.shape[1] * J
    n_rf = 2 * H.shape[1] * J
    prob, theta, Jac, _, it, refused = fit(False)
    variance_factor = 1.0
    refinement_note = ""
    if cand.size:
        # a posteriori variance factor: misfit the noise does not explain (elastic modes, errors
        # the model lacks) must not be absorbed by the geometry at the noise's weight
        for _ in range(2):
            c2 = (
                2
                * _direct_cost(prob, theta, H, R, sigma, None, line_w())
                / max(n_data - theta.size, 1)
            )
            if c2 <= 1.5:
                break
            sigma = sigma * np.sqrt(c2)
            variance_factor *= c2
            prob, theta, Jac, _, it, refused = fit(False)
        z = float(np.max(np.abs(theta[free_x.size :]), initial=0.0))
        if z > opt.max_correction_sigma and _depth < opt.max_gross_items:
            # one item far outside its stated uncertainty: a gross error the selection missed
            # (a bad impact, a mis-mounted sensor). Leave out the worst item and solve again.
            zfull = np.zeros(sig_g.size)
            zfull[prob.free_g] = np.abs(theta[free_x.size :])
            worst = int(np.argmax(zfull))
            w2 = wts.copy()
            k2 = np.asarray(keep_in, bool).copy()
            if worst >= 6 * nn + 4 * J:  # a channel's gain: leave its sensor node out
                worst = 6 * int(node_of[worst - 6 * nn - 4 * J])
            if worst < 6 * nn:
                node = int(nodes[worst // 6])
                w2[geo.nodes == node] = 0.0
                item = f"sensor node {node}"
            else:
                jj = int(in_idx[(worst - 6 * nn) // 4])
                k2[jj] = False
                item = f"input {frf.inputs[jj].name}"
            log.warning(
                "geometry refinement: %s needs a correction of %.1f σ of its stated uncertainty; "
                "left out as a gross error and solved again",
                item,
                z,
            )
            try:
                sub = solve_output_error(
                    frf,
                    setup,
                    response_weights=w2,
                    input_keep=k2,
                    known=known,
                    options=opt,
                    _depth=_depth + 1,
                )
            except (SolverError, SetupError) as err:
                log.warning("leaving out %s fails (%s); refinement refused instead", item, err)
            else:
                if sub.refine_geometry:
                    gross = {"item": item, "correction_sigma": z}
                    return replace(sub, gross_errors=[gross, *sub.gross_errors])
                # the refinement ends refused further down: the corrections that named this
                # item are not trusted either; keep every item and refuse here
                log.warning("leaving out %s does not save the refinement; all items kept", item)
        if z > opt.max_correction_sigma:
            refinement_note = (
                f"geometry refinement refused: corrections up to {z:.1f} σ of the stated "
                "uncertainty; the data disagree with the rigid-body model, not only with the "
                "stated geometry (check the band and the selection); stated geometry used"
            )
            log.warning(refinement_note)
            refused = [int(i) for i in cand]
            cand = np.zeros(0, np.intp)
            prob, theta, Jac, _cost, it, _ = fit(False)
    geometry_test: dict[str, Any] = {"tested": False}
    stated_theta: FloatArray | None = None
    keep_note = ""
    n_geo = 6 * nn + 4 * J
    if opt.geometry_test and cand.size and np.any(prob.free_g < n_geo):
        geometry_test, prob_g, theta_g = _geometry_needed(
            prob, theta, fit, cand, n_geo, H, R, sigma, line_w()
        )
        if not geometry_test["needed"]:
            # the stated geometry explains the data as well as the refined one: report the
            # estimate with the geometry as stated (the channels' gains refined); its intervals
            # are the refined fit's posterior widened by the difference of the two (below)
            stated_theta = theta.copy()
            stated_theta[: free_x.size] = theta_g[: free_x.size]
            where = {int(k): i for i, k in enumerate(prob_g.free_g)}
            for i, k in enumerate(prob.free_g):
                stated_theta[free_x.size + i] = (
                    0.0
                    if k < n_geo or int(k) not in where
                    else theta_g[free_x.size + where[int(k)]]
                )
            keep_note = (
                "stated value kept: the data do not need the geometry moved (likelihood ratio "
                f"{geometry_test['statistic']:.3g} ≤ {geometry_test['critical_value']:.3g}, "
                f"{geometry_test['dof']} dof); the refined fit's posterior and its difference "
                "to the stated-geometry estimate are in the intervals"
            )
    rf_info: dict[str, Any] = {"fitted": False, "mode": _rf_mode(rf_mode)}
    model_form: FloatArray | None = None
    if rf_mode is not False:
        # both models, each at its own solution
        prob_b, theta_b, Jac_b, _cost_b, it_b, refused_b = fit(True)
        theta_a, prob_a = theta, prob
        # Hausman test: under a rigid structure both fits are consistent and the one without
        # residual terms is efficient, so d = x_b − x_a has covariance V_b − V_a; a large
        # dᵀ (V_b − V_a)⁺ d says the residual terms change the properties beyond noise.
        ca = _direct_cost(prob_a, theta_a, H, R, sigma, None, line_w())
        cb = _direct_cost(prob_b, theta_b, H, R, sigma, basis)
        nx_ = free_x.size
        # one noise scale for both (the wider model's χ², consistent under either hypothesis)
        s2 = max(1.0, 2 * cb / max(n_data - n_rf - theta_b.size, 1))
        va = np.linalg.pinv(Jac.T @ Jac)[:nx_, :nx_] * s2
        vb = np.linalg.pinv(Jac_b.T @ Jac_b)[:nx_, :nx_] * s2
        dx = theta_b[:nx_] - theta_a[:nx_]
        lam_d, vec_d = np.linalg.eigh(vb - va)
        ok_d = lam_d > max(float(lam_d.max()), 0.0) * 1e-9
        if ok_d.any():
            hz = float(np.sum((vec_d[:, ok_d].T @ dx) ** 2 / lam_d[ok_d]))
            crit = _chi2_ppf(0.999, int(ok_d.sum()))
        else:  # no precision lost to the residual terms: nothing to test against
            hz, crit = 0.0, float("inf")
        needed = bool(hz > crit)
        rf_info.update(
            {
                "test": "Hausman (properties with and without residual terms), p = 0.001",
                "statistic": hz,
                "critical_value": crit,
                "chi2_reduced_without": 2 * ca / max(n_data - theta_a.size, 1),
                "chi2_reduced_with": 2 * cb / max(n_data - n_rf - theta_b.size, 1),
                "extra_parameters": int(n_rf),
                "needed": needed,
            }
        )
        if rf_mode is True or needed:
            prob, theta, Jac, it, refused = prob_b, theta_b, Jac_b, it_b, refused_b
            rf_info["fitted"] = True
            # which model is right the data cannot say beyond the test: the two fits' difference
            # is kept in the intervals as a model-form term (rank one, along dx). Without it the
            # residual terms on a rigid X-38 (realistic geometry, 2.5–50 Hz) moved the mass
            # −0.13 % and the CG 5 mm with intervals that missed on 5 seeds of 6, verdict ok
            model_form = dx
            rf_info["model_form_difference"] = [float(v) for v in dx]
        if rf_info["fitted"]:
            rf_info.update(_residual_size(prob, theta, H, R, sigma, basis))
    n_par = theta.size + (n_rf if rf_info["fitted"] else 0)
    dof = max(n_data - n_par, 1)
    # complex residuals: E|e/σ|² = 1 per 2 real data
    fitted_b = bool(rf_info["fitted"])
    lw_end = line_w(fitted_b)
    chi2 = 2.0 * _direct_cost(prob, theta, H, R, sigma, basis if fitted_b else None, lw_end) / dof
    N = Jac.T @ Jac
    N_inv: FloatArray = np.asarray(np.linalg.pinv(N), float)
    cov_theta = N_inv * max(1.0, chi2)
    nx0 = free_x.size
    robust = _input_robust_factors(prob, theta, Jac, cov_theta, nx0, N_inv)
    cov_theta[:nx0] *= robust[:, None]
    cov_theta[:, :nx0] *= robust[None, :]
    if model_form is not None:
        cov_theta[:nx0, :nx0] += np.outer(model_form, model_form)
    adequacy: dict[str, Any] = {"tested": False, "reason": "geometry not refined"}
    if stated_theta is not None:
        # the stated-geometry estimate, with the refined posterior widened by the difference
        # (rank one): both are consistent with the data (the test above), the truth lies within
        # the refined posterior, and the reported centre is the stated one
        dx_k = theta[:nx0] - stated_theta[:nx0]
        cov_theta[:nx0, :nx0] += np.outer(dx_k, dx_k)
        geometry_test["difference"] = [float(v) for v in -dx_k]
        theta = stated_theta
        adequacy = {"tested": False, "reason": "geometry kept as stated (geometry_test)"}
    elif prob.free_g.size and np.any(prob.free_g < n_geo):
        # the same data and noise scale with the stated geometry taken as exact
        prob_s, _ = build(rf_info["fitted"], np.zeros(0, np.intp))
        theta_s, _, _, _ = _lm(prob_s, np.asarray(x_start[free_x], float), opt.max_iterations)
        adequacy = _adequacy(prob, theta, Jac, theta_s, max(1.0, chi2))
        if adequacy["tested"] and not adequacy["passed"]:
            # a refined answer never silently replaces a stated one that disagrees with it:
            # the difference stays in the intervals (rank one, as for the residual terms)
            dx_s = np.asarray(adequacy["difference"], float)
            cov_theta[:nx0, :nx0] += np.outer(dx_s, dx_s)
            adequacy["model_form_added"] = True
    cov_noise_theta = np.linalg.pinv(N[:nx0, :nx0]) * max(1.0, chi2)  # geometry held fixed
    x = prob.full_x(theta)
    if not np.all(np.linalg.eigvalsh(mass_matrix(x)[0]) > 0):
        raise SolverError(
            "the output-error fit ended on a mass matrix that is not positive definite; the data "
            "do not support it: check the band, the selection and the stated geometry"
        )
    cov = np.zeros((10, 10))
    cov_noise = np.zeros((10, 10))
    nx = free_x.size
    cov[np.ix_(free_x, free_x)] = cov_theta[:nx, :nx]
    cov_noise[np.ix_(free_x, free_x)] = cov_noise_theta
    gauge_info: dict[str, Any] = {"fixed_modes": 0}
    if prob.gauge_rows.shape[0] and prob.gauge_modes.size:
        # the fixed gauge modes' prior variance, mapped to the properties (module docstring)
        Gw = prob.gauge_basis()[prob.free_g] / prob.sigma_g[prob.free_g][:, None]
        Gw = Gw[:, prob.gauge_live]
        V = prob.gauge_modes
        cov_a = np.linalg.inv(V.T @ Gw.T @ Gw @ V)
        Jg = gauge_property_jacobian(x)[:, prob.gauge_live] @ V  # (10, k)
        cov_gauge = Jg @ cov_a @ Jg.T
        cov[np.ix_(free_x, free_x)] += cov_gauge[np.ix_(free_x, free_x)]
        names = ["tx", "ty", "tz", "rx", "ry", "rz", "scale", "gain"]
        gauge_info = {
            "fixed_modes": int(V.shape[1]),
            "modes_live": [n for n, ok in zip(names, prob.gauge_live, strict=True) if ok],
            "data_to_prior_information": [float(v) for v in prob.gauge_information_ratio],
            "common_gain_fixed": bool(prob.gauge_live[7]),
        }
    if gu.registration_rms_m:
        for i in (1, 2, 3):
            if i in free_x:
                cov[i, i] += gu.registration_rms_m**2
    params = x.copy()
    params[1:4] += p
    g = prob.full_g(theta)
    se_g = np.zeros(sig_g.size)
    se_g[prob.free_g] = np.sqrt(np.clip(np.diag(cov_theta)[nx:], 0, None)) * sig_g[prob.free_g]
    sens, inps = _corrections(
        g,
        se_g,
        sig_g,
        prob,
        refused,
        frf.inputs,
        in_idx,
        opt.refine_geometry,
        refinement_note or keep_note,
    )
    new_setup = _refined_setup(setup, geo, active, prob, g, frf.inputs, in_idx, p)
    sig_rel = sigma / np.sqrt(h_mean_power)
    noise = {
        "method": "line-to-line scatter (third difference), per channel and input",
        "relative_median": float(np.median(sig_rel)),
        "relative_max": float(np.max(sig_rel)),
        "reaction_bias_compensated": bool(np.any(cov_R)),
        # load cells present: the share of lines × inputs whose reactions' power is within
        # REACTION_SNR_LOW of their noise (weighed by that noise in the fit, bias compensated,
        # not trusted as exact forces), and the median power / noise
        "reaction_lines_at_noise": (
            float(np.mean(~(reaction_snr > REACTION_SNR_LOW)))
            if setup.load_cells and reaction_snr.size
            else None
        ),
        "reaction_snr_median": (
            float(np.median(reaction_snr[np.isfinite(reaction_snr)]))
            if setup.load_cells and np.any(np.isfinite(reaction_snr))
            else None
        ),
        "chi2_reduced": float(chi2),
        "variance_factor": float(variance_factor),
        "chi2_reduced_stated_noise": float(chi2 * variance_factor),
        "input_robust_factor_max": float(robust.max(initial=1.0)),
    }
    if refinement_note:
        noise["refinement_refused"] = refinement_note
    gauge = (
        (
            f"inner constraint: {gauge_info['fixed_modes']} modes of the similarity of all "
            "sensors and inputs and of the common accelerometer gain, which the FRFs do not "
            "identify (data information below the prior's), carry no correction in the prior's "
            "metric: frame, scale and gain of the stated geometry and certificates; their prior "
            "variance is in the intervals"
        )
        if gauge_info["fixed_modes"]
        else (
            "frame of the stated geometry: the common rigid motion of all sensors and inputs, "
            "which the FRFs cannot see, is held by the priors at a precision-weighted mean "
            "correction of zero; its uncertainty is in the CG interval"
        )
    )
    return OutputErrorResult(
        parameters=params,
        covariance=cov,
        covariance_noise=cov_noise,
        chi2_reduced=float(chi2),
        iterations=int(it),
        elapsed_s=time.perf_counter() - t0,
        sensor_corrections=sens,
        input_corrections=inps,
        residual_flexibility=rf_info,
        noise=noise,
        gauge=gauge,
        setup=new_setup,
        refine_geometry=opt.refine_geometry and not refinement_note,
        n_inputs=J,
        response_weights=wts,
        input_keep=np.asarray(keep_in, bool),
        extras={"gauge": gauge_info, "adequacy": adequacy, "geometry_test": geometry_test},
    )


#: Significance of the refinement's adequacy test (:func:`_adequacy`) and of the test that the
#: geometry needs moving (:func:`_geometry_needed`).
ADEQUACY_P = 0.001


def _geometry_needed(
    prob: _Problem,
    theta: FloatArray,
    fit: Any,
    cand: NDArray[np.intp],
    n_geo: int,
    H: ComplexArray,
    R: ComplexArray,
    sigma: FloatArray,
    lw: FloatArray | None,
) -> tuple[dict[str, Any], _Problem, FloatArray]:
    """Do the data need the geometry moved, or do the channels' gains explain them as well?

    Nested models at the same noise scale: the refined fit (geometry and gains) against the fit
    with the channel gains alone (geometry as stated). Their likelihood ratio
    ``Λ = 2 (C_gains − C_full)`` (whitened costs, priors included: ``E|e/σ|² = 1`` per complex
    datum, hence the factor 2) is ``χ²(k)`` under the stated geometry, ``k`` the free geometry
    corrections less the gauge constraints, *if the misfit were white*. A measured test's misfit
    is not: calibration errors and unmodelled transducer dynamics are smooth along the lines, and
    a misfit correlated over the band moves the cost of every line together. So ``Λ`` is scaled
    by ``n_eff / L`` (:func:`effective_lines` of the refined fit's residual): a misfit constant
    over the band counts once per channel and input, white noise on every line. Measured on
    acquired calibration-mass sets (exact geometry): ``Λ`` 116–180 for k = 136; with the realistic
    scenario's geometry errors (2 mm, 0.5°, 1°): 2·10⁵–8·10⁵.

    Returns the test, and the gains-only problem and solution.
    """
    res_f, _ = prob.residual(theta, jacobian=False)
    prob_g, theta_g, _, _, _, _ = fit(False, cand[cand >= n_geo])
    res_g, _ = prob_g.residual(theta_g, jacobian=False)
    raw = 2.0 * (float(res_g @ res_g) - float(res_f @ res_f))
    L = H.shape[0]
    n_eff = effective_lines(_line_residual(prob, theta, H, R, sigma, lw))
    lr = raw * n_eff / L
    k = max(int(np.sum(prob.free_g < n_geo)) - int(prob.gauge_rows.shape[0]), 1)
    crit = _chi2_ppf(1.0 - ADEQUACY_P, k)
    return (
        {
            "tested": True,
            "test": (
                "likelihood ratio, refined geometry against channel gains alone, scaled by the "
                f"effective lines of the misfit ({n_eff:.3g} of {L}), p = {ADEQUACY_P:g}"
            ),
            "statistic": lr,
            "statistic_white": raw,
            "effective_lines": n_eff,
            "dof": k,
            "critical_value": crit,
            "needed": bool(lr > crit),
        },
        prob_g,
        theta_g,
    )


def _adequacy(
    prob: _Problem,
    theta: FloatArray,
    Jac: FloatArray,
    theta_s: FloatArray,
    scale: float,
) -> dict[str, Any]:
    """Does the refinement move the properties only as far as the stated geometry's uncertainty
    allows? (Hausman test of the refined against the stated-geometry estimate.)

    Linearised at the refined solution, with the data rows ``J_x, J_g`` (properties, whitened
    geometry corrections) and the gauge-constrained prior ``g ~ N(0, P)``,
    ``P = I − Rᵀ(RRᵀ)⁺R`` (``R`` the gauge rows): the stated-geometry estimate
    ``x_s = N_xx⁻¹ J_xᵀ y`` has covariance ``V_s = s² N_xx⁻¹ + K P Kᵀ``, ``K = N_xx⁻¹ J_xᵀ J_g``
    (noise plus the geometry's stated uncertainty it ignores), and the refined one, efficient
    under the model, ``V_r = s² [(JᵀJ)⁻¹]_xx``. If the misfit is geometry within its priors,
    ``d = x_r − x_s`` has covariance ``V_s − V_r`` and ``h = dᵀ(V_s − V_r)⁺d ~ χ²(rank)``. A
    large ``h`` says the refinement explained a misfit that is not geometry within its stated
    uncertainty (channel calibration, a load-cell chain, a model the rigid body lacks) by moving
    the sensors: the refined answer cannot silently replace the stated one. The covariances are
    the model's (noise scaled by the reduced χ²), not the input-clustered sandwich's: the
    sandwich widens both where the misfit is correlated within the inputs and would hide exactly
    the disagreement looked for (a calibration mass standing on its cell, band just above the
    support modes: the refinement moved the mass 15 % and the sandwich's test passed at 7.7; the
    model's gave 356 against 29.6, while acquired and model-FRF rigid cases gave 2–11).

    Returns
    -------
    dict
        ``tested``, ``statistic``, ``dof``, ``critical_value`` (at :data:`ADEQUACY_P`),
        ``passed``, ``difference`` (``x_r − x_s`` of the free properties, SI relative to P).
    """
    nx = prob.free_x.size
    n_data = prob.Lh.size
    Jx, Jg = Jac[:n_data, :nx], Jac[:n_data, nx:]
    Nxx_inv = np.linalg.pinv(Jx.T @ Jx)
    K = Nxx_inv @ (Jx.T @ Jg)
    Rg = prob.gauge_rows
    P = np.eye(Jg.shape[1])
    if Rg.shape[0]:
        P -= Rg.T @ np.linalg.pinv(Rg @ Rg.T) @ Rg
    Vs = scale * Nxx_inv + K @ P @ K.T
    Vr = scale * np.linalg.pinv(Jac.T @ Jac)[:nx, :nx]
    D = Vs - Vr
    d = theta[:nx] - theta_s[:nx]
    lam, vec = np.linalg.eigh(0.5 * (D + D.T))
    ok = lam > max(float(lam.max(initial=0.0)), 0.0) * 1e-9
    if not ok.any():
        return {"tested": False, "reason": "the refinement changes nothing the data can test"}
    h = float(np.sum((vec[:, ok].T @ d) ** 2 / lam[ok]))
    dof = int(ok.sum())
    crit = _chi2_ppf(1.0 - ADEQUACY_P, dof)
    return {
        "tested": True,
        "test": f"Hausman (refined against stated geometry), p = {ADEQUACY_P:g}",
        "statistic": h,
        "dof": dof,
        "critical_value": crit,
        "passed": bool(h <= crit),
        "difference": [float(v) for v in d],
        "free_parameters": [PARAMETERS[i] for i in prob.free_x],
    }


def _input_robust_factors(
    prob: _Problem,
    theta: FloatArray,
    Jac: FloatArray,
    cov: FloatArray,
    nx: int,
    N_inv: FloatArray | None = None,
) -> FloatArray:
    """Per free property, ``max(1, σ_robust / σ_model)``: the input-clustered sandwich against the
    model-based posterior.

    The posterior ``N⁻¹ = (JᵀJ)⁻¹`` (× the reduced χ²) holds when the misfit is independent noise
    on every line and channel. A misfit the rigid model lacks (the stiffness-line residual of an
    elastic mode near the band, a support it does not see) is smooth along the lines and
    correlated over an input's channels, and its effect on the estimate is far larger than the
    same misfit as white noise. The inputs are independent experiments, so the cluster-robust
    (Liang–Zeger) covariance holds whatever the correlation within one input:

        V = N⁻¹ (Σ_j (s_j − s̄)(s_j − s̄)ᵀ · J/(J−1) + J_pᵀJ_p) N⁻¹,   s_j = J_jᵀ r_j

    with ``s_j`` input ``j``'s score (the gradient of its cost: rows of the data residual and
    Jacobian that belong to it, :meth:`_Problem.residual`), centred (the priors' pull balances
    their sum at the MAP), and ``J_pᵀJ_p`` the priors' own (their scores have unit variance; the
    gauge constraint rows carry none). Where a property's ``V`` exceeds the model-based variance,
    its row and column of the covariance are scaled up to it (correlations kept); never down:
    with ~20 inputs the robust variance is itself known only to ±30 %.

    Returns
    -------
    ndarray, shape (nx,)
        Factors ``≥ 1`` for the rows and columns of the free properties' covariance.
    """
    J_ = prob.Lh.shape[0]
    if J_ < 3:
        return np.ones(nx)
    n_data = prob.Lh.size
    res, _ = prob.residual(theta, jacobian=False)
    Jd = Jac[:n_data].reshape(J_, -1, Jac.shape[1])
    sc = np.einsum("jrp,jr->jp", Jd, res[:n_data].reshape(J_, -1))
    sc = sc - sc.mean(axis=0)
    n_g = prob.free_g.size
    Jp = Jac[n_data : n_data + n_g]
    B = sc.T @ sc * (J_ / (J_ - 1)) + Jp.T @ Jp
    Ninv = np.linalg.pinv(Jac.T @ Jac) if N_inv is None else N_inv  # the caller's, if formed
    V = Ninv @ B @ Ninv
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.diag(V)[:nx] / np.diag(cov)[:nx]
    return np.asarray(np.sqrt(np.where(np.isfinite(ratio), np.maximum(ratio, 1.0), 1.0)), float)


def _line_residual(
    prob: _Problem,
    theta: FloatArray,
    H: ComplexArray,
    R: ComplexArray,
    sigma: FloatArray,
    lw: FloatArray | None = None,
) -> ComplexArray:
    """``w (H − Ĥ)/σ`` on every line, channel and input (L, C, J), read-only.

    The last one is kept on ``prob`` (with references to the arrays it came from, so that their
    identities stay theirs): asked again for the same θ, free items and arrays, it is returned
    as it is instead of computed anew."""
    key = (theta.tobytes(), prob.free_g.tobytes(), id(H), id(R), id(sigma), id(lw))
    memo = prob.line_residual_memo
    if memo is not None and memo[0] == key:
        return memo[2]
    x = prob.full_x(theta)
    gfull = prob.full_g(theta)
    r, d, rin, din = prob.geometry(gfull)
    A = np.linalg.inv(mass_matrix(x)[0])
    psi = np.concatenate([d, cross3(r, d)], axis=1)
    psi = psi * (1.0 + gfull[gfull.size - psi.shape[0] :])[:, None]
    phi = np.concatenate([din, cross3(rin, din)], axis=1)
    mot = A @ (phi.T[None] + R)  # (L, 6, J)
    # Ψ (real) times the motions as one real product on their (re, im) view, and 1/σ as a
    # product: numpy's complex matmul and division give these numbers (up to the sign of a zero)
    pred = (psi @ mot.view(np.float64)).view(np.complex128)
    e = (H - pred) * (1.0 / sigma)[None]
    if lw is not None:
        e = e * lw[:, None, :]
    e.flags.writeable = False
    prob.line_residual_memo = (key, (H, R, sigma, lw), e)
    return e


def _direct_cost(
    prob: _Problem,
    theta: FloatArray,
    H: ComplexArray,
    R: ComplexArray,
    sigma: FloatArray,
    basis: ComplexArray | None,
    lw: FloatArray | None = None,
) -> float:
    """``Σ w²|H − Ĥ|²/σ²`` over every line, channel and input (residual terms projected out when
    ``basis`` is given; ``w`` the line weights, 1 when absent): the data cost without the bias
    compensation, for χ² and the test."""
    e = _line_residual(prob, theta, H, R, sigma, lw)
    if basis is not None:
        Bs = np.concatenate([basis.real, basis.imag], axis=0)  # (2L, nb)
        es = np.concatenate([e.real, e.imag], axis=0).reshape(2 * e.shape[0], -1)
        Q, _ = np.linalg.qr(Bs)
        es = es - Q @ (Q.T @ es)
        return float(np.sum(es**2))
    memo = prob.line_residual_memo
    if memo is not None and memo[2] is e and len(memo) > 3:
        return float(memo[3])  # this residual's sum, already formed
    cost = float(np.sum(np.abs(e) ** 2))
    if memo is not None and memo[2] is e:
        prob.line_residual_memo = (*memo[:3], cost)
    return cost


def effective_lines(e: ComplexArray) -> float:
    """How many independent lines a misfit along the lines is worth (AR(1) approximation).

    With ``ρ`` the lag-one autocorrelation of the residual along the lines (real and imaginary
    parts of every channel and input, each about its mean; the median over them),
    ``n_eff = L (1 − ρ)/(1 + ρ)``, between 1 and ``L``: white noise counts every line; a misfit
    smooth over the band (a transducer's roll-off, an unmodelled trend) counts as the few
    independent lines it is. (The integrated autocorrelation time of the initial positive
    sequence gives 2–3 times more lines on acquired calibration-mass sets: the misfit there is
    not AR(1); the test below was measured with this one.)
    """
    L = e.shape[0]
    if L < 3:
        return float(L)
    x = np.concatenate([e.real, e.imag], axis=1).reshape(L, -1)
    x = x - x.mean(axis=0)
    den = np.sum(x * x, axis=0)
    ok = den > 0
    if not ok.any():
        return float(L)
    rho = np.sum(x[1:] * x[:-1], axis=0)[ok] / den[ok]
    r = float(np.clip(np.median(rho), -0.99, 0.999))
    return float(np.clip(L * (1 - r) / (1 + r), 1.0, L))


def _rf_mode(mode: bool | None) -> str:
    return "auto" if mode is None else ("on" if mode else "off")


def _residual_size(
    prob: _Problem,
    theta: FloatArray,
    H: ComplexArray,
    R: ComplexArray,
    sigma: FloatArray,
    basis: ComplexArray,
) -> dict[str, Any]:
    """Fitted residual terms: RMS of ``G b(ω)`` relative to the RMS of the FRFs, median and max
    over channels and inputs."""
    x = prob.full_x(theta)
    r, d, rin, din = prob.geometry(prob.full_g(theta))
    A = np.linalg.inv(mass_matrix(x)[0])
    psi = np.concatenate([d, cross3(r, d)], axis=1)
    phi = np.concatenate([din, cross3(rin, din)], axis=1)
    mot = np.einsum("ab,ljb->lja", A, phi[None] + np.moveaxis(R, 1, 2))  # (L, J, 6)
    rigid = np.einsum("ca,lja->lcj", psi, mot)
    e = H - rigid
    Bm = basis.real  # (L, nb)
    coef = np.linalg.lstsq(Bm, np.real(e).reshape(e.shape[0], -1), rcond=None)[0]
    fitted = (Bm @ coef).reshape(e.shape)
    rel = np.sqrt(np.mean(fitted**2, axis=0)) / np.sqrt(np.mean(np.abs(H) ** 2, axis=0))
    return {
        "relative_rms_median": float(np.median(rel)),
        "relative_rms_max": float(np.max(rel)),
        "basis": "(ω/ω_hi)², (ω/ω_hi)⁴ per channel and input",
    }


def _corrections(
    g: FloatArray,
    se: FloatArray,
    sig: FloatArray,
    prob: _Problem,
    refused: list[int],
    inputs: tuple[Channel, ...],
    in_idx: NDArray[np.intp],
    refine: bool,
    note: str,
) -> tuple[list[dict[str, Any]], list[dict[str, Any]]]:
    nn = prob.n_nodes
    free = set(int(i) for i in prob.free_g)
    ref = set(refused)

    def status(idx: list[int]) -> tuple[bool, str]:
        if not refine:
            return False, "geometry refinement off: stated value used"
        if note:
            return False, note
        if all(i in free for i in idx):
            return True, "estimated"
        if any(i in ref for i in idx):
            return False, (
                "not identified by the data (posterior σ above the stated prior's "
                "refuse ratio): stated value kept"
            )
        return False, "no stated uncertainty (prior σ = 0): stated value kept"

    sens = []
    for n in range(nn):
        b = 6 * n
        ok_r, why_r = status(list(range(b, b + 3)))
        ok_p, why_p = status(list(range(b + 3, b + 6)))
        sens.append(
            {
                "node": int(prob.nodes[n]),
                "rotation_deg": np.rad2deg(g[b : b + 3]).tolist(),
                "rotation_se_deg": np.rad2deg(se[b : b + 3]).tolist(),
                "rotation_prior_deg": float(np.rad2deg(sig[b])),
                "rotation_status": why_r,
                "rotation_estimated": ok_r,
                "offset_mm": (1e3 * g[b + 3 : b + 6]).tolist(),
                "offset_se_mm": (1e3 * se[b + 3 : b + 6]).tolist(),
                "offset_prior_mm": float(1e3 * sig[b + 3]),
                "offset_status": why_p,
                "offset_estimated": ok_p,
            }
        )
    inps = []
    for k, j in enumerate(in_idx):
        b = 6 * nn + 4 * k
        ok_d, why_d = status([b, b + 1])
        ok_o, why_o = status([b + 2, b + 3])
        inps.append(
            {
                "node": int(inputs[j].node),
                "direction": int(inputs[j].direction),
                "line_of_action_deg": float(np.rad2deg(np.hypot(g[b], g[b + 1]))),
                "line_of_action_components_deg": np.rad2deg(g[b : b + 2]).tolist(),
                "line_of_action_se_deg": np.rad2deg(se[b : b + 2]).tolist(),
                "line_of_action_status": why_d,
                "line_of_action_estimated": ok_d,
                "offset_mm": float(1e3 * np.hypot(g[b + 2], g[b + 3])),
                "offset_components_mm": (1e3 * g[b + 2 : b + 4]).tolist(),
                "offset_se_mm": (1e3 * se[b + 2 : b + 4]).tolist(),
                "offset_status": why_o,
                "offset_estimated": ok_o,
            }
        )
    return sens, inps


def _refined_setup(
    setup: TestSetup,
    geo: Any,
    active: NDArray[np.bool_],
    prob: _Problem,
    g: FloatArray,
    inputs: tuple[Channel, ...],
    in_idx: NDArray[np.intp],
    p: FloatArray,
) -> TestSetup:
    """The setup with the refined sensor (all channels of a refined node) and input geometry."""
    nn = prob.n_nodes
    gs = g[: 6 * nn].reshape(nn, 6)
    by_node = {int(n): gs[i] for i, n in enumerate(prob.nodes)}
    responses = []
    for c in setup.responses:
        corr = by_node.get(int(c.node))
        if corr is None:
            responses.append(c)
            continue
        d = apply_rotvec(corr[:3], np.asarray(c.direction_gcs))
        responses.append(
            c.model_copy(
                update={
                    "direction_gcs": tuple(float(v) for v in d / np.linalg.norm(d)),
                    "position_m": tuple(float(v) for v in np.asarray(c.position_m) + corr[3:]),
                }
            )
        )
    _, _, rin, din = prob.geometry(g)
    moved = {}
    for k, j in enumerate(in_idx):
        ch = inputs[j]
        moved[(ch.node, abs(ch.direction))] = (rin[k] + p, din[k], ch.direction)
    excitations = []
    for e in setup.excitations:
        hit = moved.get((e.node, abs(e.direction)))
        if hit is None:
            excitations.append(e)
            continue
        pos, dv, rec_dir = hit
        s = 1.0 if rec_dir == e.direction else -1.0
        excitations.append(
            e.model_copy(
                update={
                    "position_m": tuple(float(v) for v in pos),
                    "direction_gcs": tuple(float(v) for v in s * dv / np.linalg.norm(dv)),
                }
            )
        )
    return setup.model_copy(
        update={"responses": tuple(responses), "excitations": tuple(excitations)}
    )
