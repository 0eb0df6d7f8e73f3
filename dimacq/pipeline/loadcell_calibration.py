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

The load plan (:class:`LoadPlan`, :func:`standard_load_plan`) is a list of *series*: one cell
orientation (gravity ``d`` in the cell frame) and one hanger point ``r``, loaded in steps and
unloaded again (``0, ½M, M, ½M, 0``), so every series has a zero at each end (tare and linear
zero-drift correction, :func:`series_zero_corrected`), a loading and an unloading reading at
``½M`` (hysteresis) and the full load. Series come in mirrored pairs (``d → −d``: the cell turned
over), so every load has its negative in the plan: a nonlinearity even in the load (tension vs
compression) does not bias the fitted matrix. :func:`check_load_plan` refuses a plan whose loads
do not span the six components and names the combination it never excites.

Readings are averaged once settled (:func:`settled_mean`: the slope over the averaging window
tells a creeping reading from a settled one). :func:`static_certificate` fits ``C`` and reports
per axis, in % of the rated load, what a calibration certificate gives: nonlinearity (the mean of
the loading and unloading readings against the applied load), hysteresis (unloading − loading at
the same load), crosstalk (error on one axis while the others are loaded) and the expanded
uncertainty (k = 2) from the fit's residuals and the stated uncertainty of the applied loads.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from dimacq.errors import DataError, SetupError, SolverError
from dimacq.pipeline.line_noise import scatter_sigma
from dimacq.pipeline.rigid_body import load_cell_transform

