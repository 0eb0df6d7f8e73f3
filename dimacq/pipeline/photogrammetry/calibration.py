"""What a board calibration's data can support: how the corners cover the image, how the board
was tilted, and the refusals the figures call for; and the distance between two cameras'
images of the same rays.

A plane seen square-on by a pinhole camera fixes only ``f / Z`` (its image is a scaled copy of
it), so the focal length comes from the board's tilt: the projection of a plane tilted by ``θ``
carries ``f`` through the perspective foreshortening, of order ``tan θ × extent / Z``. Lens
distortion grows as ``r²…r⁶`` from the principal point, so only corners out towards the image's
corners fix ``k1, k2, k3``: how well they are fixed there is the 1σ of where the camera images
the rays through the image's corners (:func:`edge_std_px`). The refusals follow: too few photos, a focal length whose standard
deviation (from the calibration's covariance) is too large or too few photos tilted — too
little tilt —, corners that do not reach the image's corners, or a reprojection RMS too large
for a flat, sharp board.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import ArrayLike, NDArray

from dimacq.pipeline.photogrammetry.camera import Intrinsics, project, undistort_normalised

__all__ = [
    "LIMIT_EDGE_STD_PX",
    "LIMIT_F_REL_STD",
    "LIMIT_RMS_PX",
    "MIN_COVERAGE",
    "MIN_PHOTOS",
    "MIN_TILTED",
    "MIN_TILT_DEG",
    "Coverage",
    "board_tilt_deg",
    "coverage",
    "edge_std_px",
    "image_difference_px",
    "intrinsic_covariance",
    "refusals",
]

FloatArray = NDArray[np.float64]

#: Fewest usable photos a calibration is computed from.
MIN_PHOTOS = 6
#: Largest relative standard deviation of the focal lengths (σ_f / f).
LIMIT_F_REL_STD = 0.002
#: Fewest photos with the board tilted :data:`MIN_TILT_DEG` or more from square-on: however
#: small its σ, a focal length from a board seen square-on trades against the board's distance
#: and the distortion.
MIN_TILTED = 3
MIN_TILT_DEG = 15.0
#: Largest RMS reprojection error of the corners, px.
LIMIT_RMS_PX = 1.0
#: Smallest share of the image's cells (a 4 × 4 grid) holding a corner of some photo.
MIN_COVERAGE = 0.75
#: Largest 1σ, px, of where the calibrated camera images the rays through the image's corners
#: and edges (:func:`edge_std_px`).
LIMIT_EDGE_STD_PX = 1.0
#: Good tilts of the board from square-on, degrees.
GOOD_TILT_DEG = (20.0, 45.0)
_GRID = 4
_ROWS = ("top", "upper middle", "lower middle", "bottom")
_COLS = ("left", "left of centre", "right of centre", "right")


@dataclass(frozen=True)
class Coverage:
    """How the corners of all photos cover the image: ``cells`` the share of a 4 × 4 grid's
    cells holding a corner, ``empty`` those cells named (``"top left"``), ``reach`` the farthest
    corner's distance from the image centre over the half-diagonal."""

    cells: float
    empty: tuple[str, ...]
    reach: float


def coverage(points_px: Sequence[ArrayLike], width: int, height: int) -> Coverage:
    """The corners' cover of a ``width × height`` image.

    Parameters
    ----------
    points_px : sequence of array_like, each shape (n_i, 2)
        The corners found in each photo, pixels.
    width, height : int
        Image size, pixels.

    Returns
    -------
    Coverage
        ``reach = max ‖(u, v) − (w/2, h/2)‖ / (½ √(w² + h²))``.
    """
    pts = np.vstack([np.asarray(p, float).reshape(-1, 2) for p in points_px] or [np.zeros((0, 2))])
    hit = np.zeros((_GRID, _GRID), bool)
    if len(pts):
        col = np.clip((pts[:, 0] / width * _GRID).astype(int), 0, _GRID - 1)
        row = np.clip((pts[:, 1] / height * _GRID).astype(int), 0, _GRID - 1)
        hit[row, col] = True
    empty = tuple(
        f"{_ROWS[r]} {_COLS[c]}" for r in range(_GRID) for c in range(_GRID) if not hit[r, c]
    )
    half_diag = 0.5 * math.hypot(width, height)
    centre = np.array([0.5 * width, 0.5 * height])
    reach = float(np.max(np.linalg.norm(pts - centre, axis=1)) / half_diag) if len(pts) else 0.0
    return Coverage(float(hit.mean()), empty, reach)


