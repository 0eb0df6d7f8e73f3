"""The Dynamic Inertia Method solver (method.md §6–7, thesis Appendix A Eq. 32–35, §3.2).

Equations
---------
With ``a``, ``α`` the translational and angular acceleration of the reference point P, ``c`` the CG
relative to P, ``s = m c`` and ``I`` the inertia tensor about P (tensor elements), the linearised
equations of motion of a rigid body (Eq. 32) are

    F = m a − m [c]x α = a·m + [α]x s
    M = m [c]x a + I α = −[a]x s + L(α) I6

with ``L(α) = [[αx, αy, αz, 0, 0, 0], [0, αx, 0, αy, αz, 0], [0, 0, αx, 0, αy, αz]]`` and
``I6 = [Ixx, Ixy, Ixz, Iyy, Iyz, Izz]`` (Eq. 33). They are linear in
``x = [m, sx, sy, sz, Ixx, Ixy, Ixz, Iyy, Iyz, Izz]``: ``A(a, α) x = [F; M]``.

For FRFs, ``[a; α]`` per unit input j at line ω is the condensed accelerance ``K = Ψ⁺ H_acc``, and
``[F; M]`` is the sum of the input's unit force vector ``φ_j`` and the load-cell reactions mapped to
P (``dimacq.pipeline.rigid_body``). Real and imaginary parts and all inputs are stacked (Eq. 34–35);
since ``A`` is linear in the complex ``K``, the stacked normal matrix is
``N = Σ_j Re(A_jᴴ A_j)`` and the right side ``Σ_j Re(A_jᴴ b_j)``.

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

Length-unit scaling (§3.2.2.2, Table 15): the system is formed in the chosen length unit ``u``
in the consistent system (kg, u, s): positions ``r/u``, accelerations ``a/u``, forces ``F/u`` and
moments ``M/u²``, which weights moment rows against force rows by ``1/u``; the unknowns come back as
``s·u``, ``I·u²``.

FRF scaling (§3.2.2.1): ``γ`` such that the band mass of the solution with FRFs ``γ·H`` equals a
known mass, found with a bracketing root finder (Brent) since load-cell reactions make the mass a
nonlinear function of ``γ``.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from dimacq.errors import DataError, SetupError, SolverError
from dimacq.model.frf import Channel, FrfData
from dimacq.model.properties import (
    RigidBodyProperties,
    principal_moments,
    vector_to_inertia,
)
from dimacq.model.setup import LENGTH_UNITS, PARAMETERS, TestSetup
from dimacq.pipeline.rigid_body import (
    condense,
    force_vectors,
    load_cell_transform,
    response_matrix,
    skew,
)

__all__ = [
    "Diagnostic",
    "DimResult",
    "DimSystem",
    "assemble",
    "design_matrices",
    "line_residuals",
    "plausibility",
    "scale_to_known_mass",
    "solve",
    "solve_joint",
    "solve_system",
]

log = logging.getLogger("dimacq.pipeline.dim")

FloatArray = NDArray[np.float64]
ComplexArray = NDArray[np.complex128]
Method = Literal["joint", "mean"]

_I_KEYS = PARAMETERS[4:]
#: θ's first moments ``s = m·c`` reported as the CG parameter they estimate.
_UNKNOWN_NAME = {"sx": "cx", "sy": "cy", "sz": "cz"}


# --------------------------------------------------------------------------------------------
# Assembly: from FRFs and setup to condensed motion K and summed forces F at P
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class DimSystem:
    """Condensed motion and summed forces at P, in the working length unit.

    Attributes
    ----------
    frequencies_hz : ndarray, shape (n_lines,)
    K : ndarray, shape (n_lines, 6, n_inputs), complex
        ``[a; α]`` of P per unit input; ``a`` in unit/s²/N, ``α`` in rad/s²/N.
    F : ndarray, shape (n_lines, 6, n_inputs), complex
        Summed load on the structure at P per unit input force, in the consistent unit system
        (kg, unit, s): forces in (N/u)/N, moments in (N·m/u²)/N.
    unit_m : float
        Metres per working length unit.
    reference_point_m : ndarray, shape (3,)
    responses, inputs : tuple of Channel
        The channels used, in the order of the FRF.
    load_cells : tuple of int
        Nodes of the load cells used.
    psi : ndarray, shape (n_responses, 6)
        Rigid-body shape matrix in the working unit.
    phi : ndarray, shape (6, n_inputs)
        Unit input force vectors at P in the working unit.
    hull_points_m : ndarray, shape (n, 3)
        Measured points (responses, inputs, load cells), for the CG hull check.
    response_condition : float
        Condition number of Ψ.
    """

    frequencies_hz: FloatArray
    K: ComplexArray
    F: ComplexArray
    unit_m: float
    length_unit: str
    reference_point_m: FloatArray
    responses: tuple[Channel, ...]
    inputs: tuple[Channel, ...]
    load_cells: tuple[int, ...]
    psi: FloatArray
    phi: FloatArray
    hull_points_m: FloatArray
    response_condition: float

    def select_inputs(self, keep: NDArray[np.intp] | Sequence[int]) -> DimSystem:
        """The same system with only the given input indices."""
        k = np.asarray(keep, dtype=np.intp)
        return replace(
            self,
            K=self.K[:, :, k],
            F=self.F[:, :, k],
            inputs=tuple(self.inputs[i] for i in k),
            phi=self.phi[:, k],
        )

    def select_lines(self, keep: NDArray[np.bool_] | NDArray[np.intp]) -> DimSystem:
        return replace(
            self, frequencies_hz=self.frequencies_hz[keep], K=self.K[keep], F=self.F[keep]
        )


def assemble(
    frf: FrfData,
    setup: TestSetup,
    *,
    band_hz: tuple[float, float] | None = None,
    length_unit: str | None = None,
    reference_point_m: NDArray[np.floating] | Sequence[float] | None = None,
    response_weights: NDArray[np.floating] | None = None,
) -> DimSystem:
    """Match the FRFs to the setup, condense the responses and sum the forces at P.

    Parameters
    ----------
    frf : FrfData
        Accelerance outputs (matched to ``setup.responses`` by node and direction) and load cell
        outputs (directions ±1..±6 of each ``setup.load_cells`` node; all six needed).
    setup : TestSetup
    band_hz : (lo, hi), optional
        Keep only these lines.
    length_unit : {"m", "cm", "mm"}, optional
        Working unit; default ``setup.length_unit``.
    reference_point_m : (3,), optional
        Default ``setup.reference_point_m``.
    response_weights : ndarray, shape (n_acceleration_outputs,), optional
        Weights of the accelerometer channels in the condensation (0 drops one).
    """
    unit = length_unit or setup.length_unit
    if unit not in LENGTH_UNITS:
        raise SetupError(f"length unit {unit!r} is unknown; use one of {', '.join(LENGTH_UNITS)}")
    u = LENGTH_UNITS[unit]
    p = np.asarray(
        setup.reference_point_m if reference_point_m is None else reference_point_m, float
    )
    if p.shape != (3,) or not np.all(np.isfinite(p)):
        raise SetupError("reference point must be three finite coordinates in metres")
    if band_hz is not None:
        lo, hi = band_hz
        if not lo < hi:
            raise SetupError(f"band {lo:g}–{hi:g} Hz is empty; give LO < HI")
        frf = frf.band(lo, hi)

    # Responses -------------------------------------------------------------------------------
    acc_idx = frf.output_index("acceleration")
    if acc_idx.size == 0:
        raise DataError("the FRFs hold no acceleration output; DIM needs accelerometer FRFs")
    out_keys = _channel_keys(frf.outputs)
    r_at, r_sign = _match_channels(out_keys[acc_idx], _channel_keys(setup.responses))
    if np.any(r_at < 0):
        ch = frf.outputs[int(acc_idx[np.argmax(r_at < 0)])]
        raise SetupError(
            f"response {ch.name} of the FRFs is not in the setup; add it to responses "
            "with its position and direction, or drop the record"
        )
    pos = setup.response_positions[r_at]
    dirs = r_sign[:, None] * setup.response_directions[r_at]
    psi = response_matrix(pos / u, dirs, p / u)
    cond = condense(psi, response_weights)
    H = frf.H
    K = _apply_real(cond.transform / u, H, acc_idx)

    # Inputs ------------------------------------------------------------------------------------
    e_at, e_sign = _match_channels(_channel_keys(frf.inputs), _channel_keys(setup.excitations))
    if np.any(e_at < 0):
        ch = frf.inputs[int(np.argmax(e_at < 0))]
        raise SetupError(
            f"input {ch.name} of the FRFs has no line of action in the setup; add it to "
            "excitations with position_m and direction_gcs"
        )
    in_pos = setup.input_positions[e_at]
    in_dir = e_sign[:, None] * setup.input_directions[e_at]
    phi = force_vectors(in_pos / u, in_dir, p / u)
    # F = φ + Σ_cells T_c H_c: the first cell's product becomes F and φ is added to it in place
    # (x + φ is φ + x to the bit), which saves writing φ into every line first.
    F: ComplexArray | None = None

    # Load cells ----------------------------------------------------------------------------------
    cells = {lc.node: lc for lc in setup.load_cells}
    reaction_idx = frf.output_index("reaction")
    rows: dict[int, dict[int, int]] = {}
    for i in reaction_idx:
        ch = frf.outputs[i]
        if ch.node not in cells:
            raise SetupError(
                f"load cell output {ch.name} belongs to node {ch.node}, which is not a load cell of "
                "the setup; add it to load_cells with position, rotation and sign"
            )
        if not 1 <= abs(ch.direction) <= 6:
            raise DataError(f"load cell output {ch.name}: direction must be ±1..±6 (Fx..Mz)")
        rows.setdefault(ch.node, {})[ch.direction] = int(i)
    used_cells: list[int] = []
    for node, lc in cells.items():
        got = rows.get(node)
        if got is None:
            log.warning("load cell %s of the setup has no FRF records; it is left out", lc.name)
            continue
        sel = np.empty(6, dtype=np.intp)
        sgn = np.empty(6)
        for k in range(1, 7):
            if k in got:
                sel[k - 1], sgn[k - 1] = got[k], 1.0
            elif -k in got:
                sel[k - 1], sgn[k - 1] = got[-k], -1.0
            else:
                raise DataError(
                    f"load cell {lc.name} lacks its direction {k} record (Fx, Fy, Fz, Mx, My, Mz "
                    "are all needed); add it or remove the cell's other records"
                )
        scale = np.array([1, 1, 1, 1 / u, 1 / u, 1 / u]) * sgn
        T = load_cell_transform(
            np.asarray(lc.position_m) / u, lc.rotation_matrix, p / u, lc.sign_factor
        )
        reactions = _apply_real(T * scale[None, :], H, sel)
        if F is None:
            F = reactions
            F += phi
        else:
            F += reactions
        used_cells.append(node)
    if F is None:  # no load cell: the hammer forces alone
        F = np.empty_like(K)
        F[...] = phi

    # Consistent units (kg, unit, s): forces are kg·unit/s² = N/u, moments kg·unit²/s² = N·m/u².
    # So far F holds forces in N and moments in N·unit (N·m/u): one more division by u, on the
    # real view (a complex array divided by a real number goes through complex division).
    F.view(np.float64)[...] /= u

    hull = np.concatenate(
        [
            pos,
            in_pos,
            np.array([c.position_m for c in setup.load_cells]).reshape(-1, 3),
        ]
    )
    return DimSystem(
        frequencies_hz=frf.frequencies_hz,
        K=K,
        F=F,
        unit_m=u,
        length_unit=unit,
        reference_point_m=p,
        responses=tuple(frf.outputs[i] for i in acc_idx),
        inputs=frf.inputs,
        load_cells=tuple(used_cells),
        psi=psi,
        phi=phi,
        hull_points_m=hull,
        response_condition=cond.condition_number,
    )


def _channel_keys(channels: Sequence[Any]) -> NDArray[np.int64]:
    """(node, direction) of channels or setup items, shape (n, 2)."""
    return np.array([(c.node, c.direction) for c in channels], dtype=np.int64).reshape(-1, 2)


def _match_channels(
    keys: NDArray[np.int64], table: NDArray[np.int64]
) -> tuple[NDArray[np.intp], FloatArray]:
    """Row of ``table`` holding each (node, direction) of ``keys``, or its opposite direction.

    The same direction wins over the opposite one (a setup may list both). Returns the rows
    (−1 where neither is in the table) and the signs (+1 same direction, −1 opposite).
    """
    if table.shape[0] == 0:
        return np.full(keys.shape[0], -1, dtype=np.intp), np.ones(keys.shape[0])
    # Integer codes of (node, direction): UFF directions are within ±6.
    code_t = table[:, 0] * 64 + table[:, 1]
    order = np.argsort(code_t, kind="stable")
    sorted_t = code_t[order]

    def find(codes: NDArray[np.int64]) -> NDArray[np.intp]:
        at = np.searchsorted(sorted_t, codes)
        at_c = np.minimum(at, sorted_t.size - 1)
        hit = sorted_t[at_c] == codes
        return np.where(hit, order[at_c], -1).astype(np.intp)

    same = find(keys[:, 0] * 64 + keys[:, 1])
    opposite = find(keys[:, 0] * 64 - keys[:, 1])
    rows = np.where(same >= 0, same, opposite)
    sign = np.where(same >= 0, 1.0, -1.0)
    return rows, sign


def _apply_real(M: FloatArray, H: ComplexArray, rows: NDArray[np.intp]) -> ComplexArray:
    """``M @ H[:, rows, :]`` for a real matrix M, as one real matmul on the (re, im) view.

    Rows that form a consecutive run are read in place (a strided view that BLAS takes as it
    is); others are gathered with ``np.take`` (numpy's fancy indexing on the middle axis of a
    complex array is several times slower). Both give the same bits as a gathered copy.
    """
    n_lines, _, n_in = H.shape
    Hr = H.view(np.float64) if H.flags.c_contiguous else np.ascontiguousarray(H).view(np.float64)
    r = np.asarray(rows, dtype=np.intp)
    if r.size and r[-1] - r[0] == r.size - 1 and np.all(np.diff(r) == 1):
        Hs = Hr[:, r[0] : r[-1] + 1]
    else:
        Hs = np.take(Hr, r, axis=1)
    out = M @ Hs  # (L, k, 2J)
    return out.view(np.complex128).reshape(n_lines, M.shape[0], n_in)


def design_matrices(K: NDArray[Any]) -> NDArray[Any]:
    """DIM design matrices ``A(a, α)`` for every line and input.

    Parameters
    ----------
    K : ndarray, shape (..., 6, n_inputs)
        ``[a; α]`` per input.

    Returns
    -------
    ndarray, shape (..., n_inputs, 6, 10)
        Rows ``[F; M]``, columns ``[m, sx, sy, sz, Ixx, Ixy, Ixz, Iyy, Iyz, Izz]`` (Eq. 33).
    """
    k = np.moveaxis(np.asarray(K), -1, -2)  # (..., n_inputs, 6)
    a, al = k[..., :3], k[..., 3:]
    A: NDArray[Any] = np.zeros(k.shape[:-1] + (6, 10), dtype=k.dtype)
    A[..., :3, 0] = a
    A[..., :3, 1:4] = skew(al)
    A[..., 3:, 1:4] = -skew(a)
    ax, ay, az = al[..., 0], al[..., 1], al[..., 2]
    A[..., 3, 4], A[..., 3, 5], A[..., 3, 6] = ax, ay, az
    A[..., 4, 5], A[..., 4, 7], A[..., 4, 8] = ax, ay, az
    A[..., 5, 6], A[..., 5, 8], A[..., 5, 9] = ax, ay, az
    return A


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
# Results
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Diagnostic:
    """One plausibility or quality check, reported whatever its outcome."""

    code: str
    ok: bool
    message: str
    severity: Literal["info", "warning", "error"] = "warning"

    def as_dict(self) -> dict[str, Any]:
        return {
            "code": self.code,
            "ok": self.ok,
            "severity": self.severity,
            "message": self.message,
        }


@dataclass(frozen=True, eq=False)
class DimResult:
    """A DIM solution with its evidence.

    Attributes
    ----------
    properties : RigidBodyProperties
        Headline answer (CG in the GCS, inertia about the CG).
    reference_point_m : ndarray, shape (3,)
    parameters : ndarray, shape (10,)
        ``[m, cx, cy, cz, Ixx, Ixy, Ixz, Iyy, Iyz, Izz]``, CG in the GCS (m), inertia about P (kg·m²).
    frequencies_hz : ndarray, shape (n_lines,)
    per_line : ndarray, shape (n_lines, 10)
        The spectrum of estimates, same layout as ``parameters`` (NaN on lines of rank < unknowns).
    band_stats : dict
        Per parameter: ``mean``, ``std``, ``min``, ``max`` over the lines of the band.
    method : {"joint", "mean"}
        Joint least squares over the band, or mean of the per-line estimates.
    rank, n_unknowns : int
    condition_number : float
        Of the column-equilibrated design matrix (joint system).
    residual_rel : float
        ``‖A x − b‖ / ‖b‖`` over the band.
    unknowns : tuple of str
    known : dict
    """

    properties: RigidBodyProperties
    reference_point_m: FloatArray
    parameters: FloatArray
    frequencies_hz: FloatArray
    per_line: FloatArray
    band_stats: dict[str, dict[str, float]]
    method: str
    rank: int
    n_unknowns: int
    condition_number: float
    residual_rel: float
    unknowns: tuple[str, ...]
    known: dict[str, float]
    length_unit: str
    responses: tuple[Channel, ...]
    inputs: tuple[Channel, ...]
    load_cells: tuple[int, ...]
    response_condition: float
    diagnostics: tuple[Diagnostic, ...] = ()
    extras: dict[str, Any] = field(default_factory=dict)

    @property
    def mass_kg(self) -> float:
        return self.properties.mass_kg

    @property
    def cg_m(self) -> FloatArray:
        return self.properties.cg_m

    @property
    def inertia_p_kgm2(self) -> FloatArray:
        return self.properties.inertia_about(self.reference_point_m)

    @property
    def inertia_cg_kgm2(self) -> FloatArray:
        return self.properties.inertia_cg_kgm2

    @property
    def band_hz(self) -> tuple[float, float]:
        return float(self.frequencies_hz[0]), float(self.frequencies_hz[-1])

    def to_json(self) -> dict[str, Any]:
        """The JSON of ``dimacq solve --json``."""
        out = self.properties.to_json(self.reference_point_m)
        out.update(
            {
                "band_hz": list(self.band_hz),
                "n_lines": int(self.frequencies_hz.size),
                "method": self.method,
                "length_unit": self.length_unit,
                "known": dict(self.known),
                # the estimated parameters by their names (θ holds s = m·c where the mass is
                # unknown: that is the CG being estimated)
                "unknowns": [_UNKNOWN_NAME.get(u, u) for u in self.unknowns],
                "band_statistics": self.band_stats,
                "rank": self.rank,
                "n_unknowns": self.n_unknowns,
                "condition_number": self.condition_number,
                "response_condition_number": self.response_condition,
                "residual_rel": self.residual_rel,
                "responses_used": [c.as_dict() for c in self.responses],
                "inputs_used": [c.as_dict() for c in self.inputs],
                "load_cells_used": list(self.load_cells),
                "diagnostics": [d.as_dict() for d in self.diagnostics],
            }
        )
        out.update(self.extras)
        return out


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
    T, x0 = prm.T, prm.x0
    if known:
        Nx0 = N_full @ x0  # (L, 10)
        N = T.T @ N_full @ T  # (L, nθ, nθ)
        rhs = (rhs_full - Nx0) @ T  # (L, nθ)
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


# --------------------------------------------------------------------------------------------
# Plausibility
# --------------------------------------------------------------------------------------------
def plausibility(
    props: RigidBodyProperties, hull_points_m: FloatArray, result: DimResult | None = None
) -> tuple[Diagnostic, ...]:
    """Physical checks on an estimate, all reported whatever their outcome.

    - ``mass_positive``: m > 0.
    - ``inertia_cg_positive_definite``: eigenvalues of I_CG > 0.
    - ``triangle_inequality``: each principal moment ≤ the sum of the other two (a real mass
      distribution satisfies ``I1 + I2 ≥ I3``).
    - ``cg_inside_hull``: the CG lies inside the convex hull of the measured points (responses,
      inputs, load cells); outside it is possible but suspicious.
    - ``condition``: condition number of the design matrix (warning above 1e6).
    """
    diags: list[Diagnostic] = []
    m = props.mass_kg
    diags.append(
        Diagnostic(
            "mass_positive",
            m > 0,
            f"mass {m:.6g} kg " + ("> 0" if m > 0 else "≤ 0: not physical"),
            "error",
        )
    )
    w, _ = principal_moments(props.inertia_cg_kgm2)
    pd = bool(np.all(w > 0))
    diags.append(
        Diagnostic(
            "inertia_cg_positive_definite",
            pd,
            "principal moments about the CG "
            + ", ".join(f"{x:.6g}" for x in w)
            + " kg·m²"
            + ("" if pd else ": not positive definite, not physical"),
            "error",
        )
    )
    tri = bool(w[0] + w[1] >= w[2] * (1 - 1e-9)) and pd
    diags.append(
        Diagnostic(
            "triangle_inequality",
            tri,
            f"I1 + I2 = {w[0] + w[1]:.6g} {'≥' if tri else '<'} I3 = {w[2]:.6g} kg·m²"
            + ("" if tri else ": no real mass distribution has these principal moments"),
            "error",
        )
    )
    diags.append(_hull_check(props.cg_m, hull_points_m))
    if result is not None:
        ok = result.condition_number < 1e6
        diags.append(
            Diagnostic(
                "condition",
                ok,
                f"condition number of the equilibrated design matrix {result.condition_number:.3g}"
                + ("" if ok else ": the estimate is sensitive to noise; add or spread the inputs"),
                "warning" if not ok else "info",
            )
        )
    return tuple(diags)


def _hull_check(cg: FloatArray, points: FloatArray) -> Diagnostic:
    """CG inside the convex hull of the points: on their side of every facet plane, within
    1e-9 of their extent (:func:`dimacq.pipeline.rotations.inside_hull`)."""
    from dimacq.pipeline.rotations import inside_hull

    pts = np.asarray(points, float)
    scale = float(np.ptp(pts, axis=0).max()) if pts.size else 0.0
    inside = inside_hull(cg, pts, 1e-9 * scale)
    if inside is None:
        return Diagnostic(
            "cg_inside_hull",
            True,
            "measured points are coplanar; CG hull check not possible",
            "info",
        )
    return Diagnostic(
        "cg_inside_hull",
        inside,
        "CG inside the hull of the measured points"
        if inside
        else "CG lies outside the hull of the measured points; check signs and geometry",
        "warning",
    )


# --------------------------------------------------------------------------------------------
# FRF scaling to a known mass
# --------------------------------------------------------------------------------------------
def scale_to_known_mass(
    frf: FrfData,
    setup: TestSetup,
    mass_kg: float,
    *,
    band_hz: tuple[float, float] | None = None,
    kinds: tuple[Literal["acceleration", "reaction"], ...] = ("acceleration", "reaction"),
    length_unit: str | None = None,
    xtol: float = 1e-12,
) -> tuple[float, DimResult]:
    """Find ``γ`` with band mass of the solution on ``γ·H`` equal to ``mass_kg`` (thesis §3.2.2.1).

    ``kinds`` says which FRFs carry the scale error: both (a force transducer sensitivity error)
    or only the accelerations. With reactions present the mass is not ``m(1)/γ``; Brent's method
    on a bracket found by expanding around the reaction-free guess ``γ0 = m(1)/m_known``.

    Returns
    -------
    gamma : float
    result : DimResult
        The solution on the scaled FRFs (mass not imposed).
    """
    from scipy.optimize import brentq  # here: scipy.optimize costs start-up time to every solve

    if not mass_kg > 0:
        raise SetupError(f"known mass {mass_kg} kg must be positive")
    if band_hz is not None:
        frf = frf.band(*band_hz)

    def mass(gamma: float) -> float:
        sys_ = assemble(frf.scaled(gamma, kinds), setup, length_unit=length_unit)
        return solve_system(sys_, check_plausibility=False).mass_kg

    m1 = mass(1.0)
    g0 = m1 / mass_kg if m1 > 0 else 1.0
    lo, hi = g0 / 1.5, g0 * 1.5
    f_lo, f_hi = mass(lo) - mass_kg, mass(hi) - mass_kg
    for _ in range(40):
        if f_lo * f_hi < 0:
            break
        lo, hi = lo / 2.0, hi * 2.0
        f_lo, f_hi = mass(lo) - mass_kg, mass(hi) - mass_kg
    else:
        raise SolverError(
            f"no FRF scale factor between {lo:.3g} and {hi:.3g} gives a mass of {mass_kg} kg; "
            "check the known mass and the FRF units"
        )
    gamma = float(
        brentq(lambda g: mass(g) - mass_kg, lo, hi, xtol=xtol, rtol=4 * np.finfo(float).eps)
    )
    sys_ = assemble(frf.scaled(gamma, kinds), setup, length_unit=length_unit)
    result = solve_system(sys_)
    return gamma, replace(result, extras={**result.extras, "frf_scale_factor": gamma})
