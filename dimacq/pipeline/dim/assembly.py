"""Assembly of the DIM system: from FRFs and setup to the condensed motion ``K`` and the summed
forces ``F`` at P (:class:`DimSystem`, :func:`assemble`), and the design matrices ``A(a, α)``
(:func:`design_matrices`, Eq. 33).

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

Length-unit scaling (§3.2.2.2, Table 15): the system is formed in the chosen length unit ``u``
in the consistent system (kg, u, s): positions ``r/u``, accelerations ``a/u``, forces ``F/u`` and
moments ``M/u²``, which weights moment rows against force rows by ``1/u``; the unknowns come back as
``s·u``, ``I·u²``.
"""

from __future__ import annotations

import logging
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from dimacq.errors import DataError, SetupError
from dimacq.model.frf import Channel, FrfData
from dimacq.model.setup import LENGTH_UNITS, TestSetup
from dimacq.pipeline.rigid_body import (
    condense,
    force_vectors,
    load_cell_transform,
    response_matrix,
    skew,
)

#: the logger of the module before the split into a package: the messages keep its name
log = logging.getLogger("dimacq.pipeline.dim")

FloatArray = NDArray[np.float64]
ComplexArray = NDArray[np.complex128]


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
    used_cells: list[int] = []
    for node, T, rows in _cell_maps(frf, setup, u, p):
        reactions = _apply_real(T, H, rows)
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


def _cell_maps(
    frf: FrfData, setup: TestSetup, u: float, p: FloatArray
) -> Iterator[tuple[int, FloatArray, NDArray[np.intp]]]:
    """Each load cell of the setup that has FRF records: its node, its map ``T`` from the cell's
    six records (``rows`` of ``frf``'s outputs, in Fx..Mz order, their signs folded into ``T``) to
    the load at P, forces in N and moments in N·unit per N (``/u`` more for consistent units).

    Raises
    ------
    SetupError, DataError
        A reaction record of a node that is no load cell of the setup; a direction outside
        ±1..±6; a cell missing one of its six directions.
    """
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
        yield node, np.asarray(T * scale[None, :], float), sel


def cell_reactions(
    frf: FrfData, setup: TestSetup, reference_point_m: NDArray[np.floating] | None = None
) -> tuple[tuple[int, ...], ComplexArray]:
    """Each load cell's reactions at P, in SI: ``R_k = T_k H_k`` (the summand of ``F`` in
    :func:`assemble` with the length unit m), stacked per cell.

    Returns
    -------
    nodes : tuple of int
        The cells used, in the setup's order (those with FRF records).
    R : ndarray, shape (n_lines, 6 K, n_inputs), complex
        Rows ``6k..6k+5`` are cell ``k``'s force (N/N) and moment about P (N·m/N).
    """
    p = np.asarray(
        setup.reference_point_m if reference_point_m is None else reference_point_m, float
    )
    nodes: list[int] = []
    parts: list[ComplexArray] = []
    for node, T, rows in _cell_maps(frf, setup, 1.0, p):
        nodes.append(node)
        parts.append(_apply_real(T, frf.H, rows))
    if not parts:
        return (), np.zeros((frf.H.shape[0], 0, frf.H.shape[2]), complex)
    return tuple(nodes), np.concatenate(parts, axis=1)


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
