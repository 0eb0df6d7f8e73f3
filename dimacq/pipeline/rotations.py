"""Rotation matrices of rotation vectors, as ``scipy.spatial.transform.Rotation`` computes them.

``Rotation.from_rotvec(v).as_matrix()`` and ``.apply(x)`` without importing ``scipy.spatial``
(with ``scipy.sparse`` behind it, a fifth of ``dimacq solve``'s start-up), by scipy's
own steps, so that the numbers are the same:

* rotation vector → unit quaternion ``q = (s·v, cos(θ/2))`` with ``θ = |v|`` and
  ``s = sin(θ/2)/θ``, or its series ``1/2 − θ²/48 + θ⁴/3840`` for ``θ ≤ 10⁻³``;
* quaternion ``(x, y, z, w)`` → matrix
  ``[[x²−y²−z²+w², 2(xy−zw), 2(xz+yw)], [2(xy+zw), −x²+y²−z²+w², 2(yz−xw)],
  [2(xz−yw), 2(yz+xw), −x²−y²+z²+w²]]`` (Rodrigues' formula ``I + sinθ K + (1−cosθ) K²``
  written in half angles).

``tests/pipeline/test_rotations.py`` compares both with scipy's.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

__all__ = ["apply_rotvec", "rotvec_to_matrix"]


def rotvec_to_matrix(v: NDArray[np.floating]) -> NDArray[np.float64]:
    """Rotation matrices of rotation vectors ``v`` (rad), shape (..., 3) → (..., 3, 3)."""
    v = np.asarray(v, dtype=np.float64)
    theta = np.sqrt(v[..., 0] * v[..., 0] + v[..., 1] * v[..., 1] + v[..., 2] * v[..., 2])
    small = theta <= 1e-3
    t2 = theta * theta
    with np.errstate(divide="ignore", invalid="ignore"):
        scale = np.where(small, 0.5 - t2 / 48 + t2 * t2 / 3840, np.sin(theta / 2) / theta)
    x, y, z = scale * v[..., 0], scale * v[..., 1], scale * v[..., 2]
    w = np.cos(theta / 2)
    x2, y2, z2, w2 = x * x, y * y, z * z, w * w
    xy, zw, xz, yw, yz, xw = x * y, z * w, x * z, y * w, y * z, x * w
    m = np.empty(v.shape[:-1] + (3, 3))
    m[..., 0, 0] = x2 - y2 - z2 + w2
    m[..., 1, 0] = 2 * (xy + zw)
    m[..., 2, 0] = 2 * (xz - yw)
    m[..., 0, 1] = 2 * (xy - zw)
    m[..., 1, 1] = -x2 + y2 - z2 + w2
    m[..., 2, 1] = 2 * (yz + xw)
    m[..., 0, 2] = 2 * (xz + yw)
    m[..., 1, 2] = 2 * (yz - xw)
    m[..., 2, 2] = -x2 - y2 + z2 + w2
    return m


def apply_rotvec(v: NDArray[np.floating], x: NDArray[np.floating]) -> NDArray[np.float64]:
    """``Rotation.from_rotvec(v).apply(x)``: vectors ``x`` (n, 3) or (3,) turned by ``v``."""
    m = rotvec_to_matrix(v)
    xv = np.asarray(x, dtype=np.float64)
    if m.ndim == 2:
        return np.asarray(m @ xv.T).T if xv.ndim == 2 else m @ xv
    out: NDArray[np.float64] = np.einsum("ijk,ik->ij", m, np.broadcast_to(xv, (m.shape[0], 3)))
    return out


def inside_hull(x: NDArray[np.floating], points: NDArray[np.floating], tol: float) -> bool | None:
    """Whether ``x`` lies in the convex hull of ``points`` (n, 3), within ``tol`` (m) of a facet;
    None when the points span no volume (fewer than 4, or all on one plane).

    A plane through three of the points bounds the hull when every point lies on one side of
    it (``nᵀp + o ≤ tol``, ``n`` the unit normal turned away from them); ``x`` is inside when
    it lies on the points' side of every such plane. All triples at once: O(n⁴) for the few
    dozen points of a test, without Qhull (``scipy.spatial``, a fifth of ``dimacq solve``'s
    start-up; ``tests/pipeline/test_rotations.py`` compares with ``ConvexHull``).
    """
    pts = np.unique(np.asarray(points, dtype=np.float64), axis=0)
    xv = np.asarray(x, dtype=np.float64)
    if pts.shape[0] < 4:
        return None
    scale = float(np.ptp(pts, axis=0).max())
    sv = np.linalg.svd(pts - pts.mean(axis=0), compute_uv=False)
    if not scale > 0 or sv[2] <= 1e-9 * sv[0]:
        return None
    n = pts.shape[0]
    i, j, k = np.nonzero(
        (np.arange(n)[:, None, None] < np.arange(n)[None, :, None])
        & (np.arange(n)[None, :, None] < np.arange(n)[None, None, :])
    )  # every i < j < k
    nrm = np.cross(pts[j] - pts[i], pts[k] - pts[i])
    length = np.linalg.norm(nrm, axis=1)
    ok = length > 1e-12 * scale * scale
    nrm = nrm[ok] / length[ok, None]
    off = -np.einsum("tk,tk->t", nrm, pts[i[ok]])
    dist = nrm @ pts.T + off[:, None]  # (T, n)
    band = 1e-9 * scale
    below, above = np.all(dist <= band, axis=1), np.all(dist >= -band, axis=1)
    facet = below | above
    sign = np.where(below, 1.0, -1.0)[facet]  # outward: the points at nᵀp + o ≤ 0
    h = sign * (nrm[facet] @ xv + off[facet])
    return bool(np.all(h <= tol))
