"""Registration of the digitizer array coordinate system (DACS) in the GCS (method.md §2).

A point digitized at ``x_A`` (DACS) lies in the global coordinate system at (thesis Eq. 4)::

    x_G = T x_A + o

* :func:`three_point_frame` — no known geometry: digitize the origin, a point on +X and a point in
  the XZ plane (on the +Z side); Gram–Schmidt gives ``e_x = (p_x - p_0)/|·|``,
  ``e_z ∝ v - (v·e_x) e_x`` with ``v = p_xz - p_0``, ``e_y = e_z × e_x``; ``T`` has rows
  ``e_x, e_y, e_z`` and ``o = -T p_0``.
* :func:`register` — ``n ≥ 4`` reference nodes with known GCS coordinates, not coplanar:

  - ``"rigid"`` (default): ``T = R`` a rotation, minimising ``Σ |x_G - R x_A - o|²`` (Kabsch /
    Umeyama by :meth:`scipy.spatial.transform.Rotation.align_vectors` on centred points,
    ``o = x̄_G - R x̄_A``). The physical map is a rotation: 6 unknowns instead of 12, better
    conditioned.
  - ``"similarity"``: ``T = s R`` with the Umeyama scale ``s = Σ y_Gᵀ R y_A / Σ |y_A|²`` on
    centred points (a miscalibrated speed of sound shows up as ``s ≠ 1``).
  - ``"affine"``: the thesis's general ``T`` (Eq. 6), 12 unknowns by linear least squares on
    ``[x_Aᵀ 1]``.

  Coplanar reference nodes register only their plane (thesis §2.1.1): refused. Residuals are
  reported per node.

Large structures are digitized in patches: each array position gets its own registration from the
reference nodes it can see; the service keeps every point with its patch.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation

from dimacq.errors import DataError, SetupError

__all__ = ["Registration", "planarity", "register", "three_point_frame"]

FloatArray = NDArray[np.float64]
METHODS = ("rigid", "similarity", "affine")


@dataclass(frozen=True)
class Registration:
    """``x_G = T x_A + o`` with its quality.

    Attributes
    ----------
    matrix : ndarray, shape (3, 3)
        ``T``.
    offset_m : ndarray, shape (3,)
        ``o``.
    method : str
        ``"three-point"``, ``"rigid"``, ``"similarity"`` or ``"affine"``.
    scale : float
        ``det(T)^(1/3)`` (1 for rigid).
    residuals_m : ndarray, shape (n, 3)
        ``x_G,known - (T x_A + o)`` per reference node (zeros for the three-point frame).
    residual_norm_m : ndarray, shape (n,)
    rms_m : float
        ``sqrt(mean |residual|²)``.
    planarity : float
        Smallest over largest singular value of the centred reference nodes (0 = coplanar).
    """

    matrix: FloatArray
    offset_m: FloatArray
    method: str
    scale: float
    residuals_m: FloatArray
    residual_norm_m: FloatArray
    rms_m: float
    planarity: float

    def apply(self, points_m: ArrayLike) -> FloatArray:
        """Map DACS points, shape (..., 3), to the GCS."""
        x = np.asarray(points_m, dtype=float)
        return x @ self.matrix.T + self.offset_m

    def inverse(self, points_m: ArrayLike) -> FloatArray:
        """Map GCS points, shape (..., 3), back to the DACS."""
        x = np.asarray(points_m, dtype=float)
        return np.asarray(np.linalg.solve(self.matrix, (x - self.offset_m).T).T, dtype=np.float64)


def _points(name: str, value: ArrayLike) -> FloatArray:
    x = np.asarray(value, dtype=float)
    if x.ndim != 2 or x.shape[1] != 3:
        raise SetupError(
            f"registration: '{name}' has shape {x.shape}; give (n, 3) points in metres"
        )
    if not np.isfinite(x).all():
        raise DataError(f"registration: '{name}' contains NaN or inf; digitize those nodes again")
    return x


def planarity(points_m: ArrayLike) -> float:
    """``s_3 / s_1`` of the centred points (singular values): 0 for coplanar, ~1 for a cube."""
    x = np.asarray(points_m, dtype=float)
    s = np.linalg.svd(x - x.mean(axis=0), compute_uv=False)
    return float(s[2] / s[0]) if s[0] > 0 else 0.0


def three_point_frame(origin_m: ArrayLike, on_x_m: ArrayLike, in_xz_m: ArrayLike) -> Registration:
    """Define the GCS from three digitized DACS points: origin, a point on +X, one in XZ (+Z side).

    Raises
    ------
    SetupError
        The three points are (nearly) collinear.
    """
    p0, px, pxz = (np.asarray(p, dtype=float).reshape(3) for p in (origin_m, on_x_m, in_xz_m))
    ex = px - p0
    lx = np.linalg.norm(ex)
    v = pxz - p0
    if lx < 1e-6 or np.linalg.norm(v) < 1e-6:
        raise SetupError(
            "three-point frame: 'on_x' or 'in_xz' coincides with 'origin'; pick distinct points"
        )
    ex = ex / lx
    ez = v - (v @ ex) * ex
    lz = np.linalg.norm(ez)
    if lz < 1e-3 * np.linalg.norm(v):
        raise SetupError(
            "three-point frame: 'in_xz' lies on the X axis (collinear points); pick a point well off +X"
        )
    ez = ez / lz
    ey = np.cross(ez, ex)
    t = np.vstack([ex, ey, ez])
    return Registration(
        matrix=t,
        offset_m=-t @ p0,
        method="three-point",
        scale=1.0,
        residuals_m=np.zeros((3, 3)),
        residual_norm_m=np.zeros(3),
        rms_m=0.0,
        planarity=0.0,
    )


def register(
    points_array_m: ArrayLike,
    points_global_m: ArrayLike,
    method: str = "rigid",
    min_planarity: float = 0.02,
) -> Registration:
    """Least-squares registration from ``n ≥ 4`` non-coplanar reference nodes.

    Parameters
    ----------
    points_array_m : array_like, shape (n, 3)
        Reference nodes as digitized (DACS).
    points_global_m : array_like, shape (n, 3)
        The same nodes' known GCS coordinates.
    method : {"rigid", "similarity", "affine"}
    min_planarity : float
        Refuse node sets whose :func:`planarity` is below this (they register only a plane).

    Raises
    ------
    SetupError
        Fewer than 4 nodes, shapes differ, or the nodes are coplanar.
    """
    xa = _points("points_array_m", points_array_m)
    xg = _points("points_global_m", points_global_m)
    if method not in METHODS:
        raise SetupError(f"registration: method {method!r}; use one of {METHODS}")
    if xa.shape != xg.shape:
        raise SetupError(
            f"registration: {len(xa)} digitized nodes but {len(xg)} known nodes; give the same nodes in "
            "the same order"
        )
    n = len(xa)
    if n < 4:
        raise SetupError(
            f"registration: {n} reference nodes; give at least 4 non-coplanar nodes (or use the "
            "three-point frame)"
        )
    flat = min(planarity(xa), planarity(xg))
    if flat < min_planarity:
        raise SetupError(
            f"registration: the {n} reference nodes are coplanar (planarity {flat:.2g} < "
            f"{min_planarity}); they register only their plane: add nodes off that plane"
        )
    ca, cg = xa.mean(axis=0), xg.mean(axis=0)
    ya, yg = xa - ca, xg - cg
    if method == "affine":
        design = np.hstack([xa, np.ones((n, 1))])
        sol, *_ = np.linalg.lstsq(design, xg, rcond=None)
        t = sol[:3].T
        o = sol[3]
    else:
        rot, _ = Rotation.align_vectors(yg, ya)
        r = rot.as_matrix()
        s = 1.0
        if method == "similarity":
            s = float(np.sum(yg * (ya @ r.T)) / np.sum(ya * ya))
        t = s * r
        o = cg - t @ ca
    res = xg - (xa @ t.T + o)
    norm = np.linalg.norm(res, axis=1)
    det = float(np.linalg.det(t))
    return Registration(
        matrix=np.asarray(t, dtype=np.float64),
        offset_m=o,
        method=method,
        scale=float(np.sign(det) * abs(det) ** (1.0 / 3.0)),
        residuals_m=res,
        residual_norm_m=norm,
        rms_m=float(np.sqrt(np.mean(norm**2))),
        planarity=flat,
    )
