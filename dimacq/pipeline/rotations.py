"""Rotation matrices of rotation vectors, through ``scipy.spatial.transform.Rotation``.

A rotation vector ``v`` (rad) turns by ``θ = |v|`` about ``v/θ``; its matrix is Rodrigues'
``R = I + sin θ [u]× + (1 − cos θ) [u]×²`` (``[u]×`` the skew matrix,
:func:`dimacq.pipeline.rigid_body.skew`), which
``Rotation.from_rotvec(v).as_matrix()`` computes through the unit quaternion
``q = (sin(θ/2) u, cos(θ/2))``. scipy is imported when a rotation is first made, not with this
module (``dimacq --help`` does not need it).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

__all__ = ["apply_rotvec", "rotvec_to_matrix"]


def rotvec_to_matrix(v: NDArray[np.floating]) -> NDArray[np.float64]:
    """Rotation matrices of rotation vectors ``v`` (rad), shape (..., 3) → (..., 3, 3)."""
    from scipy.spatial.transform import Rotation

    v = np.asarray(v, dtype=np.float64)
    m = Rotation.from_rotvec(v.reshape(-1, 3)).as_matrix()
    return np.asarray(m, dtype=np.float64).reshape(v.shape[:-1] + (3, 3))


def apply_rotvec(v: NDArray[np.floating], x: NDArray[np.floating]) -> NDArray[np.float64]:
    """Vectors ``x`` (n, 3) or (3,) turned by the rotation vectors ``v`` (n, 3) or (3,):
    ``Rotation.from_rotvec(v).apply(x)``."""
    from scipy.spatial.transform import Rotation

    return np.asarray(Rotation.from_rotvec(np.asarray(v, float)).apply(x), dtype=np.float64)
