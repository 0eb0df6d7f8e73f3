"""6-DOF load cell calibration on the bench (method §8): inertial and static (dead weights).

The load cell's 12 gauges ``g`` give its forces and moments in its own frame by a 6×12 matrix:
``F_L = [f_L; m_L] = C g``.

Inertial calibration
--------------------
The calibration mass (known ``m``, CG ``c`` and inertia ``I_P`` about the reference point P) is
fixed to the load cell and excited on the support side, so the load cell carries every dynamic
force on the mass. Newton–Euler about P (method §6, linearised) gives the load on the mass at P

    F_P = M_rb a_P,    M_rb = [[m E, −m [c]x], [m [c]x, I_P]],    a_P = [ü_P; θ̈]

with ``a_P = T_q q`` condensed from the accelerometers (``T_q = Ψ⁺``, method §4). The cell's
local load maps to P as ``F_P = s T_c F_L`` with ``T_c = [[R, 0], [[r_c − P]x R, R]]`` and ``s``
the sign (+1 when the cell reads the force on the mass), hence

    F_L = s T_c⁻¹ M_rb a_P        (6 values per line and input)

Stacking real and imaginary parts over lines and inputs, ``F`` (6 × N) and ``G`` (12 × N), the
calibration solves ``C G = F`` in the least-squares sense.

Twelve gauges measure six loads: in a noise-free world ``G = S F`` has rank 6 (``S`` is the 12×6
gauge sensitivity) and any ``C`` with ``C S = E`` fits; the minimum-norm one is ``S⁺``, which is
what a rank-6 truncated SVD of ``G`` returns (``C = F V₆ Σ₆⁻¹ U₆ᵀ``). Noise fills the other six
singular values of ``G``; truncating them keeps ``C`` from fitting noise. The diagnostics report
all 12 singular values (``σ₇/σ₆`` measures how well the 6-D load space stands out of the noise),
the condition ``σ₁/σ₆`` (how evenly the excitation spans the six loads) and the residual.

Static calibration
------------------
Known dead weights ``m_k`` hung at known points ``r_k`` (cell frame) with gravity along unit
``d`` (cell frame) load the cell with ``F_L = [m_k g d; r_k × m_k g d]`` (tare subtracted); the
same least squares gives ``C``. Only for DC-coupled resistive bridges: piezoelectric gauges are
AC-coupled and cannot hold a static load, so :func:`static_calibration` refuses them with a
:class:`~dimacq.errors.SetupError` pointing to the inertial method.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from dimacq.errors import DataError, SetupError, SolverError
from dimacq.pipeline.rigid_body import load_cell_transform

__all__ = [
    "STANDARD_GRAVITY",
    "LoadCellCalibrationFit",
    "dead_weight_loads",
    "inertial_calibration",
    "inertial_loads",
    "solve_calibration_matrix",
    "static_calibration",
]

STANDARD_GRAVITY = 9.80665
N_GAUGES = 12


@dataclass(frozen=True, eq=False)
class LoadCellCalibrationFit:
    """A fitted calibration matrix with its quality measures.

    Attributes
    ----------
    matrix : ndarray, shape (6, 12)
        ``C``: N per gauge volt (rows Fx, Fy, Fz) and N·m per gauge volt (Mx, My, Mz).
    residual_rel : float
        ``‖C G − F‖_F / ‖F‖_F``.
    residual_rel_per_load : ndarray, shape (6,)
        The same per row of ``F`` (Fx .. Mz).
    singular_values : ndarray, shape (12,)
        Of the stacked gauge matrix ``G`` (12 × N), descending.
    rank_used : int
        Singular values kept (6 by default).
    condition : float
        ``σ₁ / σ_rank``: how evenly the data excite the kept load directions.
    noise_separation : float
        ``σ_{rank+1} / σ_rank`` (0 for noise-free data): small means the gauges' load space
        stands well out of the noise.
    load_condition : float
        Condition number of the applied loads ``F`` (6 × N): > 1e6 means some load component
        was hardly excited.
    n_equations : int
        Real equations per gauge (columns of ``G``).
    method : {"inertial", "static"}
    """

    matrix: NDArray[np.float64]
    residual_rel: float
    residual_rel_per_load: NDArray[np.float64]
    singular_values: NDArray[np.float64]
    rank_used: int
    condition: float
    noise_separation: float
    load_condition: float
    n_equations: int
    method: str


def solve_calibration_matrix(
    gauges: ArrayLike,
    loads: ArrayLike,
    *,
    rank: int | None = 6,
    method: str = "inertial",
) -> LoadCellCalibrationFit:
    """Least-squares ``C`` from ``C G = F``.

    Parameters
    ----------
    gauges : array_like, shape (12, N)
        Real gauge data ``G`` (volts or V/N).
    loads : array_like, shape (6, N)
        Real loads ``F`` in the cell frame, same columns.
    rank : int or None
        Truncate ``G`` to this many singular values (6: the load space); None for the plain
        least-squares solution on all 12.

    Raises
    ------
    SolverError
        The loads do not excite all six components (rank of ``F`` < 6) or ``G`` has fewer than
        ``rank`` significant singular values.
    """
    G = np.asarray(gauges, dtype=float)
    F = np.asarray(loads, dtype=float)
    if G.ndim != 2 or G.shape[0] != N_GAUGES or F.shape != (6, G.shape[1]):
        raise DataError(
            f"gauges {G.shape} and loads {F.shape}: give (12, N) gauges and (6, N) loads "
            "with the same N columns"
        )
    if not (np.all(np.isfinite(G)) and np.all(np.isfinite(F))):
        raise DataError("gauges or loads contain NaN/inf; drop the averages with lost samples")
    if G.shape[1] < N_GAUGES:
        raise DataError(f"{G.shape[1]} equations for 12 gauges; use more lines or load cases")
    sF = np.linalg.svd(F, compute_uv=False)
    load_cond = float(sF[0] / sF[-1]) if sF[-1] > 0 else np.inf
    if sF[-1] <= sF[0] * 1e-10:
        raise SolverError(
            "the applied loads do not span all six components (rank < 6): excite the "
            "calibration mass in more directions (impacts on three faces, off its CG) or add "
            "dead-weight positions"
        )
    U, s, Vt = np.linalg.svd(G, full_matrices=False)
    k = N_GAUGES if rank is None else int(rank)
    if not 1 <= k <= N_GAUGES:
        raise SetupError(f"rank={rank}; give 1..12 or None")
    if s[k - 1] <= s[0] * 1e-12:
        raise SolverError(
            f"the gauge data have fewer than {k} significant singular values "
            f"({np.array2string(s, precision=3)}); a gauge is dead or the loads are degenerate"
        )
    C = (F @ Vt[:k].T / s[:k]) @ U[:, :k].T
    R = C @ G - F
    per = np.linalg.norm(R, axis=1) / np.maximum(np.linalg.norm(F, axis=1), np.finfo(float).tiny)
    return LoadCellCalibrationFit(
        matrix=C,
        residual_rel=float(np.linalg.norm(R) / np.linalg.norm(F)),
        residual_rel_per_load=per,
        singular_values=s,
        rank_used=k,
        condition=float(s[0] / s[k - 1]),
        noise_separation=float(s[k] / s[k - 1]) if k < N_GAUGES else 0.0,
        load_condition=load_cond,
        n_equations=int(G.shape[1]),
        method=method,
    )


def inertial_loads(
    accel_p: ArrayLike,
    mass_matrix: ArrayLike,
    cell_position_m: ArrayLike,
    cell_rotation: ArrayLike,
    reference_point_m: ArrayLike,
    sign: float = 1.0,
) -> NDArray[np.complex128]:
    """Loads in the cell frame ``F_L = s T_c⁻¹ M_rb a_P``, vectorised over lines and inputs.

    Parameters
    ----------
    accel_p : array_like, shape (n_lines, 6, n_inputs), complex
        ``[ü_P; θ̈]`` per line and input (e.g. condensed accelerance, (m/s²)/N and (rad/s²)/N).
    mass_matrix : array_like, shape (6, 6)
        ``M_rb`` of the calibration mass about P.
    cell_position_m, cell_rotation, reference_point_m, sign
        The cell's origin (GCS), local-to-global rotation, P, and +1 when it reads the force on
        the mass.

    Returns
    -------
    ndarray, shape (n_lines, 6, n_inputs)
    """
    a = np.asarray(accel_p)
    if a.ndim != 3 or a.shape[1] != 6:
        raise DataError(f"accel_p has shape {a.shape}; give (n_lines, 6, n_inputs)")
    M = np.asarray(mass_matrix, dtype=float)
    if M.shape != (6, 6):
        raise DataError(f"mass_matrix has shape {M.shape}; give the 6x6 rigid-body mass matrix")
    T = load_cell_transform(
        np.asarray(cell_position_m, float),
        np.asarray(cell_rotation, float),
        np.asarray(reference_point_m, float),
        sign,
    )
    A = np.linalg.solve(T, M)  # T⁻¹ M
    return np.asarray(np.einsum("ij,ljk->lik", A, a))


def inertial_calibration(
    gauge_frf: ArrayLike,
    accel_p: ArrayLike,
    mass_matrix: ArrayLike,
    cell_position_m: ArrayLike,
    cell_rotation: ArrayLike,
    reference_point_m: ArrayLike,
    *,
    sign: float = 1.0,
    rank: int | None = 6,
) -> LoadCellCalibrationFit:
    """Inertial calibration: ``C`` from gauge FRFs and the calibration mass's motion.

    Parameters
    ----------
    gauge_frf : array_like, shape (n_lines, 12, n_inputs), complex
        Gauge volts per input force, over the lines of the analysis band.
    accel_p : array_like, shape (n_lines, 6, n_inputs), complex
        Rigid-body acceleration of P per input force on the same lines.
    mass_matrix, cell_position_m, cell_rotation, reference_point_m, sign
        See :func:`inertial_loads`.
    rank : int or None
        See :func:`solve_calibration_matrix`.

    Returns
    -------
    LoadCellCalibrationFit
    """
    g = np.asarray(gauge_frf)
    if g.ndim != 3 or g.shape[1] != N_GAUGES:
        raise DataError(f"gauge_frf has shape {g.shape}; give (n_lines, 12, n_inputs)")
    F = inertial_loads(
        accel_p, mass_matrix, cell_position_m, cell_rotation, reference_point_m, sign
    )
    if F.shape[0] != g.shape[0] or F.shape[2] != g.shape[2]:
        raise DataError(
            f"gauge_frf {g.shape} and accel_p {np.shape(accel_p)} must share lines and inputs"
        )
    G2 = g.transpose(1, 0, 2).reshape(N_GAUGES, -1)
    F2 = F.transpose(1, 0, 2).reshape(6, -1)
    return solve_calibration_matrix(
        np.concatenate([G2.real, G2.imag], axis=1),
        np.concatenate([F2.real, F2.imag], axis=1),
        rank=rank,
        method="inertial",
    )


def dead_weight_loads(
    masses_kg: ArrayLike,
    positions_m: ArrayLike,
    gravity_direction: ArrayLike,
) -> NDArray[np.float64]:
    """Loads of dead weights in the cell frame: ``[m g d; r × m g d]``, shape (6, n_loads).

    Parameters
    ----------
    masses_kg : array_like, shape (n_loads,)
    positions_m : array_like, shape (n_loads, 3)
        Where each weight's line of action passes, in the cell frame (its hanger point).
    gravity_direction : array_like, shape (3,) or (n_loads, 3)
        Unit vector of gravity in the cell frame (the cell may be turned between load cases).
    """
    m = np.asarray(masses_kg, dtype=float)
    r = np.asarray(positions_m, dtype=float).reshape(-1, 3)
    d = np.broadcast_to(np.asarray(gravity_direction, dtype=float), r.shape)
    if not np.allclose(np.linalg.norm(d, axis=1), 1.0, atol=1e-9):
        raise SetupError("gravity_direction must be a unit vector in the cell frame")
    f = m[:, None] * STANDARD_GRAVITY * d
    return np.concatenate([f, np.cross(r, f)], axis=1).T


def static_calibration(
    gauges_v: ArrayLike,
    tare_v: ArrayLike,
    loads: ArrayLike,
    *,
    gauge_coupling: Literal["DC", "AC"],
    rank: int | None = 6,
) -> LoadCellCalibrationFit:
    """Dead-weight calibration of a DC-coupled (resistive bridge) load cell.

    Parameters
    ----------
    gauges_v : array_like, shape (n_loads, 12)
        Steady gauge readings under each load case.
    tare_v : array_like, shape (12,)
        Readings unloaded.
    loads : array_like, shape (6, n_loads)
        From :func:`dead_weight_loads`.
    gauge_coupling : {"DC", "AC"}
        ``"AC"`` (piezoelectric gauges, as in the thesis's cell) is refused.

    Raises
    ------
    SetupError
        For AC-coupled gauges: they cannot hold a static load.
    """
    if gauge_coupling != "DC":
        raise SetupError(
            "static dead-weight calibration needs DC-coupled gauges (resistive bridges); these "
            "gauges are AC-coupled (piezoelectric) and cannot hold a static load: calibrate "
            "inertially with the calibration mass (inertial_calibration, method §8) instead"
        )
    g = np.asarray(gauges_v, dtype=float) - np.asarray(tare_v, dtype=float)[None, :]
    return solve_calibration_matrix(g.T, loads, rank=rank, method="static")
