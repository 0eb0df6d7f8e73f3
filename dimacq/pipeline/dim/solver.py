"""Solving the DIM system: known properties eliminated, normal equations per line and over the
band, their solution and refinement (:func:`solve_system`, :func:`solve_joint`,
:func:`line_residuals`, :func:`solve`); many joint solves under different input weights or
geometries from band-summed Gram matrices (:func:`solve_joint_many`, :func:`solve_gram_sums`).
The system comes from :mod:`.assembly`, the result is a :class:`~.result.DimResult` checked by
:mod:`.checks`.

Solution
--------
Per line (a spectrum of estimates) or jointly over a band (normal equations summed over lines).
The normal equations are column-equilibrated, solved by a symmetric eigendecomposition (which gives
rank and condition number of the equilibrated design matrix, ``κ(A) = sqrt(λmax/λmin)``), then refined
once with the residual formed in the original, unsquared system (semi-normal equations with
refinement), which recovers the accuracy of a QR solve while staying vectorised over lines.

Known properties (§3.2.1, Eq. 17–22) are eliminated by the affine parameterisation
``x = T θ + x0``: known inertia terms and known ``s`` components move to the right side; with the
mass known, an unknown CG component ``c_k`` is the unknown itself (column ``m·A_{s_k}``); with the mass
unknown and ``c_k`` known, the mass column becomes ``A_m + c_k A_{s_k}`` (Eq. 19–21). With mass and
CG known only ``I`` remains and the force rows carry no information (Eq. 22).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from dimacq.errors import SetupError, SolverError
from dimacq.model.frf import FrfData
from dimacq.model.properties import (
    RigidBodyProperties,
    vector_to_inertia,
)
from dimacq.model.setup import PARAMETERS, TestSetup
from dimacq.pipeline.dim.assembly import DimSystem, assemble, design_matrices
from dimacq.pipeline.dim.checks import plausibility
from dimacq.pipeline.dim.result import DimResult

FloatArray = NDArray[np.float64]
ComplexArray = NDArray[np.complex128]


Method = Literal["joint", "mean"]

_I_KEYS = PARAMETERS[4:]


# --------------------------------------------------------------------------------------------
# Known properties: x = T θ + x0
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class _Param:
    T: FloatArray  # (10, n_theta)
    x0: FloatArray  # (10,)
    names: tuple[str, ...]  # what θ holds: "m", "sx", "cx" (c directly), "Ixx", ...


def _parameterisation(known: Mapping[str, float], p: FloatArray, u: float) -> _Param:
    """Affine map from the unknowns θ to x = [m, s, I] in the working unit (c relative to P)."""
    unknown_names = [k for k in known if k not in PARAMETERS]
    if unknown_names:
        raise SetupError(
            f"known property {unknown_names[0]!r} is unknown; use {', '.join(PARAMETERS)}"
        )
    cols: list[FloatArray] = []
    names: list[str] = []
    x0 = np.zeros(10)
    m = known.get("m")
    c_rel = {k: (known[k] - p[i]) / u for i, k in enumerate(("cx", "cy", "cz")) if k in known}
    if m is None:
        col = np.zeros(10)
        col[0] = 1.0
        for i, k in enumerate(("cx", "cy", "cz")):
            if k in c_rel:
                col[1 + i] = c_rel[k]  # s_k = m c_k: mass column gains c_k A_{s_k}
        cols.append(col)
        names.append("m")
        for i, k in enumerate(("cx", "cy", "cz")):
            if k not in c_rel:
                col = np.zeros(10)
                col[1 + i] = 1.0
                cols.append(col)
                names.append("s" + k[1])
    else:
        x0[0] = m
        for i, k in enumerate(("cx", "cy", "cz")):
            if k in c_rel:
                x0[1 + i] = m * c_rel[k]
            else:
                col = np.zeros(10)
                col[1 + i] = m  # s_k = m c_k with c_k unknown: linear in c_k
                cols.append(col)
                names.append(k)
    for i, k in enumerate(_I_KEYS):
        if k in known:
            x0[4 + i] = known[k] / u**2
        else:
            col = np.zeros(10)
            col[4 + i] = 1.0
            cols.append(col)
            names.append(k)
    T = np.stack(cols, axis=1) if cols else np.zeros((10, 0))
    return _Param(T, x0, tuple(names))


# --------------------------------------------------------------------------------------------
# Solving
# --------------------------------------------------------------------------------------------
def _solve_normal(
    N: FloatArray, rhs: FloatArray, rcond: float
) -> tuple[FloatArray, NDArray[np.intp], FloatArray, FloatArray]:
    """Batched minimum-norm solve of ``N θ = rhs`` (N symmetric PSD, shape (..., n, n)).

    Returns θ, rank, condition number of the equilibrated design matrix, and the pseudo-inverse
    of N (for refinement).
    """
    d = np.sqrt(np.einsum("...ii->...i", N))
    d = np.where(d > 0, d, 1.0)
    Ns = N / (d[..., :, None] * d[..., None, :])
    lam, V = np.linalg.eigh(Ns)
    lam_max = lam[..., -1:]
    good = lam > lam_max * rcond**2
    inv = np.where(good, 1.0 / np.where(good, lam, 1.0), 0.0)
    Ninv_s = np.einsum("...ik,...k,...jk->...ij", V, inv, V)
    Ninv = Ninv_s / (d[..., :, None] * d[..., None, :])
    theta = np.einsum("...ij,...j->...i", Ninv, rhs)
    rank = good.sum(axis=-1)
    lam_min = np.where(good, lam, np.inf).min(axis=-1)
    with np.errstate(divide="ignore", invalid="ignore"):
        cond = np.sqrt(lam_max[..., 0] / lam_min)
    return theta, rank, cond, Ninv


# Constant tensors of the design matrix: A(k) = Σ_s E[:, :, s] k_s, shape (6, 10, 6).
_E = np.moveaxis(design_matrices(np.eye(6)[:, :, None])[..., 0, :, :], 0, -1)
# N_pq = Σ_{s,t} Q[p,q,s,t] G_st with G = Re(Σ_j conj(k_j) k_jᵀ): Q = Σ_r E[r,p,s] E[r,q,t].
_Q = np.einsum("rps,rqt->pqst", _E, _E).reshape(100, 36)
# rhs_p = Σ_{s,r} E[r,p,s] C_sr with C = Re(Σ_j conj(k_j) b_jᵀ).
_R = np.einsum("rps->psr", _E).reshape(10, 36)
#: Cholesky pivot (≈ 1/κ² of the equilibrated design matrix) below which a line is refined.
_REFINE_PIVOT = 1e-6
#: Joint condition number above which the joint solution is refined on the unsquared system.
_REFINE_COND = 1e3


def _gram_normal_equations(
    K: ComplexArray, F: ComplexArray
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Stacked real/imaginary normal equations of every line from 6×6 Gram matrices.

    ``A`` is linear in the motion ``k_j = [a; α]`` of each input, ``A(k) = Σ_s E_s k_s``, so
    ``N = Σ_j Re(A(k_j)ᴴ A(k_j)) = Σ_st Q_st G_st`` with ``G = Re(Σ_j k̄_j k_jᵀ)`` and
    ``Aᴴb = Σ_sr E_rs C_sr`` with ``C = Re(Σ_j k̄_j b_jᵀ)``: O(n_inputs·36) work per line.

    Returns
    -------
    N : (n_lines, 10, 10), rhs : (n_lines, 10), bb : (n_lines,) ``Σ_j |b_j|²``.
    """
    n_lines = K.shape[0]
    # Re(Σ_j conj(u_j) v_j) is the dot product of the interleaved (re, im) float views.
    Kv = np.ascontiguousarray(K).view(np.float64)  # (L, 6, 2J)
    Fv = np.ascontiguousarray(F).view(np.float64)
    KvT = np.swapaxes(Kv, 1, 2)
    G = (Kv @ KvT).reshape(n_lines, 36)
    C = (Kv @ np.swapaxes(Fv, 1, 2)).reshape(n_lines, 36)
    N = (G @ _Q.T).reshape(n_lines, 10, 10)
    rhs = C @ _R.T
    bb = np.einsum("lij,lij->l", Fv, Fv)
    return N, rhs, bb


