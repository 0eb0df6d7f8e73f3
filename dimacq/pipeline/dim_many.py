"""Many joint DIM solves of one system under different input weights (jackknife, bootstrap).

The joint least-squares normal equations of :func:`dimacq.pipeline.dim.solve_joint` are sums over
lines ``l`` and inputs ``j`` of 6×6 Gram matrices (``dim._gram_normal_equations``)::

    N(w) = Σ_l Σ_j w_j Q·Re(k̄_lj k_ljᵀ) = Q · Σ_j w_j G_j,    G_j = Re Σ_l k̄_lj k_ljᵀ   (6×6)
    r(w) = R · Σ_j w_j C_j,                                    C_j = Re Σ_l k̄_lj f_ljᵀ   (6×6)

with ``Q`` (100×36) and ``R`` (10×36) the constant maps of the design matrix. So the per-input
band sums ``G_j, C_j`` are formed once (O(L·J·36)), and every weighting ``w`` (a leave-one-input-
out, a bootstrap resample) is a (J,)·(J, 36) product and a 10×10 solve, instead of the Gram
matrices of every line again (the jackknife's 93 solves were a third of ``dimacq
solve``). Known properties enter as in ``dim._normal_equations`` (``N_θ = Tᵀ N T``,
``r_θ = (r − N x₀) T``), and the solve is ``dim._solve_normal``'s (equilibrated, minimum norm).

The sums are the same as ``solve_joint``'s in another order (over lines first, then inputs), so
the answers agree to rounding, not to the bit. A weighting whose joint system is ill conditioned
(condition > ``dim._REFINE_COND``, where ``solve_joint`` refines on the unsquared system) is
solved by ``solve_joint`` itself.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
from numpy.typing import NDArray

from dimacq.errors import SolverError
from dimacq.pipeline.dim import (
    _Q,
    _R,
    _REFINE_COND,
    DimSystem,
    _parameterisation,
    _solve_normal,
    _to_parameters,
    solve_joint,
)

__all__ = ["input_band_sums", "solve_joint_many"]

FloatArray = NDArray[np.float64]


def input_band_sums(system: DimSystem) -> tuple[FloatArray, FloatArray]:
    """Per-input band sums ``G_j = Re Σ_l k̄_lj k_ljᵀ`` and ``C_j = Re Σ_l k̄_lj f_ljᵀ``.

    Returns
    -------
    G, C : ndarray, shape (n_inputs, 36)
        Row-major 6×6 blocks (``G[j, 6 s + t] = G_j[s, t]``), as ``dim._gram_normal_equations``.
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

    Parameters
    ----------
    system : DimSystem
    weights : ndarray, shape (n_solves, n_inputs)
        Non-negative input weights of each solve.
    known : mapping, optional
        Known properties (as :func:`dimacq.pipeline.dim.solve_joint`).

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
    prm = _parameterisation(kn, np.asarray(system.reference_point_m, float), system.unit_m)
    T, x0 = prm.T, prm.x0
    n_theta = T.shape[1]
    G, C = input_band_sums(system)
    N_full = ((W @ G) @ _Q.T).reshape(-1, 10, 10)  # (S, 10, 10)
    r_full = (W @ C) @ _R.T  # (S, 10)
    N = np.swapaxes(T, 0, 1) @ N_full @ T
    rhs = (r_full - N_full @ x0) @ T
    theta, rank, cond, _ = _solve_normal(N, rhs, rcond)
    params = _to_parameters(theta @ T.T + x0, system.reference_point_m, system.unit_m)
    solved = (rank >= n_theta) & (params[:, 0] != 0) & np.all(np.isfinite(params), axis=1)
    params[~solved] = np.nan
    for s in np.nonzero(solved & (cond > _REFINE_COND))[0]:
        try:  # refined on the unsquared system, as solve_joint does
            params[s] = solve_joint(system, known=kn, input_weights=W[s], rcond=rcond)
        except SolverError:
            params[s], solved[s] = np.nan, False
    return params, solved