def board_tilt_deg(rvec: ArrayLike) -> float:
    """The board's tilt from square-on, degrees: ``θ = arccos |R₃₃|``, the angle between the
    board's normal (``R e_z``, ``R`` the board → camera rotation of the rotation vector
    ``rvec``) and the optical axis."""
    from scipy.spatial.transform import Rotation

    r = Rotation.from_rotvec(np.asarray(rvec, float).ravel()).as_matrix()
    return float(np.degrees(np.arccos(min(1.0, abs(r[2, 2])))))


def image_difference_px(a: Intrinsics, b: Intrinsics, step_px: float = 20.0) -> float:
    """The largest distance, px, between where cameras ``a`` and ``b`` image the same ray, over
    ``a``'s image (a grid of ``step_px``): each pixel ``p`` of ``a`` is undistorted to its ray
    ``x = a⁻¹(p)`` and projected through ``b``, ``max ‖b(x) − p‖``."""
    u = np.arange(0.0, a.width, step_px)
    v = np.arange(0.0, a.height, step_px)
    uu, vv = np.meshgrid(np.append(u, a.width - 1.0), np.append(v, a.height - 1.0))
    p = np.stack([uu.ravel(), vv.ravel()], axis=1)
    xy = undistort_normalised(p, a, iterations=50)
    q = project(np.column_stack([xy, np.ones(len(xy))]), b)
    return float(np.max(np.linalg.norm(q - p, axis=1)))


def intrinsic_covariance(
    a_blocks: Sequence[ArrayLike], b_blocks: Sequence[ArrayLike], residuals_px: ArrayLike
) -> FloatArray:
    """The intrinsics' covariance of a board calibration, the photos' poses eliminated.

    With each photo's residual Jacobian ``[A_i B_i]`` (``A_i`` by the ``p`` intrinsics, ``B_i``
    by its pose's six parameters), the normal matrix's Schur complement on the intrinsics is
    ``S = Σ_i (A_iᵀA_i − A_iᵀB_i (B_iᵀB_i)⁻¹ B_iᵀA_i)`` and

        Σ = s² S⁻¹,   s² = Σ r² / (m − p − 6 n)

    (``m`` residuals, ``n`` photos): the a-posteriori variance of a corner coordinate times the
    inverse normal matrix, as least squares gives it.

    Parameters
    ----------
    a_blocks : sequence of array_like, each shape (m_i, p)
    b_blocks : sequence of array_like, each shape (m_i, 6)
    residuals_px : array_like, shape (m,)
        Every photo's residuals, concatenated.

    Returns
    -------
    ndarray, shape (p, p)
    """
    p = np.asarray(a_blocks[0]).shape[1]
    s_mat = np.zeros((p, p))
    for a_, b_ in zip(a_blocks, b_blocks, strict=True):
        a = np.asarray(a_, float)
        b = np.asarray(b_, float)
        bta = b.T @ a
        s_mat += a.T @ a - bta.T @ np.linalg.solve(b.T @ b, bta)
    r = np.asarray(residuals_px, float).ravel()
    dof = max(len(r) - p - 6 * len(a_blocks), 1)
    s2 = float(r @ r) / dof
    return s2 * np.linalg.pinv(s_mat, rcond=1e-15, hermitian=True)


def _with(cam: Intrinsics, theta: FloatArray) -> Intrinsics:
    """``cam`` with ``(fx, fy, cx, cy, k1, k2, p1, p2, k3) = theta``."""
    fx, fy, cx, cy, k1, k2, p1, p2, k3 = (float(v) for v in theta)
    return replace(cam, fx=fx, fy=fy, cx=cx, cy=cy, k1=k1, k2=k2, p1=p1, p2=p2, k3=k3)


def edge_std_px(cam: Intrinsics, cov: ArrayLike) -> float:
    """The largest 1σ, px, of where ``cam`` images the rays through the image's four corners and
    four edge midpoints.

    Each such pixel ``p`` is undistorted to its ray ``x = cam⁻¹(p)``; ``G = ∂π(x; θ)/∂θ``
    (central differences) over ``θ = (fx, fy, cx, cy, k1, k2, p1, p2, k3)`` propagates the
    intrinsics' covariance ``Σ`` (shape (9, 9)) to ``σ_p = √trace(G Σ Gᵀ)`` (both image
    directions together); the largest over the eight points is returned.
    """
    w, h = cam.width - 1.0, cam.height - 1.0
    pts = np.array(
        [[0, 0], [w, 0], [0, h], [w, h], [w / 2, 0], [0, h / 2], [w / 2, h], [w, h / 2]], float
    )
    x = undistort_normalised(pts, cam, iterations=50)
    rays = np.column_stack([x, np.ones(len(x))])
    theta = np.array([cam.fx, cam.fy, cam.cx, cam.cy, *cam.distortion])
    g = np.empty((len(pts), 2, len(theta)))
    for i in range(len(theta)):
        step = 1e-6 * max(1.0, abs(theta[i]))
        hi, lo = theta.copy(), theta.copy()
        hi[i] += step
        lo[i] -= step
        up = project(rays, _with(cam, hi))
        down = project(rays, _with(cam, lo))
        g[:, :, i] = (up - down) / (2 * step)
    c = np.asarray(cov, float)
    var = np.einsum("kai,ij,kaj->k", g, c, g)
    return float(np.sqrt(np.max(np.clip(var, 0.0, None))))


