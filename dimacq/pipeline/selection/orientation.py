"""Sensor orientation repair: one small rotation per sensor node fit to rigid-body motion.

The thesis asks for it as future work; SDynPy's ``rigid_body_fix_node_orientation`` optimises one
rotation per suspect node. Here every node (a triax, or any group of channels sharing a node
number) gets a rotation ``R_g``, estimated from all inputs and all lines of the band.

Model: channel i of node g at ``r_i`` with nominal direction ``d_i`` truly measures along ``R_g d_i``;
the rigid-body acceleration at its point is ``a_i = a_P + α × r_i`` with ``[a_P; α] = K`` condensed
from the *other* nodes' channels (so a node cannot hide its own error). For a small update
``R_g ← exp([δθ]x) R_g``:

    q_i ≈ (R_g d_i + δθ × R_g d_i) · a_i = d̃_i · a_i + δθ · (d̃_i × a_i)

which is linear in the real 3-vector δθ; real and imaginary parts over lines, inputs and the
node's channels are stacked and solved by least squares (Gauss–Newton). Sweeps over all nodes
repeat until the largest update is below ``tol_deg``; each sweep re-condenses K with the current
directions, so the nodes' corrections become mutually consistent. A rotation about a single
channel's own axis is unobservable (minimum-norm solution).

The rotations are *estimated* here; :func:`apply_orientation` writes corrected directions into a
new setup, only when the caller asks for it.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from dimacq.errors import SetupError
from dimacq.model.frf import Channel, FrfData
from dimacq.model.setup import TestSetup
from dimacq.pipeline.rigid_body import response_matrix
from dimacq.pipeline.selection._common import ResponseGeometry, response_geometry

__all__ = [
    "OrientationRepair",
    "apply_orientation",
    "estimate_orientation",
    "estimate_orientation_frf",
]

log = logging.getLogger(__name__)
FloatArray = NDArray[np.float64]


@dataclass(frozen=True, eq=False)
class OrientationRepair:
    """Estimated orientation corrections.

    Attributes
    ----------
    nodes : ndarray, shape (n_nodes,)
    rotvecs : ndarray, shape (n_nodes, 3)
        Rotation vectors (rad, GCS) of ``R_g``: true direction = ``R_g`` nominal direction.
    angles_deg : ndarray, shape (n_nodes,)
        ``|rotvec|`` in degrees.
    channels : tuple of Channel
    corrected_directions : ndarray, shape (n_ch, 3)
        ``R_g d_i`` for every channel (as measured by its FRF record, sign included).
    error_before, error_after : ndarray, shape (n_nodes,)
        RMS relative rigid-body error of each node's channels (prediction from the other nodes)
        with the nominal and the corrected directions.
    sweeps : int
    applied : bool
        Set by the caller when the corrections were written into the setup.
    """

    nodes: NDArray[np.int64]
    rotvecs: FloatArray
    angles_deg: FloatArray
    channels: tuple[Channel, ...]
    corrected_directions: FloatArray
    error_before: FloatArray
    error_after: FloatArray
    sweeps: int
    applied: bool = False

    def to_json(self) -> list[dict[str, Any]]:
        return [
            {
                "node": int(n),
                "angle_deg": float(a),
                "rotation_vector_deg": np.rad2deg(v).tolist(),
                "error_before": float(eb),
                "error_after": float(ea),
                "applied": self.applied,
            }
            for n, a, v, eb, ea in zip(
                self.nodes,
                self.angles_deg,
                self.rotvecs,
                self.error_before,
                self.error_after,
                strict=True,
            )
        ]


def _condense(psi: FloatArray, q: NDArray[Any], use: NDArray[np.bool_]) -> NDArray[Any] | None:
    p = psi[use]
    s = np.linalg.svd(p, compute_uv=False)
    if s.size < 6 or s[5] < s[0] * 1e-8:
        return None
    return np.einsum("ks,lsj->lkj", np.linalg.pinv(p), q[:, use, :])


def _node_error(q_i: NDArray[Any], d: FloatArray, a: NDArray[Any]) -> float:
    pred = np.einsum("cx,lcxj->lcj", d, a)
    return float(np.sqrt(np.sum(np.abs(q_i - pred) ** 2) / np.sum(np.abs(pred) ** 2)))


def estimate_orientation(
    positions_m: NDArray[np.floating],
    directions: NDArray[np.floating],
    nodes: NDArray[np.integer],
    q: NDArray[np.complexfloating],
    channels: tuple[Channel, ...],
    *,
    active: NDArray[np.bool_] | None = None,
    reference_point_m: NDArray[np.floating] | None = None,
    max_sweeps: int = 20,
    tol_deg: float = 1e-3,
) -> OrientationRepair:
    """Fit one small rotation per node to rigid-body motion (module docstring).

    Parameters
    ----------
    positions_m : ndarray, shape (n_ch, 3)
    directions : ndarray, shape (n_ch, 3)
        Nominal unit directions.
    nodes : ndarray, shape (n_ch,)
        Node of each channel; channels of one node share a rotation.
    q : ndarray, shape (n_lines, n_ch, n_inputs), complex
    active : ndarray of bool, shape (n_ch,), optional
        Channels to use (excluded channels are corrected but not used in any fit).
    """
    pos = np.asarray(positions_m, float)
    d0 = np.asarray(directions, float)
    nodes = np.asarray(nodes)
    n = pos.shape[0]
    act = np.ones(n, bool) if active is None else np.asarray(active, bool)
    p = np.zeros(3) if reference_point_m is None else np.asarray(reference_point_m, float)
    r = pos - p
    from scipy.spatial.transform import Rotation  # here: only --repair-orientation needs it

    uniq = np.unique(nodes)
    rots = [Rotation.identity() for _ in uniq]
    members = [np.nonzero(nodes == g)[0] for g in uniq]
    q = np.asarray(q)

    def accel(K: NDArray[Any], idx: NDArray[np.intp]) -> NDArray[Any]:
        # a_i = a_P + α × r_i, shape (L, c, 3, J)
        aP, al = K[:, None, :3, :], K[:, None, 3:, :]
        rr = r[idx][None, :, :, None]
        return aP + np.cross(al, rr, axis=2)

    def errors(dirs: FloatArray) -> FloatArray:
        psi = response_matrix(pos, dirs, p)
        out = np.full(uniq.size, np.nan)
        for k, idx in enumerate(members):
            K = _condense(psi, q, act & (nodes != uniq[k]))
            ia = idx[act[idx]]
            if K is None or ia.size == 0:
                continue
            out[k] = _node_error(q[:, ia, :], dirs[ia], accel(K, ia))
        return out

    before = errors(d0)
    dirs = d0.copy()
    sweeps = 0
    for sweeps in range(1, max_sweeps + 1):  # noqa: B007
        psi = response_matrix(pos, dirs, p)
        biggest = 0.0
        for k, idx in enumerate(members):
            ia = idx[act[idx]]
            if ia.size == 0:
                continue
            K = _condense(psi, q, act & (nodes != uniq[k]))
            if K is None:
                log.info("node %s cannot be repaired: the other nodes do not have rank 6", uniq[k])
                continue
            a = accel(K, ia)  # (L, c, 3, J)
            dd = dirs[ia]
            y = q[:, ia, :] - np.einsum("cx,lcxj->lcj", dd, a)  # (L, c, J)
            J = np.cross(dd[None, :, :, None], a, axis=2)  # (L, c, 3, J): d × a
            Jm = np.moveaxis(J, 2, -1).reshape(-1, 3)
            A = np.concatenate([Jm.real, Jm.imag])
            b = np.concatenate([y.reshape(-1).real, y.reshape(-1).imag])
            dth = np.linalg.lstsq(A, b, rcond=1e-8)[0]
            upd = Rotation.from_rotvec(dth)
            rots[k] = upd * rots[k]
            dirs[idx] = rots[k].apply(d0[idx])
            biggest = max(biggest, float(np.rad2deg(np.linalg.norm(dth))))
        if biggest < tol_deg:
            break
    after = errors(dirs)
    rv = np.array([rt.as_rotvec() for rt in rots]).reshape(-1, 3)
    return OrientationRepair(
        nodes=uniq.astype(np.int64),
        rotvecs=rv,
        angles_deg=np.rad2deg(np.linalg.norm(rv, axis=1)),
        channels=tuple(channels),
        corrected_directions=dirs,
        error_before=before,
        error_after=after,
        sweeps=sweeps,
    )


def estimate_orientation_frf(
    frf: FrfData,
    setup: TestSetup,
    *,
    band_hz: tuple[float, float] | None = None,
    active: NDArray[np.bool_] | None = None,
    **kwargs: Any,
) -> tuple[OrientationRepair, ResponseGeometry]:
    """:func:`estimate_orientation` on the accelerometer FRFs of a test matched to its setup."""
    data = frf.band(*band_hz) if band_hz is not None else frf
    geo = response_geometry(data, setup)
    rep = estimate_orientation(
        geo.positions_m,
        geo.directions,
        geo.nodes,
        data.H[:, geo.output_index, :],
        geo.channels,
        active=active,
        reference_point_m=setup.reference_point,
        **kwargs,
    )
    return rep, geo


def apply_orientation(
    setup: TestSetup, repair: OrientationRepair, geometry: ResponseGeometry
) -> TestSetup:
    """A copy of ``setup`` whose response directions are the repaired ones."""
    if len(geometry.channels) != repair.corrected_directions.shape[0]:
        raise SetupError(
            "the orientation repair and the response geometry do not match; estimate the repair "
            "on the same FRFs and setup"
        )
    resp = list(setup.responses)
    for k, si in enumerate(geometry.setup_index):
        d = geometry.signs[k] * repair.corrected_directions[k]
        d = d / np.linalg.norm(d)
        resp[si] = resp[si].model_copy(
            update={"direction_gcs": (float(d[0]), float(d[1]), float(d[2]))}
        )
    return setup.model_copy(update={"responses": tuple(resp)})
