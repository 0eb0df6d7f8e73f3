"""Excitation line of action from points digitized along one jig rod (thesis §2.1.3, Eq. 13).

The jig rod in the mounting base at the input node gives the direction of the force. From the
``n`` digitized points ``x_i`` (GCS) and the input node ``x_O``:

* Thesis Eq. 13: per-axis standard deviations, normalised to unit length, signed per component
  by the input node relative to the mean::

      C_j = sgn(x_O,j - x̄_j) σ_j / sqrt(σ_x² + σ_y² + σ_z²)

  Exact for noise-free points on a line; measurement noise inflates every ``σ_j`` (small
  components most), and a component near zero can take the wrong sign.
* Principal direction: the first right singular vector ``v_1`` of the centred points
  ``X - x̄``, signed so that ``v_1 · (x_O - x̄) > 0`` (the same convention: pointing towards the
  input node, i.e. into the structure). Its angular standard deviation is about
  ``σ_⊥ / sqrt(Σ t_i²)`` with ``t_i`` the centred positions along the line and ``σ_⊥`` the
  perpendicular scatter.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from dimacq.errors import DataError, SetupError

__all__ = ["LineOfAction", "angle_between_deg", "line_of_action_svd", "line_of_action_thesis"]

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class LineOfAction:
    """Unit direction of an excitation with quality measures.

    Attributes
    ----------
    direction : ndarray, shape (3,)
        Unit vector, pointing from the points' mean towards the input node.
    point_m : ndarray, shape (3,)
        Mean of the digitized points (on the line).
    method : str
        ``"thesis"`` (Eq. 13) or ``"svd"``.
    perpendicular_rms_m : float
        RMS distance of the points from the fitted line.
    angle_std_deg : float
        Expected angular error (``nan`` for the thesis method, which has no fit).
    """

    direction: FloatArray
    point_m: FloatArray
    method: str
    perpendicular_rms_m: float
    angle_std_deg: float


def _inputs(points_m: ArrayLike, input_node_m: ArrayLike) -> tuple[FloatArray, FloatArray]:
    x = np.asarray(points_m, dtype=float)
    o = np.asarray(input_node_m, dtype=float).reshape(-1)
    if x.ndim != 2 or x.shape[1] != 3 or len(x) < 2 or o.shape != (3,):
        raise SetupError(
            f"line of action: points {x.shape} must be (n >= 2, 3) and the input node a 3-vector"
        )
    if not np.isfinite(x).all() or not np.isfinite(o).all():
        raise DataError(
            "line of action: NaN in the digitized points or the input node; digitize again"
        )
    return x, o


def _perp(x: FloatArray, mean: FloatArray, d: FloatArray) -> tuple[FloatArray, FloatArray]:
    y = x - mean
    t = y @ d
    return t, y - np.outer(t, d)


def line_of_action_thesis(points_m: ArrayLike, input_node_m: ArrayLike) -> LineOfAction:
    """Thesis Eq. 13: normalised per-axis standard deviations signed by ``x_O - x̄``."""
    x, o = _inputs(points_m, input_node_m)
    mean = x.mean(axis=0)
    sigma = x.std(axis=0, ddof=1)
    norm = float(np.linalg.norm(sigma))
    if norm == 0.0:
        raise DataError("line of action: all points coincide; digitize indentations along the rod")
    sign = np.sign(o - mean)
    sign[sign == 0] = 1.0
    d = sign * sigma / norm
    _, perp = _perp(x, mean, d)
    return LineOfAction(
        direction=d,
        point_m=mean,
        method="thesis",
        perpendicular_rms_m=float(np.sqrt(np.mean(np.sum(perp**2, axis=1)))),
        angle_std_deg=float("nan"),
    )


def line_of_action_svd(points_m: ArrayLike, input_node_m: ArrayLike) -> LineOfAction:
    """Principal direction of the centred points, signed towards the input node."""
    x, o = _inputs(points_m, input_node_m)
    mean = x.mean(axis=0)
    _, s, vt = np.linalg.svd(x - mean, full_matrices=False)
    if s[0] == 0.0:
        raise DataError("line of action: all points coincide; digitize indentations along the rod")
    d = vt[0]
    along = float((o - mean) @ d)
    if abs(along) < 1e-9:
        raise SetupError(
            "line of action: the input node projects onto the middle of the points; its side is "
            "undefined: give the input node at the rod's base"
        )
    if along < 0:
        d = -d
    t, perp = _perp(x, mean, d)
    n = len(x)
    sigma_perp = float(np.sqrt(np.sum(perp**2) / max(2 * (n - 2), 1)))
    return LineOfAction(
        direction=d,
        point_m=mean,
        method="svd",
        perpendicular_rms_m=float(np.sqrt(np.mean(np.sum(perp**2, axis=1)))),
        angle_std_deg=float(np.degrees(np.sqrt(2.0) * sigma_perp / np.sqrt(np.sum(t**2)))),
    )


def angle_between_deg(a: ArrayLike, b: ArrayLike) -> float:
    """Angle between two directions, degrees (robust ``atan2`` form)."""
    u = np.asarray(a, dtype=float)
    v = np.asarray(b, dtype=float)
    return float(np.degrees(np.arctan2(np.linalg.norm(np.cross(u, v)), u @ v)))