def more_photos(n: int, ratio: float) -> int:
    """Photos to add to ``n`` for a standard deviation ``ratio`` times its limit to reach it
    (``σ ∝ 1/√n``): ``⌈n ratio²⌉ − n``, at least :data:`MIN_PHOTOS`."""
    return max(MIN_PHOTOS, math.ceil(n * ratio * ratio) - n)


def refusals(
    n_photos: int,
    f_rel_std: float | None,
    rms_px: float | None,
    cover: Coverage,
    tilts_deg: Sequence[float],
    edge_px: float | None = None,
) -> list[str]:
    """Why the calibration cannot be trusted, each with the fix; empty when it can.

    Parameters
    ----------
    n_photos : int
        Usable photos.
    f_rel_std : float or None
        ``max(σ_fx / fx, σ_fy / fy)`` (None: not calibrated; then neither it nor the tilts are
        judged).
    rms_px : float or None
        RMS reprojection error of the corners, px.
    cover : Coverage
    tilts_deg : sequence of float
        Each photo's board tilt from square-on, degrees.
    edge_px : float, optional
        :func:`edge_std_px` of the calibration.
    """
    out = []
    if n_photos == 0:
        out.append(
            "no usable photo of the board: each photo is named with what was wrong and the "
            "fix (a wrong board file shows in every photo)"
        )
    elif n_photos < MIN_PHOTOS:
        out.append(
            f"{n_photos} usable photos, fewer than {MIN_PHOTOS}: take "
            f"{max(MIN_PHOTOS - n_photos, 15 - n_photos)} more photos of the whole board, "
            f"tilted {GOOD_TILT_DEG[0]:.0f}–{GOOD_TILT_DEG[1]:.0f}° towards different sides"
        )
    tilted = sum(1 for t in tilts_deg if t >= MIN_TILT_DEG)
    if f_rel_std is not None and (f_rel_std > LIMIT_F_REL_STD or tilted < MIN_TILTED):
        # photos square-on do not fix f however many: more only help once most are tilted
        more = (
            more_photos(n_photos, f_rel_std / LIMIT_F_REL_STD)
            if 2 * tilted >= n_photos
            else max(MIN_PHOTOS, 10 - tilted)
        )
        out.append(
            f"focal length ±{100 * f_rel_std:.2f} % (1σ; limit {100 * LIMIT_F_REL_STD:.1f} %) "
            f"with the board tilted {MIN_TILT_DEG:.0f}° or more in {tilted} of {n_photos} "
            f"photos (at most {max(tilts_deg, default=0.0):.0f}°; at least {MIN_TILTED} "
            f"needed): take {more} more photos tilting the board "
            f"{GOOD_TILT_DEG[0]:.0f}–{GOOD_TILT_DEG[1]:.0f}° to the left, right, up and down"
        )
    loose = edge_px is not None and edge_px > LIMIT_EDGE_STD_PX
    if n_photos and (cover.cells < MIN_COVERAGE or loose):
        where = ", ".join(cover.empty[:6]) + (" …" if len(cover.empty) > 6 else "")
        edge = (
            ""
            if edge_px is None
            else (
                f"; the calibrated camera places the image's corners to ±{edge_px:.2f} px (1σ; "
                f"limit {LIMIT_EDGE_STD_PX:.1f} px)"
            )
        )
        out.append(
            f"the corners cover {100 * cover.cells:.0f} % of the image (limit "
            f"{100 * MIN_COVERAGE:.0f} %) and reach {100 * cover.reach:.0f} % of the way to its "
            f"corners{edge}, so the lens distortion is not fixed"
            + (f"; nothing in: {where}" if where else "")
            + "; take photos with the board near each corner and edge of the frame"
        )
    if rms_px is not None and rms_px > LIMIT_RMS_PX:
        out.append(
            f"reprojection RMS {rms_px:.2f} px (limit {LIMIT_RMS_PX:.1f} px): check the board "
            "file (squares, marker and square sides as printed), that the board is flat and "
            "the photos sharp; retake the blurred ones"
        )
    return out
