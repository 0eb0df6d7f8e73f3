"""Pinhole camera with Brown–Conrady lens distortion (OpenCV's model) and square tag corners.

A world point ``X`` seen by a camera with pose ``(R, t)`` (world → camera) is at
``X_c = R X + t``; its normalised image point ``x = X_c,x / X_c,z``, ``y = X_c,y / X_c,z``,
``r² = x² + y²``, is distorted

    x' = x (1 + k1 r² + k2 r⁴ + k3 r⁶) + 2 p1 x y + p2 (r² + 2 x²)
    y' = y (1 + k1 r² + k2 r⁴ + k3 r⁶) + p1 (r² + 2 y²) + 2 p2 x y

and lands on the pixel ``u = fx x' + cx``, ``v = fy y' + cy`` (pixel centres at integers), as
``cv2.projectPoints`` computes it with ``distCoeffs = (k1, k2, p1, p2, k3)``.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import ArrayLike, NDArray

from dimacq.errors import SetupError

__all__ = [
    "Intrinsics",
    "project",
    "tag_corners",
]

FloatArray = NDArray[np.float64]

#: The intrinsic parameters a bundle adjustment may refine, in this order.
INTRINSIC_NAMES = ("f", "cx", "cy", "k1", "k2", "p1", "p2", "k3")


@dataclass(frozen=True)
class Intrinsics:
    """A camera's intrinsics: focal lengths and principal point in pixels, distortion
    ``(k1, k2, p1, p2, k3)`` (OpenCV's order), image size in pixels."""

    fx: float
    fy: float
    cx: float
    cy: float
    k1: float = 0.0
    k2: float = 0.0
    p1: float = 0.0
    p2: float = 0.0
    k3: float = 0.0
    width: int = 0
    height: int = 0

    def __post_init__(self) -> None:
        if not (self.fx > 0 and self.fy > 0):
            raise SetupError(
                f"camera intrinsics: focal lengths fx = {self.fx}, fy = {self.fy} px must be > 0; "
                "give the focal length in pixels (focal length in mm × width px / sensor width mm)"
            )

    @property
    def matrix(self) -> FloatArray:
        """The camera matrix ``K = [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]``."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def distortion(self) -> FloatArray:
        """``(k1, k2, p1, p2, k3)``, OpenCV's ``distCoeffs``."""
        return np.array([self.k1, self.k2, self.p1, self.p2, self.k3])

    def vector(self) -> FloatArray:
        """The refinable parameters :data:`INTRINSIC_NAMES` (one focal length: ``f = fx``, with
        the aspect ratio ``fy/fx`` held)."""
        return np.array([self.fx, self.cx, self.cy, self.k1, self.k2, self.p1, self.p2, self.k3])

    def with_vector(self, v: ArrayLike) -> Intrinsics:
        """These intrinsics with the refinable parameters ``v`` (see :meth:`vector`)."""
        f, cx, cy, k1, k2, p1, p2, k3 = (float(x) for x in np.asarray(v, float))
        aspect = self.fy / self.fx
        return replace(self, fx=f, fy=f * aspect, cx=cx, cy=cy, k1=k1, k2=k2, p1=p1, p2=p2, k3=k3)

    def to_json(self) -> dict[str, float | int]:
        return {
            "fx": self.fx,
            "fy": self.fy,
            "cx": self.cx,
            "cy": self.cy,
            "k1": self.k1,
            "k2": self.k2,
            "p1": self.p1,
            "p2": self.p2,
            "k3": self.k3,
            "width": self.width,
            "height": self.height,
        }


def distort(xy: FloatArray, cam: Intrinsics) -> FloatArray:
    """Brown–Conrady distortion of normalised points ``xy`` (shape (..., 2)), see the module."""
    x, y = xy[..., 0], xy[..., 1]
    r2 = x * x + y * y
    radial = 1.0 + r2 * (cam.k1 + r2 * (cam.k2 + r2 * cam.k3))
    xd = x * radial + 2.0 * cam.p1 * x * y + cam.p2 * (r2 + 2.0 * x * x)
    yd = y * radial + cam.p1 * (r2 + 2.0 * y * y) + 2.0 * cam.p2 * x * y
    return np.stack([xd, yd], axis=-1)


def project(points_cam: ArrayLike, cam: Intrinsics) -> FloatArray:
    """Pixel coordinates of points given in the camera frame.

    Parameters
    ----------
    points_cam : array_like, shape (..., 3)
        ``X_c`` (z > 0 in front of the camera), any length unit.
    cam : Intrinsics

    Returns
    -------
    ndarray, shape (..., 2)
        ``(u, v)`` pixels, as ``cv2.projectPoints``.
    """
    p = np.asarray(points_cam, dtype=float)
    xy = p[..., :2] / p[..., 2:3]
    d = distort(xy, cam)
    return np.stack([cam.fx * d[..., 0] + cam.cx, cam.fy * d[..., 1] + cam.cy], axis=-1)


def undistort_normalised(uv: ArrayLike, cam: Intrinsics, iterations: int = 20) -> FloatArray:
    """Normalised undistorted points ``(x, y)`` of pixels ``uv`` (shape (..., 2)): the fixed
    point ``x = (x'_obs − tangential(x)) / radial(x)``, as ``cv2.undistortPoints``."""
    p = np.asarray(uv, dtype=float)
    xd = np.stack([(p[..., 0] - cam.cx) / cam.fx, (p[..., 1] - cam.cy) / cam.fy], axis=-1)
    xy = xd.copy()
    for _ in range(iterations):
        x, y = xy[..., 0], xy[..., 1]
        r2 = x * x + y * y
        radial = 1.0 + r2 * (cam.k1 + r2 * (cam.k2 + r2 * cam.k3))
        dx = 2.0 * cam.p1 * x * y + cam.p2 * (r2 + 2.0 * x * x)
        dy = cam.p1 * (r2 + 2.0 * y * y) + 2.0 * cam.p2 * x * y
        xy = np.stack([(xd[..., 0] - dx) / radial, (xd[..., 1] - dy) / radial], axis=-1)
    return xy


def tag_corners(side_m: float) -> FloatArray:
    """The four outer corners of a square tag of side ``side_m`` in its own frame, shape (4, 3).

    The tag lies in its z = 0 plane, z out of the printed face, x to the right and y up as the
    tag is printed; the order is OpenCV's ArUco order (top-left, top-right, bottom-right,
    bottom-left): ``(−s/2, s/2, 0), (s/2, s/2, 0), (s/2, −s/2, 0), (−s/2, −s/2, 0)``.
    """
    h = 0.5 * float(side_m)
    return np.array([[-h, h, 0.0], [h, h, 0.0], [h, -h, 0.0], [-h, -h, 0.0]])