def _solve_lines(N: FloatArray, rhs: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Batched Cholesky solve of SPD systems after equilibration, vectorised over lines.

    The factorisation ``Ns = L Lᵀ`` of the equilibrated matrix (unit diagonal) runs column by
    column over all lines at once; ``min_i L_ii²`` is returned as a cheap measure of
    ``λ_min(Ns) ≈ 1/κ(A)²`` (0 for a rank-deficient line, whose θ is then the minimum-norm
    solution from an eigendecomposition).

    Returns
    -------
    theta : (n_lines, n), pivot : (n_lines,)
    """
    d = np.sqrt(np.einsum("lii->li", N))
    d = np.where(d > 0, d, 1.0)
    Ns = N / (d[:, :, None] * d[:, None, :])
    bs = rhs / d
    n_lines, n = rhs.shape
    L = np.zeros_like(Ns)
    piv = np.empty((n_lines, n))
    tiny = 1e-30
    for j in range(n):
        Lj = L[:, j, :j]
        sj = Ns[:, j, j] - np.einsum("li,li->l", Lj, Lj)
        piv[:, j] = sj
        ljj = np.sqrt(np.maximum(sj, tiny))
        L[:, j, j] = ljj
        if j + 1 < n:
            L[:, j + 1 :, j] = (
                Ns[:, j + 1 :, j] - np.einsum("lik,lk->li", L[:, j + 1 :, :j], Lj)
            ) / ljj[:, None]
    y = np.empty_like(bs)
    for j in range(n):
        y[:, j] = (bs[:, j] - np.einsum("li,li->l", L[:, j, :j], y[:, :j])) / L[:, j, j]
    x = np.empty_like(bs)
    for j in range(n - 1, -1, -1):
        x[:, j] = (y[:, j] - np.einsum("li,li->l", L[:, j + 1 :, j], x[:, j + 1 :])) / L[:, j, j]
    pivot = np.clip(piv.min(axis=1), 0.0, None)
    theta = x / d
    bad = pivot < 1e-13
    if bad.any():
        theta[bad] = _solve_normal(N[bad], rhs[bad], 1e-10)[0]
    return theta, pivot


def _explicit_system(
    K: ComplexArray, F: ComplexArray, T: FloatArray, x0: FloatArray
) -> tuple[NDArray[Any], NDArray[Any]]:
    """Explicit stacked design ``A T`` (L, 6J, nθ) and right side ``b − A x0`` (L, 6J)."""
    A = design_matrices(K)  # (L, J, 6, 10)
    b = np.moveaxis(F, -1, -2)  # (L, J, 6)
    n_lines = A.shape[0]
    A_t = (A @ T).reshape(n_lines, -1, T.shape[1])
    b_t = (b - A @ x0).reshape(n_lines, -1)
    return A_t, b_t


def _refine(A_t: ComplexArray, b_t: ComplexArray, N: FloatArray, theta: FloatArray) -> FloatArray:
    """One step of iterative refinement per line with residuals of the unsquared system."""
    _, _, _, Ninv = _solve_normal(N, np.zeros(theta.shape), 1e-13)
    for _ in range(2):
        r = b_t - np.einsum("lij,lj->li", A_t, theta)
        g = np.real(np.einsum("lij,li->lj", A_t.conj(), r))
        theta = theta + np.einsum("lij,lj->li", Ninv, g)
    return theta


def _to_parameters(x: FloatArray, p: FloatArray, u: float) -> FloatArray:
    """x = [m, s, I] in the working unit → [m, CG in GCS (m), I about P (kg·m²)], shape (..., 10)."""
    out = np.empty_like(x)
    m = x[..., 0]
    out[..., 0] = m
    with np.errstate(divide="ignore", invalid="ignore"):
        out[..., 1:4] = x[..., 1:4] / m[..., None] * u + p
    out[..., 4:] = x[..., 4:] * u**2
    return out


def _eliminate_known(
    N_full: FloatArray, rhs_full: FloatArray, prm: _Param
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Normal equations in the unknowns θ from those in ``x = [m, s, I]`` (Eq. 17–22).

    With ``x = T θ + x0``: ``N_θ = Tᵀ N T`` and ``r_θ = (r − N x0) T``.

    Parameters
    ----------
    N_full : ndarray, shape (..., 10, 10)
    rhs_full : ndarray, shape (..., 10)
    prm : the parameterisation (:func:`_parameterisation`)

    Returns
    -------
    N : ndarray, shape (..., nθ, nθ)
    rhs : ndarray, shape (..., nθ)
    Nx0 : ndarray, shape (..., 10)
        ``N x0`` (the residual's cross term).
    """
    T, x0 = prm.T, prm.x0
    Nx0 = N_full @ x0
    return T.T @ N_full @ T, (rhs_full - Nx0) @ T, Nx0


@dataclass(frozen=True, eq=False)
class _NormalEquations:
    """Per-line normal equations in the unknowns θ (known properties eliminated)."""

    prm: _Param
    Kw: ComplexArray  # input-weighted K, F: (L, 6, J)
    Fw: ComplexArray
    N: FloatArray  # (L, nθ, nθ)
    rhs: FloatArray  # (L, nθ)
    bb: FloatArray  # (L,) ‖b − A x0‖²


def _normal_equations(
    system: DimSystem,
    known: Mapping[str, float],
    input_weights: NDArray[np.floating] | None,
) -> _NormalEquations:
    """Checks, parameterisation, input weights and per-line normal equations of a solve."""
    prm = _parameterisation(known, system.reference_point_m, system.unit_m)
    n_theta = prm.T.shape[1]
    if n_theta == 0:
        raise SetupError("every property is known; leave at least one unknown to solve for")
    n_lines, _, n_in = system.K.shape
    if n_lines == 0:
        raise SolverError("no frequency line to solve; widen the band")
    w_in = np.ones(n_in) if input_weights is None else np.asarray(input_weights, float)
    if w_in.shape != (n_in,) or np.any(w_in < 0):
        raise SetupError(f"input_weights must be {n_in} non-negative numbers, one per input")
    if input_weights is None:
        Kw, Fw = system.K, system.F
    else:
        sw = np.sqrt(w_in)
        # C order: a system from select_inputs is not C-contiguous, and the Gram matrices
        # would copy the weighted arrays again (same values either way)
        Kw = np.multiply(system.K, sw, order="C")
        Fw = np.multiply(system.F, sw, order="C")

    # Normal equations from 6×6 Gram matrices (see module docstring, "Solution").
    N_full, rhs_full, bb = _gram_normal_equations(Kw, Fw)
    x0 = prm.x0
    if known:
        N, rhs, Nx0 = _eliminate_known(N_full, rhs_full, prm)  # (L, nθ, nθ), (L, nθ), (L, 10)
        bb = bb - 2.0 * rhs_full @ x0 + Nx0 @ x0  # ‖b − A x0‖² per line
    else:  # T = I, x0 = 0
        N, rhs = N_full, rhs_full
    return _NormalEquations(prm, Kw, Fw, N, rhs, bb)


def _solve_joint(
    ne: _NormalEquations, w_l: FloatArray, rcond: float
) -> tuple[FloatArray, int, float, float]:
    """Joint least squares over the lines with weights ``w_l``: θ, rank, condition, residual.

    Raises
    ------
    SolverError
        Rank below the number of unknowns.
    """
    prm, N, rhs, bb = ne.prm, ne.N, ne.rhs, ne.bb
    T, x0 = prm.T, prm.x0
    n_theta = T.shape[1]
    Nj = np.tensordot(w_l, N, axes=1)
    rj = w_l @ rhs
    theta, rank_j, cond, Ninv = _solve_normal(Nj, rj, rcond)
    if cond > _REFINE_COND:
        sel = np.nonzero(w_l > 0)[0]
        A_t, b_t = _explicit_system(ne.Kw[sel], ne.Fw[sel], T, x0)
        sq = np.sqrt(w_l[sel])
        A_t, b_t = A_t * sq[:, None, None], b_t * sq[:, None]
        for _ in range(2):
            r = b_t - A_t @ theta
            theta = theta + Ninv @ np.real(np.einsum("lij,li->j", A_t.conj(), r))
        r = b_t - A_t @ theta
        resid2 = float(np.sum(np.abs(r) ** 2))
    else:
        resid2 = float(w_l @ bb - 2.0 * theta @ rj + theta @ Nj @ theta)
    bnorm2 = float(w_l @ bb)
    resid = float(np.sqrt(max(resid2, 0.0) / bnorm2)) if bnorm2 > 0 else 0.0
    rank = int(rank_j)
    if rank < n_theta:
        null = np.linalg.eigh(Nj)[1][:, 0]
        worst = prm.names[int(np.argmax(np.abs(null)))]
        raise SolverError(
            f"the DIM system has rank {rank} < {n_theta} unknowns ({', '.join(prm.names)}): "
            f"'{worst}' is not determined by the data; the inputs do not excite every rigid-body "
            "DOF (run the excitation check) or the band holds no usable line"
        )
    return theta, rank, float(cond), resid


def solve_joint(
    system: DimSystem,
    *,
    known: Mapping[str, float] | None = None,
    input_weights: NDArray[np.floating] | None = None,
    rcond: float = 1e-10,
) -> FloatArray:
    """The joint answer of :func:`solve_system` alone, without the per-line spectrum.

    ``solve_system(system, known=known, input_weights=input_weights).parameters`` to the bit
    (the same operations in the same order), for callers that solve many times and use only
    the joint answer (the jackknife over inputs).

    Returns
    -------
    ndarray, shape (10,)
        ``[m, cx, cy, cz, Ixx, Ixy, Ixz, Iyy, Iyz, Izz]`` (CG in the GCS, m; I about P, kg·m²).

    Raises
    ------
    SolverError
        As :func:`solve_system`: rank deficiency, no line, or a mass of exactly zero.
    """
    kn = dict(known or {})
    ne = _normal_equations(system, kn, input_weights)
    theta, _, _, _ = _solve_joint(ne, np.ones(system.K.shape[0]), rcond)
    params = _to_parameters(ne.prm.T @ theta + ne.prm.x0, system.reference_point_m, system.unit_m)
    if params[0] == 0:
        raise SolverError(
            "the estimated mass is exactly zero; the data carry no inertia information"
        )
    return params


def solve_gram_sums(
    G: FloatArray,
    C: FloatArray,
    reference_point_m: NDArray[np.floating],
    unit_m: float,
    *,
    known: Mapping[str, float] | None = None,
    rcond: float = 1e-10,
) -> tuple[FloatArray, NDArray[np.intp], FloatArray, int]:
    """Joint DIM answers from band-summed Gram matrices, one per row (vectorised).

    The joint normal equations are linear in the Gram matrices of :func:`_gram_normal_equations`
    summed over the band (and over inputs, with any input weights):
    ``N = Q · Σ G`` (``Q`` the 100×36 map of the design matrix) and ``r = R · Σ C`` (``R``,
    10×36). Known properties are eliminated (:func:`_eliminate_known`) and the equilibrated
    minimum-norm solve is :func:`_solve_normal`'s, as :func:`solve_joint` solves the same
    equations summed over lines first. An ill-conditioned row (``cond`` above
    ``_REFINE_COND``) is not refined on the unsquared system here; :func:`solve_joint_many`
    hands those to :func:`solve_joint`.

    Parameters
    ----------
    G, C : ndarray, shape (n_solves, 36)
        Row-major 6×6 sums ``Re Σ k̄ kᵀ`` and ``Re Σ k̄ fᵀ`` in the working unit.
    reference_point_m : ndarray, shape (3,)
    unit_m : float
        The working length unit (m).
    known : mapping, optional
        Known properties (as :func:`solve_joint`).

    Returns
    -------
    params : ndarray, shape (n_solves, 10)
        ``[m, cx, cy, cz, Ixx, Ixy, Ixz, Iyy, Iyz, Izz]`` (CG in the GCS, m; I about P, kg·m²).
    rank : ndarray of int, shape (n_solves,)
    cond : ndarray, shape (n_solves,)
        Condition number of the equilibrated design matrix.
    n_theta : int
        Number of unknowns (a row is determined when its rank reaches it).
    """
    p = np.asarray(reference_point_m, float)
    prm = _parameterisation(dict(known or {}), p, unit_m)
    N_full = (np.asarray(G) @ _Q.T).reshape(-1, 10, 10)  # (S, 10, 10)
    r_full = np.asarray(C) @ _R.T  # (S, 10)
    N, rhs, _ = _eliminate_known(N_full, r_full, prm)
    theta, rank, cond, _ = _solve_normal(N, rhs, rcond)
    params = _to_parameters(theta @ prm.T.T + prm.x0, p, unit_m)
    return params, rank, cond, prm.T.shape[1]


def input_band_sums(system: DimSystem) -> tuple[FloatArray, FloatArray]:
    """Per-input band sums ``G_j = Re Σ_l k̄_lj k_ljᵀ`` and ``C_j = Re Σ_l k̄_lj f_ljᵀ``.

    Returns
    -------
    G, C : ndarray, shape (n_inputs, 36)
        Row-major 6×6 blocks (``G[j, 6 s + t] = G_j[s, t]``), as :func:`_gram_normal_equations`.
    """
    K = np.asarray(system.K, dtype=np.complex128)  # (L, 6, J)
    F = np.asarray(system.F, dtype=np.complex128)
    Kj = np.ascontiguousarray(K.transpose(2, 1, 0))  # (J, 6, L)
    Fj = np.ascontiguousarray(F.transpose(2, 1, 0))
    n_in = Kj.shape[0]
    G = np.real(Kj.conj() @ Kj.swapaxes(1, 2)).reshape(n_in, 36)
    C = np.real(Kj.conj() @ Fj.swapaxes(1, 2)).reshape(n_in, 36)
    return G, C


def solve_joint_many(
    system: DimSystem,
    weights: NDArray[np.floating],
    *,
    known: Mapping[str, float] | None = None,
    rcond: float = 1e-10,
) -> tuple[FloatArray, NDArray[np.bool_]]:
    """Joint answers of ``solve_joint(system, known=known, input_weights=w)`` for every row w.

    The joint normal equations are sums over lines ``l`` and inputs ``j`` of 6×6 Gram matrices,
    ``N(w) = Q · Σ_j w_j G_j`` and ``r(w) = R · Σ_j w_j C_j`` with ``G_j = Re Σ_l k̄_lj k_ljᵀ``,
    ``C_j = Re Σ_l k̄_lj f_ljᵀ`` (:func:`input_band_sums`), so the per-input band sums are
    formed once and every weighting (a leave-one-input-out, a bootstrap resample) is a
    (J,)·(J, 36) product and a 10×10 solve (:func:`solve_gram_sums`). The sums are
    :func:`solve_joint`'s in another order (lines first, then inputs): the answers agree to
    rounding, not to the bit. A weighting whose joint system is ill conditioned (condition above
    ``_REFINE_COND``) is solved by :func:`solve_joint` itself, refined on the unsquared system.

    Parameters
    ----------
    system : DimSystem
    weights : ndarray, shape (n_solves, n_inputs)
        Non-negative input weights of each solve.
    known : mapping, optional
        Known properties (as :func:`solve_joint`).

    Returns
    -------
    params : ndarray, shape (n_solves, 10)
        ``[m, cx, cy, cz, Ixx, Ixy, Ixz, Iyy, Iyz, Izz]`` per solve (CG in the GCS, m; I about P,
        kg·m²); NaN rows where ``solve_joint`` raises :class:`SolverError` (rank deficiency, a
        mass of exactly zero).
    solved : ndarray of bool, shape (n_solves,)
    """
    W = np.atleast_2d(np.asarray(weights, dtype=np.float64))
    kn = dict(known or {})
    G, C = input_band_sums(system)
    params, rank, cond, n_theta = solve_gram_sums(
        W @ G, W @ C, system.reference_point_m, system.unit_m, known=kn, rcond=rcond
    )
    solved = (rank >= n_theta) & (params[:, 0] != 0) & np.all(np.isfinite(params), axis=1)
    params[~solved] = np.nan
    for s in np.nonzero(solved & (cond > _REFINE_COND))[0]:
        try:  # refined on the unsquared system, as solve_joint does
            params[s] = solve_joint(system, known=kn, input_weights=W[s], rcond=rcond)
        except SolverError:
            params[s], solved[s] = np.nan, False
    return params, solved


def solve_system(
    system: DimSystem,
    *,
    known: Mapping[str, float] | None = None,
    method: Method = "joint",
    input_weights: NDArray[np.floating] | None = None,
    line_weights: NDArray[np.floating] | None = None,
    rcond: float = 1e-10,
    rcond_line: float = 1e-7,
    check_plausibility: bool = True,
) -> DimResult:
    """Solve an assembled DIM system per line and over the band.

    Parameters
    ----------
    system : DimSystem
    known : dict, optional
        Known values by name (``m`` kg; ``cx, cy, cz`` CG in the GCS, m; ``Ixx..Izz`` about P, kg·m²).
    method : {"joint", "mean"}
        Headline answer: joint least squares over all lines, or the mean of per-line estimates.
    input_weights : ndarray, shape (n_inputs,), optional
        Non-negative weights of the inputs' equations.
    line_weights : ndarray, shape (n_lines,), optional
        Non-negative weights of the lines in the joint solve.
    rcond : float
        Relative singular-value cut-off on the equilibrated design matrix for the rank of the
        joint system.
    rcond_line : float
        A line whose equilibrated design matrix has a Cholesky pivot below ``rcond_line``
        (roughly a condition number above ``1/rcond_line``) is reported as NaN in ``per_line``.
    """
    known = dict(known or {})
    u = system.unit_m
    p = system.reference_point_m
    ne = _normal_equations(system, known, input_weights)
    prm, Kw, Fw, N, rhs = ne.prm, ne.Kw, ne.Fw, ne.N, ne.rhs
    T, x0 = prm.T, prm.x0
    n_theta = T.shape[1]
    n_lines = system.K.shape[0]

    # Per line ---------------------------------------------------------------------------------
    theta_l, piv_l = _solve_lines(N, rhs)
    ill = piv_l < _REFINE_PIVOT
    if ill.any():  # ill-conditioned lines: refine with residuals of the unsquared system
        idx = np.nonzero(ill)[0]
        A_t, b_t = _explicit_system(Kw[idx], Fw[idx], T, x0)
        theta_l[idx] = _refine(A_t, b_t, N[idx], theta_l[idx])
    x_l = theta_l @ T.T + x0
    per_line = _to_parameters(x_l, p, u)
    per_line[piv_l < rcond_line**2] = np.nan

    # Joint ------------------------------------------------------------------------------------
    w_l = np.ones(n_lines) if line_weights is None else np.asarray(line_weights, float)
    if w_l.shape != (n_lines,) or np.any(w_l < 0):
        raise SetupError(f"line_weights must be {n_lines} non-negative numbers, one per line")
    theta, rank, cond, resid = _solve_joint(ne, w_l, rcond)
    x = prm.T @ theta + prm.x0
    joint = _to_parameters(x, p, u)

    finite = per_line[np.all(np.isfinite(per_line), axis=1)]
    stats: dict[str, dict[str, float]] = {}
    for i, name in enumerate(PARAMETERS):
        col = finite[:, i] if finite.size else np.array([np.nan])
        stats[name] = {
            "mean": float(np.mean(col)),
            "std": float(np.std(col, ddof=1)) if col.size > 1 else 0.0,
            "min": float(np.min(col)),
            "max": float(np.max(col)),
        }
    if method == "joint":
        params = joint
    elif method == "mean":
        if finite.size == 0:
            raise SolverError(
                "no line of the band has full rank; use method 'joint' or widen the band"
            )
        params = finite.mean(axis=0)
        for k, v in known.items():  # known values stay exact
            params[PARAMETERS.index(k)] = v
    else:
        raise SetupError(f"method {method!r} is unknown; use 'joint' or 'mean'")

    I_p = vector_to_inertia(params[4:])
    props = (
        RigidBodyProperties.from_about_point(float(params[0]), params[1:4], I_p, p)
        if params[0] != 0
        else None
    )
    if props is None:
        raise SolverError(
            "the estimated mass is exactly zero; the data carry no inertia information"
        )
    result = DimResult(
        properties=props,
        reference_point_m=p,
        parameters=params,
        frequencies_hz=system.frequencies_hz,
        per_line=per_line,
        band_stats=stats,
        method=method,
        rank=rank,
        n_unknowns=n_theta,
        condition_number=float(cond),
        residual_rel=resid,
        unknowns=prm.names,
        known=known,
        length_unit=system.length_unit,
        responses=system.responses,
        inputs=system.inputs,
        load_cells=system.load_cells,
        response_condition=system.response_condition,
    )
    if check_plausibility:
        result = replace(
            result, diagnostics=plausibility(result.properties, system.hull_points_m, result)
        )
    return result


def line_residuals(system: DimSystem, *, known: Mapping[str, float] | None = None) -> FloatArray:
    """Relative residual of the DIM equations of every line, each solved on its own.

    ``r(ω) = ‖A(ω) x(ω) − b(ω)‖ / ‖b(ω)‖`` with ``x(ω)`` the per-line least-squares solution
    (stacked real and imaginary parts and inputs; known properties eliminated as in
    :func:`solve_system`). From the normal equations, ``‖A x − b‖² = ‖b‖² − x·Aᵀb`` at the optimum.
    Noise gives a floor; a line where the rigid-body equations do not hold (unmeasured support
    forces, an elastic mode) stands out above it.

    Returns
    -------
    ndarray, shape (n_lines,)
        NaN on lines without load (``‖b‖ = 0``).
    """
    kn = dict(known or {})
    prm = _parameterisation(kn, system.reference_point_m, system.unit_m)
    N_full, rhs_full, bb = _gram_normal_equations(system.K, system.F)
    T, x0 = prm.T, prm.x0
    Nx0 = N_full @ x0
    N = T.T @ N_full @ T
    rhs = (rhs_full - Nx0) @ T
    bb_t = bb - 2.0 * rhs_full @ x0 + Nx0 @ x0
    theta, _ = _solve_lines(N, rhs)
    r2 = bb_t - np.einsum("li,li->l", theta, rhs)
    with np.errstate(divide="ignore", invalid="ignore"):
        out: FloatArray = np.sqrt(np.clip(r2, 0.0, None) / bb)
    out[~(bb > 0)] = np.nan
    return out


def solve(
    frf: FrfData,
    setup: TestSetup,
    *,
    band_hz: tuple[float, float] | None = None,
    known: Mapping[str, float] | None = None,
    length_unit: str | None = None,
    reference_point_m: Sequence[float] | NDArray[np.floating] | None = None,
    method: Method = "joint",
    input_weights: NDArray[np.floating] | None = None,
    line_weights: NDArray[np.floating] | None = None,
) -> DimResult:
    """Assemble and solve in one call; ``known`` defaults to ``setup.known``.

    See :func:`assemble` and :func:`solve_system`.
    """
    system = assemble(
        frf, setup, band_hz=band_hz, length_unit=length_unit, reference_point_m=reference_point_m
    )
    kn = setup.known.as_dict() if known is None else dict(known)
    return solve_system(
        system, known=kn, method=method, input_weights=input_weights, line_weights=line_weights
    )