__all__ = [
    "STANDARD_GRAVITY",
    "LoadCase",
    "LoadCellCalibrationFit",
    "LoadPlan",
    "SettledReading",
    "StaticCertificate",
    "check_load_plan",
    "dead_weight_loads",
    "inertial_calibration",
    "inertial_loads",
    "series_zero_corrected",
    "settled_mean",
    "solve_calibration_matrix",
    "standard_load_plan",
    "static_calibration",
    "static_certificate",
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
    matrix_std : ndarray, shape (6, 12), optional
        Standard uncertainty of each element of ``C`` from the fit's residuals alone:
        ``C = F P`` with ``P = V_k Σ_k⁻¹ U_kᵀ``, row ``i`` with residual variance
        ``s_i² = ‖R_i‖² / (N − k)``, so ``Var C_ib = s_i² (U_k Σ_k⁻² U_kᵀ)_bb`` (residuals taken
        as independent: a lower bound where neighbouring lines share their errors).
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
    matrix_std: NDArray[np.float64] | None = None


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
    s_row = np.linalg.norm(R, axis=1) / np.sqrt(max(G.shape[1] - k, 1))
    p_col = np.sqrt(np.sum((U[:, :k] / s[:k]) ** 2, axis=1))  # √(U_k Σ_k⁻² U_kᵀ)_bb
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
        matrix_std=s_row[:, None] * p_col[None, :],
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


# ---------------------------------------------------------------------------------------------
# Static (dead-weight) calibration: load plan, settled readings, certificate
# ---------------------------------------------------------------------------------------------
AXIS_NAMES = ("Fx", "Fy", "Fz", "Mx", "My", "Mz")
_CELL_AXES = {"+x": 0, "-x": 0, "+y": 1, "-y": 1, "+z": 2, "-z": 2}


@dataclass(frozen=True)
class LoadCase:
    """One reading of a dead-weight calibration.

    Attributes
    ----------
    series : int
        The loading series (one orientation and one hanger point).
    step : int
        Position in the series (0 = its first zero).
    mass_kg : float
        Weights on the hanger (0 for the series' zeros).
    position_m : tuple of 3 float
        Hanger point (where the weights' line of action passes), cell frame, m.
    gravity : tuple of 3 float
        Unit gravity direction in the cell frame (the cell's orientation on the bench).
    phase : {"zero", "loading", "unloading"}
        Zeros open and close a series; a load is "loading" while the series goes up.
    orientation : str
        How the cell is turned, for the operator (e.g. ``"cell +z up"``).
    point : str
        Name of the hanger point, for the operator (e.g. ``"arm +x"``).
    """

    series: int
    step: int
    mass_kg: float
    position_m: tuple[float, float, float]
    gravity: tuple[float, float, float]
    phase: Literal["zero", "loading", "unloading"]
    orientation: str = ""
    point: str = ""

    def prompt(self) -> str:
        """What the operator is asked to do."""
        what = "empty hanger (zero)" if self.mass_kg == 0 else f"{self.mass_kg:g} kg on the hanger"
        return (
            f"series {self.series + 1}, step {self.step + 1}: {self.orientation}, hanger at "
            f"{self.point} ({', '.join(f'{1e3 * v:.1f}' for v in self.position_m)} mm): {what}"
        )


@dataclass(frozen=True, eq=False)
class LoadPlan:
    """The load cases of a dead-weight calibration, in the order the operator applies them.

    Attributes
    ----------
    cases : tuple of LoadCase
    rated_load : ndarray, shape (6,)
        Full scale per axis (N, N·m): the reference of every % FS figure.
    mass_rel_uncertainty : float
        Standard uncertainty of the weights, relative (e.g. 5e-5 for OIML class M1 sets).
    position_uncertainty_m : float
        Standard uncertainty of each hanger point (digitized geometry), m.
    gravity_uncertainty_rad : float
        Standard uncertainty of the cell's orientation (levelling), rad.
    """

    cases: tuple[LoadCase, ...]
    rated_load: NDArray[np.float64]
    mass_rel_uncertainty: float = 5e-5
    position_uncertainty_m: float = 5e-6
    gravity_uncertainty_rad: float = 1e-4

    def loads(self) -> NDArray[np.float64]:
        """Applied loads ``[m g d; r × m g d]`` per case, shape (6, n_cases), cell frame."""
        return dead_weight_loads(
            [c.mass_kg for c in self.cases],
            [c.position_m for c in self.cases],
            [c.gravity for c in self.cases],
        )

    def load_uncertainty(self) -> NDArray[np.float64]:
        """Standard uncertainty of each applied load component, shape (6, n_cases).

        ``u(f) = |f| u_m`` ⊕ ``m g u_θ`` (tilt); ``u(M) = |M| u_m`` ⊕ ``m g u_r √2`` (point)
        ⊕ ``|r| m g u_θ``, components in quadrature.
        """
        F = self.loads()
        m = np.array([c.mass_kg for c in self.cases])
        r = np.linalg.norm(np.array([c.position_m for c in self.cases]), axis=1)
        w = m * STANDARD_GRAVITY
        u = np.empty_like(F)
        u[:3] = np.hypot(
            np.abs(F[:3]) * self.mass_rel_uncertainty, w * self.gravity_uncertainty_rad
        )
        u[3:] = np.sqrt(
            (np.abs(F[3:]) * self.mass_rel_uncertainty) ** 2
            + 2 * (w * self.position_uncertainty_m) ** 2
            + (r * w * self.gravity_uncertainty_rad) ** 2
        )
        return u


def standard_load_plan(
    rated_load: ArrayLike,
    *,
    arm_m: float = 0.1,
    height_m: float = 0.05,
    levels: tuple[float, ...] = (0.5, 1.0),
    mass_step_kg: float = 0.5,
    minimal: bool = False,
    points: dict[str, tuple[float, float, float]] | None = None,
    mass_rel_uncertainty: float = 5e-5,
    position_uncertainty_m: float = 5e-6,
    gravity_uncertainty_rad: float = 1e-4,
) -> LoadPlan:
    """Series that load every axis to about its rated load, in both signs, up and down.

    The loading arm carries hanger points at the cell's centre line (``(0, 0, h)``) and at
    ``±a`` along the two other axes; the cell is turned so that gravity runs along ``∓x``,
    ``∓y`` or ``∓z`` of the cell. Gravity along ``z`` at the centre gives ``Fz``; at ``(±a, 0,
    h)`` ``Fz`` and ``My``; at ``(0, ±a, h)`` ``Fz`` and ``Mx``; along ``x`` at the centre ``Fx``
    and ``My = h Fx``, at ``(0, ±a, 0)`` ``Fx`` and ``Mz``; likewise for ``y``. The mass of a
    series is the largest multiple of ``mass_step_kg`` that keeps every axis within its rated
    load; each series is ``0, l₁M, …, M, …, l₁M, 0`` for ``levels = (l₁, …, 1)``.
    ``minimal`` keeps one offset point per orientation (14 series instead of 22). Points are
    named ``centre``, ``arm ±x`` / ``arm ±y`` (at height ``h``, cell upright or turned over)
    and ``ring ±x`` / ``ring ±y`` (in the cell's plane, cell on its side); ``points`` replaces
    the nominal position of a named point by its digitized one (cell frame, m).

    Returns
    -------
    LoadPlan
    """
    R = np.asarray(rated_load, dtype=float).reshape(6)
    if np.any(R <= 0):
        raise SetupError("rated_load: give six positive full-scale values (N, N·m)")
    if not levels or levels[-1] != 1.0 or any(not 0 < lv <= 1 for lv in levels):
        raise SetupError(
            f"levels {levels}: give increasing fractions of the series' mass ending at 1"
        )
    a, h = float(arm_m), float(height_m)
    points_given = dict(points or {})
    series: list[tuple[str, tuple[float, float, float], str, tuple[float, float, float]]] = []
    for ax in ("z", "x", "y"):
        k = "xyz".index(ax)
        others = [i for i in range(3) if i != k]
        centre = [0.0, 0.0, h]
        hangers: list[tuple[str, list[float]]] = [("centre", centre)]
        offsets = others if ax == "z" else [i for i in others if i != 2] + [2]
        for i in offsets:
            if ax != "z" and i == 2:
                continue
            for sgn in (1.0, -1.0) if not minimal else (1.0,):
                pnt = [0.0, 0.0, h if ax == "z" else 0.0]
                pnt[i] = sgn * a
                where = "arm" if ax == "z" else "ring"
                hangers.append((f"{where} {'+' if sgn > 0 else '-'}{'xyz'[i]}", pnt))
        for pname, pnt in hangers:
            if points_given and pname in points_given:
                pnt = [float(v) for v in points_given[pname]]
            for gs in (-1.0, 1.0):
                d = [0.0, 0.0, 0.0]
                d[k] = gs
                up = f"{'+' if gs < 0 else '-'}{ax}"
                series.append(
                    (f"cell {up} up", (d[0], d[1], d[2]), pname, (pnt[0], pnt[1], pnt[2]))
                )
    cases: list[LoadCase] = []
    for s_i, (orient, g_dir, pname, point) in enumerate(series):
        u = dead_weight_loads([1.0], [point], g_dir)[:, 0]  # load per kg
        m_max = float(np.min(R / np.maximum(np.abs(u), 1e-300)))
        M = np.floor(m_max / mass_step_kg + 1e-9) * mass_step_kg
        if M <= 0:
            raise SetupError(
                f"series {s_i + 1} ({orient}, {pname}): one kilogram already exceeds a rated "
                "load; shorten the arm"
            )
        steps = [0.0, *[lv * M for lv in levels], *[lv * M for lv in reversed(levels[:-1])], 0.0]
        n_up = len(levels)
        for k_s, mass in enumerate(steps):
            phase: Literal["zero", "loading", "unloading"] = (
                "zero" if mass == 0 else "loading" if k_s <= n_up else "unloading"
            )
            cases.append(LoadCase(s_i, k_s, float(mass), point, g_dir, phase, orient, pname))
    known = {c.point for c in cases}
    unknown = sorted(set(points_given) - known)
    if unknown:
        raise SetupError(
            f"digitized points {unknown} are not hanger points of the plan; use "
            f"{', '.join(sorted(known))}"
        )
    return LoadPlan(
        tuple(cases),
        R,
        mass_rel_uncertainty=mass_rel_uncertainty,
        position_uncertainty_m=position_uncertainty_m,
        gravity_uncertainty_rad=gravity_uncertainty_rad,
    )


def check_load_plan(plan: LoadPlan) -> list[str]:
    """Refuse a plan that does not determine the matrix; return warnings for weaker ones.

    The loads ``F`` (6 × n), scaled by the rated loads, must have rank 6: otherwise the
    combination ``v`` (right singular vector of the smallest singular value) is never excited
    and ``C`` is undetermined along it; the error names it (e.g. ``0.71 Fx − 0.71 Mz``).

    Raises
    ------
    SetupError
        Fewer than 12 loaded cases, or the loads do not span all six components.

    Returns
    -------
    list of str
        Warnings: an axis never loaded in one sign, below half its rated load, or never both
        loaded and unloaded (no hysteresis figure).
    """
    F = plan.loads() / plan.rated_load[:, None]
    loaded = [c for c in plan.cases if c.mass_kg > 0]
    if len(loaded) < 12:
        raise SetupError(
            f"load plan: {len(loaded)} loaded cases; the 12 gauges need at least 12 (add series)"
        )
    U, sv, _ = np.linalg.svd(F, full_matrices=True)
    weak = sv < 1e-3 * sv[0] if sv.size == 6 else np.ones(6, bool)
    if sv.size < 6 or weak.any():
        names = []
        for k in np.flatnonzero(np.concatenate([weak, np.ones(6 - sv.size, bool)])[:6]):
            v = U[:, k]
            v = v * np.sign(v[np.argmax(np.abs(v))])
            terms = [
                f"{'+' if c > 0 else '−'} {abs(c):.2f} {AXIS_NAMES[i]}"
                for i, c in enumerate(v)
                if abs(c) > 0.1
            ]
            names.append(" ".join(terms).lstrip("+ "))
        raise SetupError(
            "load plan does not determine the calibration matrix: the loads never excite "
            + "; ".join(names)
            + " (per rated load); add series with the cell turned or hanger points off that "
            "axis"
        )
    warnings = []
    for i, name in enumerate(AXIS_NAMES):
        if F[i].max() < 0.5 or F[i].min() > -0.5:
            warnings.append(
                f"{name} reaches {100 * F[i].max():.0f} % / {100 * F[i].min():.0f} % of its rated "
                "load; nonlinearity is characterised only over that range"
            )
    ups = {(c.series, c.mass_kg) for c in plan.cases if c.phase == "loading"}
    downs = {(c.series, c.mass_kg) for c in plan.cases if c.phase == "unloading"}
    if not ups & downs:
        warnings.append("no load is applied both loading and unloading: no hysteresis figure")
    return warnings


@dataclass(frozen=True)
class SettledReading:
    """The mean of a settled window of readings.

    Attributes
    ----------
    mean : ndarray, shape (12,)
    std_error : ndarray, shape (12,)
        Of the mean (sample std / √n).
    drift : ndarray, shape (12,)
        Change over the window from a straight-line fit (slope × duration).
    settled : bool
        ``|drift| ≤ max(tolerance · |step|, 4 × std of the drift estimate)`` on every gauge.
    n_samples : int
    """

    mean: NDArray[np.float64]
    std_error: NDArray[np.float64]
    drift: NDArray[np.float64]
    settled: bool
    n_samples: int


def settled_mean(samples: ArrayLike, step: ArrayLike, *, tolerance: float = 2e-5) -> SettledReading:
    """Average a window of gauge readings and tell whether they still creep.

    A line ``g(t) = a + b t`` is fitted per gauge over the window (``t`` centred, n samples);
    ``drift = b (n − 1)`` with standard error ``σ √(12 / n)`` (slope std ``σ √(12/n³)`` times
    the duration), ``σ`` the white noise estimated robustly from the sample-to-sample
    differences (``1.4826 MAD(Δg) / √2``, :func:`dimacq.pipeline.line_noise.scatter_sigma`),
    so a step or a swing in the window counts as drift. The window is settled when every
    gauge's drift is within
    ``tolerance · |step|`` (``step``: the reading's change from the series zero, so the creep
    allowed is a fraction of the load change) or within four of its own standard errors.

    Parameters
    ----------
    samples : array_like, shape (12, n)
    step : array_like, shape (12,)
    tolerance : float
    """
    g = np.asarray(samples, dtype=float)
    if g.ndim != 2 or g.shape[1] < 8:
        raise DataError(f"samples {g.shape}: give (12, n ≥ 8) readings")
    if not np.all(np.isfinite(g)):
        raise DataError("readings contain NaN (frames lost); repeat the reading")
    n = g.shape[1]
    t = np.arange(n) - (n - 1) / 2
    mean = g.mean(axis=1)
    b = (g - mean[:, None]) @ t / (t @ t)
    # Noise from the sample-to-sample differences (median absolute deviation): a step or a
    # swing inside the window inflates a fit's residual, not this; so they count as drift.
    sig = scatter_sigma(g.T, 1)
    drift = b * (n - 1)
    drift_se = sig * np.sqrt(12.0 / n)
    ok = np.abs(drift) <= np.maximum(tolerance * np.abs(np.asarray(step, float)), 4 * drift_se)
    return SettledReading(mean, g.std(axis=1, ddof=1) / np.sqrt(n), drift, bool(ok.all()), n)


def series_zero_corrected(
    readings: ArrayLike, times_s: ArrayLike, plan: LoadPlan
) -> NDArray[np.float64]:
    """Readings minus each series' zero, the zero drifting linearly between its two ends.

    For series ``s`` with zero readings ``z₀`` at ``t₀`` (first case) and ``z₁`` at ``t₁``
    (last), ``g − z₀ − (z₁ − z₀)(t − t₀)/(t₁ − t₀)``: the tare of the arm's own weight and the
    zero's drift with temperature, removed.

    Parameters
    ----------
    readings : array_like, shape (n_cases, 12)
    times_s : array_like, shape (n_cases,)
        When each reading was taken (centre of its window).
    plan : LoadPlan

    Returns
    -------
    ndarray, shape (n_cases, 12)
    """
    g = np.asarray(readings, dtype=float)
    t = np.asarray(times_s, dtype=float)
    out = np.empty_like(g)
    series = np.array([c.series for c in plan.cases])
    for s in np.unique(series):
        idx = np.flatnonzero(series == s)
        zeros = [i for i in idx if plan.cases[i].phase == "zero"]
        if not zeros:
            raise SetupError(f"load plan series {s + 1} has no zero reading; start it empty")
        i0, i1 = zeros[0], zeros[-1]
        if i1 != i0 and t[i1] > t[i0]:
            slope = (g[i1] - g[i0]) / (t[i1] - t[i0])
        else:
            slope = np.zeros(g.shape[1])
        out[idx] = g[idx] - g[i0] - np.outer(t[idx] - t[i0], slope)
    return out


@dataclass(frozen=True, eq=False)
class StaticCertificate:
    """A static calibration with the figures of a calibration certificate (per axis, % FS).

    Attributes
    ----------
    fit : LoadCellCalibrationFit
    matrix_std : ndarray, shape (6, 12)
        Standard uncertainty of each element of ``C``.
    errors : ndarray, shape (6, n_loaded)
        ``C g − F`` at the loaded cases (N, N·m).
    nonlinearity_pct_fs, hysteresis_pct_fs, uncertainty_pct_fs : ndarray, shape (6,)
    crosstalk_pct_fs : ndarray, shape (6, 6)
        ``[i, j]``: largest error on axis ``i`` while axis ``j`` carries the largest share of
        the load and axis ``i`` less than 5 % of its rated load.
    rated_load : ndarray, shape (6,)
    verdict : {"ok", "warn", "fail"}
    reasons : tuple of str
    """

    fit: LoadCellCalibrationFit
    matrix_std: NDArray[np.float64]
    errors: NDArray[np.float64]
    nonlinearity_pct_fs: NDArray[np.float64]
    hysteresis_pct_fs: NDArray[np.float64]
    uncertainty_pct_fs: NDArray[np.float64]
    crosstalk_pct_fs: NDArray[np.float64]
    rated_load: NDArray[np.float64]
    verdict: str
    reasons: tuple[str, ...]


def _same_load_groups(
    cases: list[LoadCase],
) -> Iterator[tuple[list[int], list[int], list[int]]]:
    """Readings of one load of one series, in (series, mass) order: all, loading, unloading."""
    key = [(c.series, c.mass_kg) for c in cases]
    for kk in sorted(set(key)):
        idx = [i for i, q in enumerate(key) if q == kk]
        up = [i for i in idx if cases[i].phase == "loading"]
        down = [i for i in idx if cases[i].phase == "unloading"]
        yield idx, up, down


def _hysteresis_free_fit_data(
    G: NDArray[np.float64], F: NDArray[np.float64], R: NDArray[np.float64], cases: list[LoadCase]
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Gauges (12, n_fit) and loads (6, n_fit) the matrix is fitted to.

    The mean ``½(g_up + g_down)`` of the loading and unloading readings of a load, and single
    readings (series tops) only where every axis is at ≥ 90 % of its rated load or ≤ 5 % (the
    loop closes there); otherwise the loading branch of the tops would bias ``C``. A plan
    without pairs (too few points or loads of rank < 6) fits every reading.
    """
    fit_G, fit_F = [], []
    for idx, up, down in _same_load_groups(cases):
        if up and down:
            fit_G.append(0.5 * (G[:, up[0]] + G[:, down[0]]))
            fit_F.append(0.5 * (F[:, up[0]] + F[:, down[0]]))
        else:
            for i in idx:
                xi = np.abs(F[:, i]) / R
                if np.all((xi >= 0.9) | (xi <= 0.05)):
                    fit_G.append(G[:, i])
                    fit_F.append(F[:, i])
    Gf, Ff = np.array(fit_G).T, np.array(fit_F).T
    if Gf.shape[1] < N_GAUGES or np.linalg.matrix_rank(Ff / R[:, None], tol=1e-3) < 6:
        Gf, Ff = G, F
    return Gf, Ff


def _hysteresis_points(
    E: NDArray[np.float64], F: NDArray[np.float64], cases: list[LoadCase]
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.bool_]]:
    """Hysteresis ``max |e_down − e_up|`` (6,) and the hysteresis-free points.

    Returns the hysteresis, the points' applied loads ``F_p`` and errors ``e_p`` (6, n_points)
    (``½(e_up + e_down)`` for a load read both ways, ``e`` for a single reading) and which
    points are single readings (n_points,).
    """
    hyst = np.zeros(6)
    pts_F: list[NDArray[np.float64]] = []
    pts_e: list[NDArray[np.float64]] = []
    single_pts: list[bool] = []
    for idx, up, down in _same_load_groups(cases):
        if up and down:
            e_up, e_dn = E[:, up[0]], E[:, down[0]]
            pts_F.append(0.5 * (F[:, up[0]] + F[:, down[0]]))
            pts_e.append(0.5 * (e_up + e_dn))
            single_pts.append(False)
            hyst = np.maximum(hyst, np.abs(e_dn - e_up))
        else:
            for i in idx:
                pts_F.append(F[:, i])
                pts_e.append(E[:, i])
                single_pts.append(True)
    return hyst, np.array(pts_F).T, np.array(pts_e).T, np.array(single_pts, dtype=bool)


def _bfsl_nonlinearity(
    PF: NDArray[np.float64],
    PE: NDArray[np.float64],
    single: NDArray[np.bool_],
    R: NDArray[np.float64],
) -> NDArray[np.float64]:
    """``max_p |e_p − k_i F_p|`` (6,) against each axis's best straight line through zero.

    ``k_i = Σ F e / Σ F²`` over the points used: a residual gain (the hysteresis of single top
    readings pulls the matrix fit slightly) is a sensitivity error, not nonlinearity. A single
    reading carries the loading branch's hysteresis except near the rated load, where the loop
    closes: axis ``i`` keeps its single readings at ≥ 90 % FS (or unloaded).
    """
    xs = np.abs(PF) / R[:, None]
    use = ~single[None, :] | (xs >= 0.9) | (xs < 1e-9)
    W = use.astype(float)
    k_gain = np.sum(W * PF * PE, axis=1) / np.maximum(
        np.sum(W * PF**2, axis=1), np.finfo(float).tiny
    )
    out: NDArray[np.float64] = np.max(W * np.abs(PE - k_gain[:, None] * PF), axis=1)
    return out


def _crosstalk_pct_fs(
    E: NDArray[np.float64], F: NDArray[np.float64], R: NDArray[np.float64]
) -> NDArray[np.float64]:
    """``[i, j]`` (6, 6): ``100 max |e_i| / R_i`` over the readings where axis ``j`` carries the
    largest share of its rated load and axis ``i`` less than 5 % of its own."""
    x = np.abs(F) / R[:, None]
    dominant = np.argmax(x, axis=0)
    cross = np.zeros((6, 6))
    for i in range(6):
        quiet = x[i] < 0.05
        for j in range(6):
            sel = quiet & (dominant == j)
            if j != i and sel.any():
                cross[i, j] = 100 * np.max(np.abs(E[i, sel])) / R[i]
    return cross


def _certificate_verdict(
    warnings: list[str],
    plan: LoadPlan,
    unsettled: ArrayLike | None,
    nonlin: NDArray[np.float64],
    hyst: NDArray[np.float64],
    R: NDArray[np.float64],
    residual_rel: float,
) -> tuple[str, list[str]]:
    """``fail`` when the residual exceeds 1 % of the loads, ``warn`` when the plan warned,
    readings crept or nonlinearity or hysteresis exceeds 0.5 % FS; with the reasons."""
    reasons = list(warnings)
    verdict = "ok"
    if unsettled is not None and np.any(unsettled):
        bad = [plan.cases[i].prompt() for i in np.flatnonzero(np.asarray(unsettled, bool))]
        reasons.append(
            f"{len(bad)} reading(s) still creeping when taken (first: {bad[0]}); "
            "allow a longer settling time"
        )
    figures = np.concatenate([100 * nonlin / R, 100 * hyst / R])
    if figures.max() > 0.5:
        reasons.append(f"nonlinearity or hysteresis up to {figures.max():.2f} % FS")
    if reasons:
        verdict = "warn"
    if residual_rel > 0.01:
        verdict = "fail"
        reasons.append(
            f"residual {100 * residual_rel:.2f} % of the loads: the readings do not follow "
            "the plan (a weight or hanger point wrong, a gauge broken)"
        )
    return verdict, reasons


def static_certificate(
    gauges: ArrayLike,
    plan: LoadPlan,
    *,
    gauge_coupling: Literal["DC", "AC"] = "DC",
    rank: int | None = 6,
    unsettled: ArrayLike | None = None,
) -> StaticCertificate:
    """Fit ``C`` from zero-corrected readings of a load plan and report it as a certificate.

    Parameters
    ----------
    gauges : array_like, shape (n_cases, 12)
        Settled, zero-corrected readings (:func:`series_zero_corrected`), mV/V or V.
    plan : LoadPlan
        The plan the readings follow (cases in the same order).
    unsettled : array_like of bool, shape (n_cases,), optional
        Readings that were still creeping when taken (a warning).

    Definitions (``e = C g − F`` per axis ``i``, ``R_i`` its rated load):

    - nonlinearity: the hysteresis-free points ``p`` (``½(e_up + e_down)`` at loads applied
      both ways, ``e`` at loads applied once — the top of a series — where the axis is at
      ≥ 90 % of its rated load, the loop closing there) against the best straight
      line through zero of axis ``i`` (BFSL): ``max |e_p − k_i F_p| / R_i`` with
      ``k_i = Σ F e / Σ F²``;
    - hysteresis: ``max |e_down − e_up|`` at the same load of the same series, ``/ R_i``;
    - uncertainty (k = 2): ``2 √(s_i² + ū_i²) / R_i`` with ``s_i`` the rms residual of axis ``i``
      (``√(Σe² / (n − 6))``: noise, nonlinearity and hysteresis) and ``ū_i`` the rms standard
      uncertainty of the applied loads (:meth:`LoadPlan.load_uncertainty`);
    - ``matrix_std``: ``C = F P`` with ``P = V₆ Σ₆⁻¹ U₆ᵀ`` (rank-6 least squares), so row ``i``
      has covariance ``s_i² PᵀP``.

    The verdict is ``fail`` when the residual exceeds 1 % of the loads (a wrong plan or a
    broken gauge), ``warn`` when readings crept or a figure exceeds 0.5 % FS.
    """
    warnings = check_load_plan(plan)
    g = np.asarray(gauges, dtype=float)
    n = len(plan.cases)
    if g.shape != (n, N_GAUGES):
        raise DataError(f"gauges {g.shape}: give ({n}, 12) readings, one per load case")
    loaded = np.array([c.mass_kg > 0 for c in plan.cases])
    F_all = plan.loads()
    G = g[loaded].T
    F = F_all[:, loaded]
    R = plan.rated_load
    cases = [c for c in plan.cases if c.mass_kg > 0]
    Gf, Ff = _hysteresis_free_fit_data(G, F, R, cases)
    fit = static_calibration(Gf.T, np.zeros(N_GAUGES), Ff, gauge_coupling=gauge_coupling, rank=rank)
    C = fit.matrix
    E = C @ G - F
    n_l = int(loaded.sum())
    dof = max(n_l - 6, 1)
    s = np.sqrt(np.sum(E**2, axis=1) / dof)
    U, sv, Vt = np.linalg.svd(Gf, full_matrices=False)
    k = fit.rank_used
    P = (Vt[:k].T / sv[:k]) @ U[:, :k].T  # (n_fit, 12)
    matrix_std = s[:, None] * np.sqrt(np.sum(P**2, axis=0))[None, :]
    u_ref = np.sqrt(np.mean(plan.load_uncertainty()[:, loaded] ** 2, axis=1))
    uncertainty = 200 * np.sqrt(s**2 + u_ref**2) / R
    hyst, PF, PE, single = _hysteresis_points(E, F, cases)
    nonlin = _bfsl_nonlinearity(PF, PE, single, R)
    cross = _crosstalk_pct_fs(E, F, R)
    verdict, reasons = _certificate_verdict(
        warnings, plan, unsettled, nonlin, hyst, R, fit.residual_rel
    )
    return StaticCertificate(
        fit=fit,
        matrix_std=matrix_std,
        errors=E,
        nonlinearity_pct_fs=100 * nonlin / R,
        hysteresis_pct_fs=100 * hyst / R,
        uncertainty_pct_fs=uncertainty,
        crosstalk_pct_fs=cross,
        rated_load=R,
        verdict=verdict,
        reasons=tuple(reasons),
    )
