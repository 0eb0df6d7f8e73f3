"""Mass-line (inertia-restraint) estimate: a second estimator of m, CG and I beside the DIM.

Model
-----
On the mass line a free rigid body obeys ``M ẍ_P = F_P``, so the measured accelerances
(responses × inputs) at every line ω of the band are

    A(ω) ≈ Ψ G F(ω),    G = M⁻¹ (6×6, symmetric),    F(ω) = Φ + R(ω),

with Ψ (n×6) the rigid-body shape matrix of the response channels (rows ``[dᵀ, ((r − P) × d)ᵀ]``,
:func:`dimacq.pipeline.rigid_body.response_matrix`), Φ (6×J) the inputs' unit force vectors at P
(columns ``[d; (r − P) × d]``) and R(ω) (6×J) the measured load-cell reactions per unit input
mapped to P (zero without load cells; they enter as extra forces, as in the DIM).
``Ψ G F`` is linear in the 21 unique entries ``g`` of the symmetric ``G``:
``vec(Ψ G f) = (fᵀ ⊗ Ψ) D g`` (``D`` the 36×21 duplication matrix), so ``g`` is a weighted linear
least squares over every line, input, channel and both real and imaginary parts:

    ĝ = argmin Σ_ω Σ_j Σ_i w_ij |A_ij(ω) − (Ψ G F_j(ω))_i|²,

with the normal matrix ``N = Dᵀ [Σ_j Re(Σ_ω F̄_j F_jᵀ) ⊗ ΨᵀW_jΨ] D`` built from band sums
(the per-line loop never happens). ``w_ij = w_i = 1/σ²_i`` with ``σ²_i`` the residual power of
channel i (over its inputs and lines) in a first, unweighted pass: a sensor's noise floor, and a
channel that does not follow the model is weighted down as noise would be. (Weights per channel
*and input* were tried: with FRF noise relative to each FRF they follow each FRF's size, put the
small cross terms first, and those are the ones the stated geometry's errors dominate — the
mass's spread over the line-of-action priors was 1.05 % against 0.30 % with one weight per
channel.) Exact data (residuals at round-off) are not weighted. Rotational coordinates are scaled by the RMS
distance ℓ of the channels from P, so that ``G`` is fitted in one unit (1/kg).

Reading the properties: ``M = Ĝ⁻¹ = [[M11, M12], [M21, M22]]``; a rigid body has
``M11 = m E``, ``M21 = m [c]x`` and ``M22 = I_P`` (the DIM's ``F = m a − m [c]x α``,
``M = m [c]x a + I α``). So ``m = tr(M11)/3``, ``m c = vee(skew(M21))`` and ``I_P = M22``, and
``I_CG = I_P − m(|c|² E − c cᵀ)``. The 11 remaining numbers (the deviatoric part of M11 and
the symmetric part of M21) are zero for a rigid body with the right geometry: their χ² against
their covariance (:attr:`MassLineFit.structure_chi2`, 11 degrees of freedom) is a test of the
model the DIM imposes.

Why this estimator and why it is independent of the DIM's assumptions
----------------------------------------------------------------------
The DIM condenses the responses to the motion of P first (``K = Ψ⁺ A``), then fits the ten
rigid-body parameters of the force-sum / inertia equation ``F = M(x) K`` with the measured
motion as regressor. Here the roles are reversed: the forces are the regressors and the measured
accelerances the outputs (no condensation, residuals in measured units per channel, so the noise
is where the model puts it), and the inverse mass matrix is fitted *without* the rigid-body
structure: 21 free numbers, not 10. It shares with the DIM only the data and the stated geometry
(Ψ, Φ and the load-cell transforms), none of its estimator: not the equation-error / output-error
fit, the geometry self-calibration, its priors or its gross-error search. A mis-mounted sensor or
a wrong line of action biases the two differently, and breaks the rigid structure of the fitted
``M``. It is the mass-line method of the commercial rigid-body calculators (FEMtools RBPE,
Simcenter Testlab), the "inertia restraint" of Almeida, Urgueira & Maia (2008).

The modal-model method (mass properties from the rigid-body modes of a fitted modal model,
SDynPy's ``rigid_body_shape_scaling``) was not chosen: it needs suspension modes in the data and a
pole-residue fit (a stabilisation choice) before any property is read, it is undefined on
free-free model FRFs, and its rigid-body modes come from the same accelerances on the same
geometry, so it adds a modal fitter's assumptions without removing any the mass line shares with
the DIM.

Uncertainty
-----------
Three sources, each on the derived quantities ``q = [m, CG, I_P (6), I_CG (6), principal (3)]``:
noise, by first-order propagation of ``Cov(ĝ) = N⁻¹ χ²/(ν)`` through the reading (central
differences); the delete-one-input jackknife (inputs are independent experiments; it holds
misfit correlated along the lines of one input); and the stated geometry and transducer
uncertainty by Monte Carlo (the same model as
:func:`dimacq.pipeline.uncertainty.geometry_spread`: per sensor node a shift and a rotation,
per input a shift and a turn of its line of action, per channel a sensitivity, one force
sensitivity). Variance = max(noise, jackknife) + geometry. With a ``companion`` estimator (the
joint DIM, :func:`mass_line_from_frf` ``dim_companion=True``) solved on the same geometry
samples, the spread of the *difference* is reported too
(:attr:`MassLineFit.se_geometry_difference`): the stated geometry moves both estimators alike, and
a comparison of the two should hold only what it moves differently.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from dimacq.errors import SetupError, SolverError
from dimacq.model.frf import FrfData
from dimacq.model.setup import TestSetup
from dimacq.pipeline._batched import cross3, real_apply
from dimacq.pipeline.rotations import rotvec_to_matrix

__all__ = [
    "QUANTITIES",
    "MassLineFit",
    "data_band_sums",
    "mass_line_fit",
    "mass_line_from_frf",
    "normal_equations",
    "quantities_from_parameters",
    "read_mass_matrix",
]

#: A second estimator evaluated on the same geometry samples: (positions (S, n, 3), directions
#: (S, n, 3), input positions (S, J, 3), input directions (S, J, 3)) → quantities (S, 19).
Companion = Callable[
    [NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]],
    NDArray[np.float64],
]

FloatArray = NDArray[np.float64]
ComplexArray = NDArray[np.complex128]

#: Names of the derived quantities, in the order of :attr:`MassLineFit.values`.
QUANTITIES: tuple[str, ...] = (
    "m",
    "cx",
    "cy",
    "cz",
    "Ixx_p",
    "Ixy_p",
    "Ixz_p",
    "Iyy_p",
    "Iyz_p",
    "Izz_p",
    "Ixx_cg",
    "Ixy_cg",
    "Ixz_cg",
    "Iyy_cg",
    "Iyz_cg",
    "Izz_cg",
    "I1",
    "I2",
    "I3",
)

_IU = np.triu_indices(6)
_I3 = ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))


def _duplication() -> FloatArray:
    """36×21: ``vec(G) = D g`` (column-major vec, ``g`` the upper triangle row by row)."""
    d = np.zeros((36, 21))
    for k, (i, j) in enumerate(zip(*_IU, strict=True)):
        d[i + 6 * j, k] = 1.0
        d[j + 6 * i, k] = 1.0
    return d


_DUP = _duplication()


def _sym(g: NDArray[Any]) -> NDArray[Any]:
    """(..., 21) → symmetric (..., 6, 6)."""
    out = np.zeros(g.shape[:-1] + (6, 6))
    out[..., _IU[0], _IU[1]] = g
    out[..., _IU[1], _IU[0]] = g
    return out


def read_mass_matrix(M: NDArray[np.floating]) -> tuple[FloatArray, FloatArray]:
    """Rigid-body properties read from 6×6 mass matrices about P, and their structure misfit.

    Parameters
    ----------
    M : ndarray, shape (..., 6, 6)
        In SI units (kg, kg·m, kg·m²), about P.

    Returns
    -------
    q : ndarray, shape (..., 19)
        ``[m, c (3, relative to P), I_P (6), I_CG (6), principal moments (3, ascending)]``.
    structure : ndarray, shape (..., 11)
        Deviatoric part of M11 (5: ``M11 − mE`` upper triangle less one diagonal) and the
        symmetric part of M21 (6), zero for a rigid body.
    """
    M = np.asarray(M, float)
    M = 0.5 * (M + np.swapaxes(M, -1, -2))
    m11, m21, m22 = M[..., :3, :3], M[..., 3:, :3], M[..., 3:, 3:]
    m = np.trace(m11, axis1=-2, axis2=-1) / 3.0
    k = 0.5 * (m21 - np.swapaxes(m21, -1, -2))
    s = np.stack([k[..., 2, 1], k[..., 0, 2], k[..., 1, 0]], axis=-1)
    c = s / m[..., None]
    cc = np.einsum("...i,...j->...ij", c, c)
    shift = m[..., None, None] * (
        np.einsum("...i,...i->...", c, c)[..., None, None] * np.eye(3) - cc
    )
    icg = m22 - shift
    ip6 = np.stack([m22[..., i, j] for i, j in _I3], axis=-1)
    icg6 = np.stack([icg[..., i, j] for i, j in _I3], axis=-1)
    pm = np.linalg.eigvalsh(0.5 * (icg + np.swapaxes(icg, -1, -2)))
    q = np.concatenate([m[..., None], c, ip6, icg6, pm], axis=-1)
    dev = m11 - m[..., None, None] * np.eye(3)
    sym21 = 0.5 * (m21 + np.swapaxes(m21, -1, -2))
    structure = np.concatenate(
        [
            np.stack(
                [dev[..., 0, 0], dev[..., 1, 1], dev[..., 0, 1], dev[..., 0, 2], dev[..., 1, 2]], -1
            ),
            np.stack([sym21[..., i, j] for i, j in _I3], axis=-1),
        ],
        axis=-1,
    )
    return q, structure


def quantities_from_parameters(x: NDArray[np.floating], p: NDArray[np.floating]) -> FloatArray:
    """DIM parameters ``[m, CG (GCS), I_P (6)]`` (..., 10) → :data:`QUANTITIES` (..., 19)."""
    x = np.asarray(x, float)
    m, cg, ip6 = x[..., 0], x[..., 1:4], x[..., 4:10]
    c = cg - np.asarray(p, float)
    ip = np.zeros(x.shape[:-1] + (3, 3))
    for k, (i, j) in enumerate(_I3):
        ip[..., i, j] = ip6[..., k]
        ip[..., j, i] = ip6[..., k]
    shift = m[..., None, None] * (
        np.einsum("...i,...i->...", c, c)[..., None, None] * np.eye(3)
        - np.einsum("...i,...j->...ij", c, c)
    )
    icg = ip - shift
    icg6 = np.stack([icg[..., i, j] for i, j in _I3], axis=-1)
    pm = np.linalg.eigvalsh(icg)
    out: FloatArray = np.concatenate([x[..., :10], icg6, pm], axis=-1)
    return out


@dataclass(frozen=True, eq=False)
class MassLineFit:
    """The mass-line estimate with its uncertainty and its evidence.

    Attributes
    ----------
    values : ndarray, shape (19,)
        :data:`QUANTITIES`: ``m`` (kg), CG in the GCS (m), I about P and about the CG
        (``Ixx, Ixy, Ixz, Iyy, Iyz, Izz``, tensor elements, kg·m²), principal moments (kg·m²).
    se : ndarray, shape (19,)
        Standard errors: ``sqrt(max(se_noise², se_inputs²) + se_geometry²)``.
    se_noise, se_inputs, se_geometry : ndarray, shape (19,)
    mass_matrix : ndarray, shape (6, 6)
        ``Ĝ⁻¹`` about P, SI units.
    structure_rel : float
        Size of the non-rigid part of the fitted mass matrix: ``‖dev M11‖/m`` and
        ``‖sym M21‖/(m ℓ)`` combined (root sum of squares).
    structure_chi2 : float
        χ² of the 11 non-rigid numbers against their covariance (noise or input jackknife,
        whichever is larger, plus the stated geometry's): 11 degrees of freedom; large when the
        data are not a rigid body seen through the stated geometry within its uncertainty.
    residual_rel : float
        ``‖A − Ψ Ĝ F‖ / ‖A‖`` over the band (unweighted).
    condition_number : float
        Of the equilibrated normal matrix (square root: that of the design).
    n_lines, n_channels, n_inputs : int
    length_scale_m : float
        ℓ, the RMS distance of the channels from P.
    reference_point_m : ndarray, shape (3,)
    jackknife : ndarray, shape (n_inputs, 19)
        The leave-one-input-out values.
    geometry_samples : int
    se_geometry_difference : ndarray, shape (19,), optional
        Spread over the same geometry samples of the difference between this estimate and the
        companion estimator's (the DIM on the same stated geometry): the part of the geometry
        uncertainty the two do not share. None without a companion.
    """

    values: FloatArray
    se: FloatArray
    se_noise: FloatArray
    se_inputs: FloatArray
    se_geometry: FloatArray
    mass_matrix: FloatArray
    structure_rel: float
    structure_chi2: float
    residual_rel: float
    condition_number: float
    n_lines: int
    n_channels: int
    n_inputs: int
    length_scale_m: float
    reference_point_m: FloatArray
    jackknife: FloatArray
    geometry_samples: int
    se_geometry_difference: FloatArray | None = None

    def value(self, name: str) -> float:
        return float(self.values[QUANTITIES.index(name)])

    def std(self, name: str) -> float:
        return float(self.se[QUANTITIES.index(name)])


@dataclass(frozen=True)
class _Sums:
    """Band sums per input that make the normal equations a function of the geometry only."""

    n_lines: int
    sum_r: ComplexArray  # (J, 6)  Σ_ω R_j
    rr: FloatArray  # (J, 6, 6)  Re Σ_ω R̄_j R_jᵀ
    sum_a: ComplexArray  # (J, n)  Σ_ω A_·j
    ar: ComplexArray  # (J, n, 6)  Σ_ω A_·j R_jᴴ


def data_band_sums(H: ComplexArray, R: ComplexArray) -> _Sums:
    """The data's band sums per input (:class:`_Sums`) from the FRFs ``H`` (lines, n, J) and
    the reactions ``R`` (lines, 6, J)."""
    return _Sums(
        n_lines=H.shape[0],
        sum_r=R.sum(axis=0).T,
        rr=np.real(np.einsum("lkj,lmj->jkm", R.conj(), R)),
        sum_a=H.sum(axis=0).T,
        ar=H.transpose(2, 1, 0) @ R.transpose(2, 0, 1).conj(),  # (J, n, 6): Σ_l A_l·j R_ljᴴ
    )


def normal_equations(
    sums: _Sums, psi: FloatArray, phi: FloatArray, w: FloatArray, *, summed: bool = False
) -> tuple[FloatArray, FloatArray]:
    """Per-input normal matrices and right sides, batched over geometries.

    psi (S, n, 6), phi (S, J, 6) scaled; w (J, n). Returns N (S, J, 21, 21), b (S, J, 21);
    with ``summed`` their sums over the inputs, N (S, 21, 21), b (S, 21): the Kronecker blocks
    ``Σ_j S_j ⊗ P_j`` as one product over j (a (36, J)·(J, 36) matmul per geometry) before the
    21×21 reduction, instead of J of them (the geometry Monte Carlo needs only the sums).
    """
    L = sums.n_lines
    # S_j = Re Σ F̄ Fᵀ with F = φ + R
    sr = np.real(sums.sum_r)  # (J, 6)
    Sj = (
        L * np.einsum("sjk,sjm->sjkm", phi, phi)
        + np.einsum("sjk,jm->sjkm", phi, sr)
        + np.einsum("jk,sjm->sjkm", sr, phi)
        + sums.rr[None]
    )
    pw = psi[:, None, :, :] * w[None, :, :, None]  # (S, J, n, 6): W_j Ψ
    Pj = np.swapaxes(pw, -1, -2) @ psi[:, None]  # ΨᵀW_jΨ
    if summed:
        S_, J_ = Sj.shape[:2]
        X = np.swapaxes(Sj.reshape(S_, J_, 36), 1, 2) @ Pj.reshape(S_, J_, 36)  # [s, bd, ac]
        N36 = X.reshape(S_, 6, 6, 6, 6).transpose(0, 1, 3, 2, 4).reshape(S_, 36, 36)
    else:
        N36 = (Sj[:, :, :, None, :, None] * Pj[:, :, None, :, None, :]).reshape(
            *Sj.shape[:2], 36, 36
        )
    N = _DUP.T @ N36 @ _DUP
    # T_j = Σ A_j Fᴴ = Σ A_j φᵀ + Σ A_j Rᴴ ;  rhs = vec(ΨᵀW_j Re T_j)
    T = np.real(sums.sum_a[None, :, :, None] * phi[:, :, None, :] + sums.ar[None])
    B = np.swapaxes(pw, -1, -2) @ T  # (S, J, 6, 6): row a, column b
    if summed:
        B = B.sum(axis=1)
    b36 = np.swapaxes(B, -1, -2).reshape(*B.shape[:-2], 36)  # column-major vec
    b = b36 @ _DUP
    return N, b


def _solve(N: FloatArray, b: FloatArray) -> FloatArray:
    """Column-equilibrated solve of (batched) normal equations; NaN where singular."""
    with np.errstate(invalid="ignore", divide="ignore"):
        d = np.sqrt(np.einsum("...ii->...i", N))
        Ne = N / (d[..., :, None] * d[..., None, :])
        be = (b / d)[..., None]
        try:
            g = np.linalg.solve(Ne, be)[..., 0]
        except np.linalg.LinAlgError:
            g = np.full(b.shape, np.nan)
            for k in np.ndindex(*b.shape[:-1]):
                if np.all(np.isfinite(Ne[k])) and np.linalg.matrix_rank(Ne[k]) == Ne[k].shape[-1]:
                    g[k] = np.linalg.solve(Ne[k], be[k])[:, 0]
        out: FloatArray = g / d
    return out


def _scaled(
    positions_m: FloatArray, directions: FloatArray, p: FloatArray, ell: float
) -> FloatArray:
    r = positions_m - p
    return np.concatenate([directions, cross3(r, directions) / ell], axis=-1)


def _derive(g: FloatArray, ell: float, p: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Scaled ``g`` (..., 21) → (q with the CG in the GCS, structure)."""
    G = _sym(g)
    Ms = np.linalg.inv(G)
    D = np.array([1.0, 1.0, 1.0, ell, ell, ell])
    M = Ms * D[:, None] * D[None, :]
    q, st = read_mass_matrix(M)
    q = q.copy()
    q[..., 1:4] += p
    return q, st


@dataclass(frozen=True, eq=False)
class _Scaled:
    """The stated geometry scaled by ``ℓ`` (rms channel distance from P) and the data's sums."""

    p: FloatArray
    geometry: tuple[FloatArray, FloatArray, FloatArray, FloatArray]
    keep: NDArray[np.bool_]
    ell: float
    psi0: FloatArray
    phi0: FloatArray
    sums: _Sums
    F: ComplexArray
    W: FloatArray


def _prepare(
    H: ComplexArray,
    reactions: NDArray[np.complexfloating] | None,
    geometry: tuple[NDArray[np.floating], ...],
    reference_point_m: NDArray[np.floating],
    weights: NDArray[np.floating] | None,
) -> _Scaled:
    """Scaled ``Ψ``, ``Φ``, reactions ``R`` (moments / ``ℓ``), ``F = Φᵀ + R`` and weights.

    Raises
    ------
    SolverError
        Fewer than 6 response channels or no input.
    """
    L, n, J = H.shape
    R = (
        np.zeros((L, 6, J), dtype=np.complex128)
        if reactions is None
        else np.asarray(reactions, dtype=np.complex128)
    )
    p = np.asarray(reference_point_m, float)
    pos, dirs, ipos, idir = (np.asarray(a, float) for a in geometry)
    wc = np.ones(n) if weights is None else np.asarray(weights, float)
    keep = wc > 0
    if keep.sum() < 6 or J < 1:
        raise SolverError(
            f"the mass-line fit needs at least 6 response channels and 1 input; got "
            f"{int(keep.sum())} and {J}"
        )
    ell = float(np.sqrt(np.mean(np.sum((pos[keep] - p) ** 2, axis=1))))
    if not ell > 0:
        ell = 1.0
    psi0 = _scaled(pos, dirs, p, ell)
    phi0 = _scaled(ipos, idir, p, ell)
    Rs = R.copy()
    Rs[:, 3:] /= ell
    sums = data_band_sums(H, Rs)
    F = phi0.T[None] + Rs  # (L, 6, J)
    W = np.broadcast_to(wc[None, :], (J, n)).copy()
    return _Scaled(p, (pos, dirs, ipos, idir), keep, ell, psi0, phi0, sums, F, W)


def _weighted_fit(
    H: ComplexArray,
    F: ComplexArray,
    sums: _Sums,
    psi0: FloatArray,
    phi0: FloatArray,
    W: FloatArray,
    noise_weighting: bool,
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """Fit ``g`` with channel weights, then (optionally) again with ``W_c = 1/σ²_c``.

    ``σ²_c`` is channel c's residual power pooled over inputs and lines, floored at 10⁻⁶ of the
    median; exact data (round-off residuals) keep their weights.

    Returns
    -------
    g : ndarray, shape (21,)
    Nj, bj : ndarray, shape (J, 21, 21), (J, 21)
        Each input's normal equations.
    W : ndarray, shape (J, n)
        The weights used.
    """

    def fit(Wm: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        Nj, bj = normal_equations(sums, psi0[None], phi0[None], Wm)
        N, b = Nj[0].sum(axis=0), bj[0].sum(axis=0)
        return _solve(N, b), Nj[0], bj[0]

    g, Nj, bj = fit(W)
    if noise_weighting:
        res = H - real_apply(psi0 @ _sym(g), F)
        s2 = np.mean(np.abs(res) ** 2, axis=0).T  # (J, n)
        power = np.mean(np.abs(H) ** 2, axis=0).T
        pos_s2 = s2[W > 0]
        floor = 1e-6 * float(np.median(pos_s2)) if pos_s2.size else 0.0
        # exact data (round-off residuals) carry no noise to weight by
        exact = (
            not pos_s2.size or float(np.median(pos_s2 / np.maximum(power[W > 0], 1e-300))) < 1e-16
        )
        if floor > 0 and not exact:
            # one noise level per channel (pooled over inputs and lines): a sensor's floor; per
            # channel and input the weights would follow each FRF's own size and put the small
            # cross terms, which the stated geometry's errors dominate, first
            s2c = np.sum(s2 * (W > 0), axis=0) / np.maximum(np.sum(W > 0, axis=0), 1)
            W = W / np.maximum(s2c, floor)[None, :]
            W /= float(np.median(W[W > 0]))
            g, Nj, bj = fit(W)
    return g, Nj, bj, W


def _checked(N: FloatArray, g: FloatArray) -> tuple[float, FloatArray]:
    """Condition number of the scaled normal matrix and ``G = M⁻¹``; refuse a singular fit.

    ``κ = √(λ_max/λ_min)`` of ``D⁻¹ N D⁻¹``, ``D = diag(√N_ii)``.

    Raises
    ------
    SolverError
        ``κ > 10¹²`` or ``G`` not positive definite.
    """
    d = np.sqrt(np.diag(N))
    cond = float("inf")
    if np.all(d > 0) and np.all(np.isfinite(N)):
        ev = np.linalg.eigvalsh(N / np.outer(d, d))
        cond = float(np.sqrt(ev[-1] / ev[0])) if ev[0] > 0 else float("inf")
    if not np.isfinite(cond) or cond > 1e12:
        raise SolverError(
            f"the mass-line fit is singular (condition {cond:.3g}): the inputs and channels do "
            "not excite and see all six rigid-body DOF"
        )
    G = _sym(g)
    if np.min(np.linalg.eigvalsh(G)) <= 0:
        raise SolverError(
            "the fitted inverse mass matrix is not positive definite: the data are not a rigid "
            "body with the stated geometry in this band"
        )
    return cond, G


def _noise_spread(
    g: FloatArray, N: FloatArray, res: ComplexArray, W: FloatArray, ell: float, p: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """Noise: ``Cov(g) = N⁻¹ χ²/ν``, first-order through the reading (central differences).

    ``χ² = Σ W |A − Ψ G F|²``, ``ν = 2 L n_w − 21``.

    Returns
    -------
    se_noise : ndarray, shape (19,)
    cov_s : ndarray, shape (11, 11)
        Covariance of the structure terms, unscaled.
    """
    chi2 = float(np.sum(W.T[None] * np.abs(res) ** 2))
    nu = max(2 * res.shape[0] * int(np.sum(W > 0)) - 21, 1)
    Ninv = np.linalg.inv(N)
    cov_g = Ninv * chi2 / nu
    step = np.sqrt(np.maximum(np.diag(cov_g), 0.0))
    step = np.where(step > 0, step, 1e-9 * np.maximum(np.abs(g), 1e-30))
    eye = np.eye(21) * step[None, :]
    qp, sp_ = _derive(g[None] + eye, ell, p)
    qm, sm_ = _derive(g[None] - eye, ell, p)
    Jq = ((qp - qm) / (2 * step[:, None])).T  # (19, 21)
    Js = ((sp_ - sm_) / (2 * step[:, None])).T  # (11, 21)
    se_noise = np.sqrt(np.maximum(np.einsum("ik,kl,il->i", Jq, cov_g, Jq), 0.0))
    return se_noise, Js @ cov_g @ Js.T


def _input_jackknife(
    N: FloatArray, Nj: FloatArray, bj: FloatArray, ell: float, p: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """Delete-one-input fits ``g₋ⱼ = (N − N_j)⁻¹ (b − b_j)`` (same weights), read.

    Returns
    -------
    qj : ndarray, shape (n_ok, 19)
    sj : ndarray, shape (n_ok, 11)
        Only the fits with a positive definite ``G``.
    """
    if Nj.shape[0] > 1:
        gj = _solve(N[None] - Nj, bj.sum(axis=0)[None] - bj)
        ok = np.all(np.isfinite(gj), axis=1)
        ok[ok] = np.linalg.eigvalsh(_sym(gj[ok]))[:, 0] > 0
        if ok.any():
            return _derive(gj[ok], ell, p)
    return np.empty((0, 19)), np.empty((0, 11))


def _jackknife_spread(
    qj: FloatArray, sj: FloatArray, st_scale: FloatArray, cov_s: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """Jackknife standard errors ``√((n−1)/n Σ (q₋ⱼ − q̄)²)`` and structure covariance.

    The structure covariance is the jackknife's where its trace exceeds ``cov_s``'s.
    """
    nj = qj.shape[0]
    if nj > 1:
        se_inputs = np.sqrt((nj - 1) / nj * np.sum((qj - qj.mean(axis=0)) ** 2, axis=0))
        dj = (sj - sj.mean(axis=0)) / st_scale
        cov_sj = (nj - 1) / nj * dj.T @ dj
        if np.trace(cov_sj) > np.trace(cov_s):
            cov_s = cov_sj
    else:
        se_inputs = np.zeros(19)
    return se_inputs, cov_s


@dataclass(frozen=True)
class _GeometrySigma:
    """Stated 1σ geometry and transducer uncertainty (m, deg, relative)."""

    sensor_position_m: float
    sensor_orientation_deg: float
    input_position_m: float
    line_of_action_deg: float
    accel_sensitivity_rel: float
    force_sensitivity_rel: float

    def any(self) -> bool:
        return any(
            s > 0
            for s in (
                self.sensor_position_m,
                self.sensor_orientation_deg,
                self.input_position_m,
                self.line_of_action_deg,
                self.accel_sensitivity_rel,
                self.force_sensitivity_rel,
            )
        )


def _geometry_monte_carlo(
    sg: _GeometrySigma,
    S: int,
    seed: int | None,
    nodes: NDArray[np.integer] | None,
    geometry: tuple[FloatArray, FloatArray, FloatArray, FloatArray],
    p: FloatArray,
    ell: float,
    sums: _Sums,
    W: FloatArray,
    companion: Companion | None,
    st_scale: FloatArray,
) -> tuple[FloatArray, FloatArray | None, FloatArray | None]:
    """Refit on ``S`` perturbed geometries (node moves and turns, input moves, line tilts,
    sensitivities) with the same weights.

    Returns
    -------
    se_geometry : ndarray, shape (19,)
        Sample standard deviation of the readings with a positive definite ``G`` (0 from < 2).
    cov_geo : ndarray, shape (11, 11), or None
        Covariance of the scaled structure terms over those samples (None from < 2).
    se_geometry_difference : ndarray, shape (19,), or None
        Standard deviation of reading minus the companion's (finite rows; None from < 2).
    """
    pos, dirs, ipos, idir = geometry
    n, J = pos.shape[0], ipos.shape[0]
    rng = np.random.default_rng(seed)
    node_ids = np.arange(n) if nodes is None else np.asarray(nodes)
    uniq, inv = np.unique(node_ids, return_inverse=True)
    Gn = uniq.size
    dp = rng.normal(scale=sg.sensor_position_m, size=(S, Gn, 3))
    rv = rng.normal(scale=np.deg2rad(sg.sensor_orientation_deg), size=(S, Gn, 3))
    dpi = rng.normal(scale=sg.input_position_m, size=(S, J, 3))
    rvi = rng.normal(scale=np.deg2rad(sg.line_of_action_deg), size=(S, J, 3))
    rvi -= np.einsum("sjk,jk->sj", rvi, idir)[..., None] * idir[None]
    eps = rng.normal(scale=sg.accel_sensitivity_rel, size=(S, n))
    eta = rng.normal(scale=sg.force_sensitivity_rel, size=S)
    Rn = rotvec_to_matrix(rv)  # (S, Gn, 3, 3), as scipy Rotation
    Ri = rotvec_to_matrix(rvi)
    pos_s = pos[None] + dp[:, inv]
    dir_s = np.einsum("snij,nj->sni", Rn[:, inv], dirs) * (1.0 + eps)[..., None]
    idir_s = np.einsum("sjik,jk->sji", Ri, idir) * (1.0 + eta)[:, None, None]
    ipos_s = ipos[None] + dpi
    qs_list, ss_list, dd_list = [], [], []
    for chunk in np.array_split(np.arange(S), max(1, S // 50)):
        psi_s = _scaled(pos_s[chunk], dir_s[chunk], p, ell)
        phi_s = _scaled(ipos_s[chunk], idir_s[chunk], p, ell)
        Ns, bs = normal_equations(sums, psi_s, phi_s, W, summed=True)
        gs = _solve(Ns, bs)
        good = np.all(np.isfinite(gs), axis=1)
        good[good] = np.linalg.eigvalsh(_sym(gs[good]))[:, 0] > 0
        if good.any():
            q_s, s_s = _derive(gs[good], ell, p)
            qs_list.append(q_s)
            ss_list.append(s_s)
            if companion is not None:
                sel = chunk[good]
                qc = companion(pos_s[sel], dir_s[sel], ipos_s[sel], idir_s[sel])
                dd_list.append(q_s - qc)
    se_geometry = np.zeros(19)
    cov_geo = se_geo_diff = None
    if qs_list:
        qs, ss = np.concatenate(qs_list), np.concatenate(ss_list)
        if qs.shape[0] > 1:
            se_geometry = qs.std(axis=0, ddof=1)
            cov_geo = np.cov((ss / st_scale).T)
    if dd_list:
        dd = np.concatenate(dd_list)
        dd = dd[np.all(np.isfinite(dd), axis=1)]
        if dd.shape[0] > 1:
            se_geo_diff = dd.std(axis=0, ddof=1)
    return se_geometry, cov_geo, se_geo_diff


def mass_line_fit(
    H_acc: NDArray[np.complexfloating],
    reactions: NDArray[np.complexfloating] | None,
    positions_m: NDArray[np.floating],
    directions: NDArray[np.floating],
    in_positions_m: NDArray[np.floating],
    in_directions: NDArray[np.floating],
    reference_point_m: NDArray[np.floating],
    *,
    weights: NDArray[np.floating] | None = None,
    nodes: NDArray[np.integer] | None = None,
    noise_weighting: bool = True,
    sensor_position_m: float = 0.0,
    sensor_orientation_deg: float = 0.0,
    input_position_m: float = 0.0,
    line_of_action_deg: float = 0.0,
    accel_sensitivity_rel: float = 0.0,
    force_sensitivity_rel: float = 0.0,
    n_samples: int = 200,
    seed: int | None = 0,
    companion: Companion | None = None,
) -> MassLineFit:
    """Fit ``A(ω) ≈ Ψ M⁻¹ (Φ + R(ω))`` over the band and read m, CG and I (module docstring).

    Parameters
    ----------
    H_acc : ndarray, shape (n_lines, n, J)
        Accelerances, (m/s²)/N, of the response channels under each input.
    reactions : ndarray, shape (n_lines, 6, J), optional
        Summed load-cell loads on the structure at P per unit input (N/N, N·m/N); None: none.
    positions_m, directions : ndarray, shape (n, 3)
        Stated channel positions (GCS, m) and unit directions (sign of the record applied).
    in_positions_m, in_directions : ndarray, shape (J, 3)
        Stated input points and unit lines of action.
    reference_point_m : ndarray, shape (3,)
        P, about which ``I_P`` is reported.
    weights : ndarray, shape (n,), optional
        Channel weights (0 drops a channel); default all 1.
    nodes : ndarray, shape (n,), optional
        Sensor node of each channel (the channels of a node move and turn together in the
        geometry Monte Carlo); default one node per channel.
    noise_weighting : bool
        Weight channel i under input j by ``1/σ²_ij`` from the first pass's residuals.
    sensor_position_m .. force_sensitivity_rel : float
        Stated 1σ geometry and transducer uncertainty (as
        :func:`dimacq.pipeline.uncertainty.geometry_spread`); all zero: no geometry term.
    n_samples : int
        Geometry Monte Carlo samples.
    companion : callable, optional
        A second estimator run on every geometry sample (:data:`Companion`): gives
        :attr:`MassLineFit.se_geometry_difference`.

    Raises
    ------
    SolverError
        Fewer than 6 inputs or channels of rank 6, or a fitted mass matrix that is not positive
        definite (the data are not a rigid body with the stated geometry).
    """
    H = np.asarray(H_acc, dtype=np.complex128)
    L, J = H.shape[0], H.shape[2]
    geometry = (positions_m, directions, in_positions_m, in_directions)
    sc = _prepare(H, reactions, geometry, reference_point_m, weights)
    p, ell, keep, F, sums = sc.p, sc.ell, sc.keep, sc.F, sc.sums
    g, Nj, bj, W = _weighted_fit(H, F, sums, sc.psi0, sc.phi0, sc.W, noise_weighting)
    N = Nj.sum(axis=0)
    cond, G = _checked(N, g)
    values, structure = _derive(g, ell, p)
    res = H - real_apply(sc.psi0 @ G, F)
    se_noise, cov_s_raw = _noise_spread(g, N, res, W, ell, p)
    st_scale = np.concatenate([np.full(5, values[0]), np.full(6, values[0] * ell)])
    cov_s = cov_s_raw / np.outer(st_scale, st_scale)
    structure_rel = float(np.linalg.norm(structure / st_scale))
    qj, sj = _input_jackknife(N, Nj, bj, ell, p)
    se_inputs, cov_s = _jackknife_spread(qj, sj, st_scale, cov_s)
    se_geometry = np.zeros(19)
    se_geo_diff: FloatArray | None = None
    sg = _GeometrySigma(
        sensor_position_m,
        sensor_orientation_deg,
        input_position_m,
        line_of_action_deg,
        accel_sensitivity_rel,
        force_sensitivity_rel,
    )
    S = int(n_samples) if sg.any() else 0
    if S > 1:
        se_geometry, cov_geo, se_geo_diff = _geometry_monte_carlo(
            sg, S, seed, nodes, sc.geometry, p, ell, sums, W, companion, st_scale
        )
        cov_s = cov_s + cov_geo if cov_geo is not None else cov_s
    z = structure / st_scale
    structure_chi2 = float(z @ np.linalg.pinv(cov_s, rcond=1e-12, hermitian=True) @ z)
    se = np.sqrt(np.maximum(se_noise**2, se_inputs**2) + se_geometry**2)
    a_norm = float(np.sqrt(np.sum(np.abs(H[:, keep]) ** 2)))
    residual_rel = float(np.sqrt(np.sum(np.abs(res[:, keep]) ** 2)) / a_norm) if a_norm else 0.0
    Dm = np.array([1.0, 1.0, 1.0, ell, ell, ell])
    return MassLineFit(
        values=values,
        se=se,
        se_noise=se_noise,
        se_inputs=se_inputs,
        se_geometry=se_geometry,
        mass_matrix=np.linalg.inv(G) * Dm[:, None] * Dm[None, :],
        structure_rel=structure_rel,
        structure_chi2=structure_chi2,
        residual_rel=residual_rel,
        condition_number=cond,
        n_lines=L,
        n_channels=int(keep.sum()),
        n_inputs=J,
        length_scale_m=ell,
        reference_point_m=p,
        jackknife=qj,
        geometry_samples=S,
        se_geometry_difference=se_geo_diff,
    )


def mass_line_from_frf(
    frf: FrfData,
    setup: TestSetup,
    *,
    response_weights: NDArray[np.floating] | None = None,
    input_keep: NDArray[np.bool_] | None = None,
    reference_point_m: NDArray[np.floating] | None = None,
    geometry: bool = True,
    n_samples: int = 200,
    seed: int | None = 0,
    dim_companion: bool = False,
    known: Mapping[str, float] | None = None,
    length_unit: str | None = None,
) -> MassLineFit:
    """:func:`mass_line_fit` on an FRF set and its setup (the whole span of ``frf``: band it first).

    The channels and inputs are matched to the setup as the DIM matches them
    (:func:`dimacq.pipeline.selection._common.response_geometry`, the inputs' lines of action);
    the load-cell reactions at P are those the DIM sums (:func:`dimacq.pipeline.dim.assemble`).
    ``response_weights`` (one per acceleration output, 0 drops) and ``input_keep`` (one per
    input) select the data; ``geometry`` adds the setup's stated geometry and transducer
    uncertainty to the intervals. ``dim_companion``: the joint equation-error DIM (with
    ``known`` and ``length_unit``) is solved on every geometry sample too
    (:func:`dimacq.pipeline.uncertainty.joint_parameters_for_geometry`), for
    :attr:`MassLineFit.se_geometry_difference`.
    """
    from dimacq.pipeline.dim import assemble
    from dimacq.pipeline.selection._common import response_geometry

    p = np.asarray(
        setup.reference_point_m if reference_point_m is None else reference_point_m, float
    )
    geo = response_geometry(frf, setup)
    keep = (
        np.ones(len(frf.inputs), dtype=bool)
        if input_keep is None
        else np.asarray(input_keep, dtype=bool)
    )
    idx = np.nonzero(keep)[0]
    ex_key = {(e.node, e.direction): e for e in setup.excitations}
    in_pos, in_dir = [], []
    for j in idx:
        ch = frf.inputs[int(j)]
        ex = ex_key.get((ch.node, ch.direction)) or ex_key.get((ch.node, -ch.direction))
        if ex is None or ex.direction_gcs is None:
            raise SetupError(
                f"input {ch.name} of the FRFs has no line of action in the setup; add it to "
                "excitations with position_m and direction_gcs"
            )
        sign = 1.0 if ex.direction == ch.direction else -1.0
        in_pos.append(ex.position_m)
        in_dir.append(sign * np.asarray(ex.direction_gcs, float))
    reactions = None
    if setup.load_cells and frf.output_index("reaction").size:
        system = assemble(frf, setup, length_unit="m", reference_point_m=p)
        R = system.F - system.phi[None].astype(complex)
        reactions = R[:, :, idx]
    H = frf.H[:, geo.output_index][:, :, idx]
    companion: Companion | None = None
    if dim_companion and geometry:
        from dimacq.pipeline.uncertainty import band_sums, joint_parameters_for_geometry

        wts = (
            np.ones(len(geo.channels))
            if response_weights is None
            else np.asarray(response_weights, float)
        )
        sysd = assemble(
            frf, setup, length_unit=length_unit, reference_point_m=p, response_weights=wts
        ).select_inputs(idx)
        dsums = band_sums(sysd, H)

        def companion(
            pos_s: FloatArray, dir_s: FloatArray, ipos_s: FloatArray, idir_s: FloatArray
        ) -> FloatArray:
            try:
                x = joint_parameters_for_geometry(
                    sysd, dsums, pos_s, dir_s, wts, ipos_s, idir_s, known
                )
            except np.linalg.LinAlgError:
                return np.full((pos_s.shape[0], 19), np.nan)
            return quantities_from_parameters(x, p)

    gu = setup.geometry_uncertainty
    tu = setup.transducer_uncertainty
    reg = float(gu.registration_rms_m or 0.0)
    on = 1.0 if geometry else 0.0
    return mass_line_fit(
        H,
        reactions,
        geo.positions_m,
        geo.directions,
        np.asarray(in_pos, float).reshape(-1, 3),
        np.asarray(in_dir, float).reshape(-1, 3),
        p,
        weights=response_weights,
        nodes=geo.nodes,
        n_samples=n_samples,
        seed=seed,
        companion=companion,
        sensor_position_m=on * float(np.hypot(gu.sensor_position_m, reg)),
        sensor_orientation_deg=on * float(gu.sensor_orientation_deg),
        input_position_m=on * float(np.hypot(gu.input_position_m, reg)),
        line_of_action_deg=on * float(gu.line_of_action_deg),
        accel_sensitivity_rel=on * float(tu.accel_sensitivity_rel),
        force_sensitivity_rel=on * float(tu.force_sensitivity_rel),
    )
