"""Transducer orientation from the digitized orientation jig (method.md §3, thesis Eq. 7–12).

The jig sits in the sensor's mounting base; its ``n`` indentations (24: 8 per rod at 25.4 mm
pitch) have calibrated local coordinates ``x_L,i``. Digitized and mapped to the GCS they give
``x_G,i`` with (Eq. 7)::

    x_G = C x_L + o

The columns of ``C`` are the sensor's local axes in the GCS (its direction cosines), ``o`` its
origin.

* Thesis affine (Eq. 8): least squares for the 12 entries of ``[C | o]`` from ``[x_Lᵀ 1]`` (needs
  three rods: the local points must span 3D). ``C`` is not forced orthonormal, so the thesis
  normalises rows, ``S_i = sqrt(C_i1² + C_i2² + C_i3²)`` (Eq. 10), ``C'_ij = C_ij / S_i`` (Eq. 11),
  and checks ``C'ᵀ C' ≈ I`` (Eq. 12, printed by :func:`orthogonality_table` like its Table 1).
  The nearest rotation ``U Vᵀ`` (SVD of ``C``, det fixed to +1) is the orthonormal estimate.
* Rigid (default): ``C = R`` a rotation minimising ``Σ |x_G - R x_L - o|²`` (Kabsch, through
  :meth:`scipy.spatial.transform.Rotation.align_vectors`); this is the constrained least squares
  the affine fit only approximates, and it works with two rods as well.
* Two rods (no room for the third): the thesis way, ``"cross"``, fits the two measured columns
  ``c_a, c_b`` and ``o`` from the two local coordinates, normalises them and takes the third axis
  as their cross product (right-handed order), then the nearest rotation.

Orientation uncertainty (rigid, linearised): a small rotation ``δθ`` moves ``x_G,i`` by
``δθ × y_i`` with ``y_i = R (x_L,i - x̄_L)``, so ``cov(δθ) = σ² (Σ_i [y_i]×ᵀ [y_i]×)⁻¹`` with
``σ² = Σ|r_i|² / (3n - 6)``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation

from dimacq.errors import DataError, SetupError

__all__ = [
    "AffineOrientation",
    "JigDefinition",
    "Orientation",
    "fit_affine",
    "fit_orientation",
    "nearest_rotation",
    "nominal_jig",
    "orthogonality_table",
    "rotation_error_deg",
]

FloatArray = NDArray[np.float64]
AXES = "XYZ"


@dataclass(frozen=True)
class JigDefinition:
    """Calibrated orientation jig.

    Attributes
    ----------
    points_local_m : ndarray, shape (n, 3)
        Indentation coordinates in the sensor's local frame, metres.
    rod : ndarray of int, shape (n,)
        Local axis of each indentation's rod: 0 (X), 1 (Y), 2 (Z).
    labels : tuple of str
        Names of the indentations, e.g. ``"X3"``.
    """

    points_local_m: FloatArray
    rod: NDArray[np.int64]
    labels: tuple[str, ...]

    def __post_init__(self) -> None:
        pts = np.asarray(self.points_local_m, dtype=float)
        rod = np.asarray(self.rod, dtype=np.int64)
        if (
            pts.ndim != 2
            or pts.shape[1] != 3
            or rod.shape != (len(pts),)
            or len(self.labels) != len(pts)
        ):
            raise SetupError(
                f"jig: 'points_local_m' {pts.shape}, 'rod' {rod.shape} and {len(self.labels)} labels "
                "must describe the same n points"
            )
        if not np.isin(rod, (0, 1, 2)).all():
            raise SetupError("jig: 'rod' values must be 0 (X), 1 (Y) or 2 (Z)")
        object.__setattr__(self, "points_local_m", pts)
        object.__setattr__(self, "rod", rod)

    @property
    def rods(self) -> tuple[int, ...]:
        return tuple(int(r) for r in np.unique(self.rod))

    def subset(self, rods: Sequence[int]) -> JigDefinition:
        """The indentations of the given rods only."""
        keep = np.isin(self.rod, list(rods))
        return JigDefinition(
            self.points_local_m[keep], self.rod[keep], tuple(np.asarray(self.labels)[keep].tolist())
        )


def nominal_jig(first_m: float = 0.030, pitch_m: float = 0.0254, per_rod: int = 8) -> JigDefinition:
    """The uncalibrated jig: ``per_rod`` indentations on each local axis at ``first + i pitch``."""
    pts, rod, labels = [], [], []
    for axis in range(3):
        for i in range(per_rod):
            p = np.zeros(3)
            p[axis] = first_m + i * pitch_m
            pts.append(p)
            rod.append(axis)
            labels.append(f"{AXES[axis]}{i + 1}")
    return JigDefinition(np.array(pts), np.array(rod), tuple(labels))


def nearest_rotation(c: ArrayLike) -> FloatArray:
    """Rotation closest to ``c`` in the Frobenius norm: ``U diag(1, 1, det(U Vᵀ)) Vᵀ``."""
    u, _, vt = np.linalg.svd(np.asarray(c, dtype=float))
    d = np.sign(np.linalg.det(u @ vt)) or 1.0
    return u @ np.diag([1.0, 1.0, d]) @ vt


def rotation_error_deg(estimate: ArrayLike, truth: ArrayLike) -> float:
    """Angle of the rotation ``estimate · truthᵀ``, degrees (the misorientation)."""
    r = np.asarray(estimate, dtype=float) @ np.asarray(truth, dtype=float).T
    return float(np.degrees(Rotation.from_matrix(nearest_rotation(r)).magnitude()))


@dataclass(frozen=True)
class AffineOrientation:
    """The thesis's unconstrained fit (Eq. 8) with row normalisation and check (Eq. 10–12).

    Attributes
    ----------
    matrix : ndarray, shape (3, 3)
        ``C`` as fitted.
    origin_m : ndarray, shape (3,)
    row_norms : ndarray, shape (3,)
        ``S`` (Eq. 10).
    normalised : ndarray, shape (3, 3)
        ``C'`` (Eq. 11).
    orthogonality : ndarray, shape (3, 3)
        ``C'ᵀ C'`` (Eq. 12); the identity for a perfect fit.
    max_off_diagonal : float
        Largest ``|off-diagonal|`` of the check.
    nearest_rotation : ndarray, shape (3, 3)
        SVD projection of ``C`` on the rotations.
    """

    matrix: FloatArray
    origin_m: FloatArray
    row_norms: FloatArray
    normalised: FloatArray
    orthogonality: FloatArray
    max_off_diagonal: float
    nearest_rotation: FloatArray


@dataclass(frozen=True)
class Orientation:
    """Sensor orientation and origin in the GCS with quality measures.

    Attributes
    ----------
    rotation : ndarray, shape (3, 3)
        Orthonormal ``C``; column ``j`` is local axis ``j`` in the GCS.
    origin_m : ndarray, shape (3,)
    method : str
        ``"rigid"``, ``"affine"`` (nearest rotation of the thesis fit) or ``"cross"``.
    rods : tuple of int
        Rods used.
    residuals_m : ndarray, shape (n, 3)
        ``x_G - (C x_L + o)`` per indentation.
    residual_rms_m : float
    angle_std_deg : ndarray, shape (3,)
        Standard deviation of the small rotation about the global X, Y, Z axes.
    uncertainty_deg : float
        ``sqrt(Σ angle_std²)``, the RMS misorientation expected from the residuals.
    affine : AffineOrientation or None
        The thesis fit when three rods were digitized.
    """

    rotation: FloatArray
    origin_m: FloatArray
    method: str
    rods: tuple[int, ...]
    residuals_m: FloatArray
    residual_rms_m: float
    angle_std_deg: FloatArray
    uncertainty_deg: float
    affine: AffineOrientation | None

    def axis(self, j: int) -> FloatArray:
        """Direction of local axis ``j`` in the GCS (a channel's direction, Eq. 1–3)."""
        return self.rotation[:, j].copy()


def _inputs(x_local: ArrayLike, x_global: ArrayLike) -> tuple[FloatArray, FloatArray]:
    xl = np.asarray(x_local, dtype=float)
    xg = np.asarray(x_global, dtype=float)
    if xl.ndim != 2 or xl.shape[1] != 3 or xl.shape != xg.shape:
        raise SetupError(
            f"orientation: local points {xl.shape} and digitized points {xg.shape} must both be (n, 3)"
        )
    if not np.isfinite(xg).all():
        raise DataError("orientation: digitized jig points contain NaN; digitize them again")
    return xl, xg


def fit_affine(x_local: ArrayLike, x_global: ArrayLike) -> AffineOrientation:
    """Thesis Eq. 8 and 10–12: ``[C | o]`` by least squares, rows normalised, ``C'ᵀC'``.

    Raises
    ------
    SetupError
        The local points do not span 3D (fewer than three rods): use ``fit_orientation``.
    """
    xl, xg = _inputs(x_local, x_global)
    design = np.hstack([xl, np.ones((len(xl), 1))])
    if len(xl) < 4 or np.linalg.matrix_rank(design, tol=1e-9) < 4:
        raise SetupError(
            "orientation (affine): the jig points do not span 3D (need indentations on three rods); "
            "use method 'rigid' or 'cross' for two rods"
        )
    sol, *_ = np.linalg.lstsq(design, xg, rcond=None)
    c = sol[:3].T
    s = np.linalg.norm(c, axis=1)
    cn = c / s[:, None]
    check = cn.T @ cn
    off = np.abs(check - np.diag(np.diag(check))).max()
    return AffineOrientation(
        np.asarray(c, dtype=np.float64), sol[3], s, cn, check, float(off), nearest_rotation(c)
    )


def _uncertainty(r: FloatArray, xl: FloatArray, res: FloatArray) -> tuple[FloatArray, float]:
    n = len(xl)
    dof = max(3 * n - 6, 1)
    sigma2 = float(np.sum(res**2) / dof)
    y = (xl - xl.mean(axis=0)) @ r.T
    normal = np.sum(y * y) * np.eye(3) - y.T @ y  # Σ [y_i]×ᵀ [y_i]×
    cov = sigma2 * np.linalg.inv(normal)
    std = np.degrees(np.sqrt(np.clip(np.diag(cov), 0.0, None)))
    return std, float(np.sqrt(np.sum(std**2)))


def fit_orientation(
    x_local: ArrayLike,
    x_global: ArrayLike,
    rod: ArrayLike,
    method: str = "rigid",
) -> Orientation:
    """Sensor orientation and origin from digitized jig points.

    Parameters
    ----------
    x_local : array_like, shape (n, 3)
        Calibrated local coordinates of the digitized indentations.
    x_global : array_like, shape (n, 3)
        Their digitized GCS coordinates.
    rod : array_like of int, shape (n,)
        Rod (local axis) of each indentation.
    method : {"rigid", "affine", "cross"}
        ``"affine"`` needs three rods, ``"cross"`` exactly two.

    Raises
    ------
    SetupError
        Fewer than two rods, a rod with fewer than two points, or a method that does not fit the
        rods present.
    """
    xl, xg = _inputs(x_local, x_global)
    rods_arr = np.asarray(rod, dtype=np.int64).reshape(-1)
    if rods_arr.shape != (len(xl),):
        raise SetupError(f"orientation: 'rod' has {rods_arr.size} entries for {len(xl)} points")
    rods = tuple(int(r) for r in np.unique(rods_arr))
    counts = {r: int((rods_arr == r).sum()) for r in rods}
    if len(rods) < 2 or min(counts.values()) < 2:
        missing = [AXES[a] for a in range(3) if counts.get(a, 0) < 2]
        raise SetupError(
            f"orientation: rod(s) {', '.join(missing)} missing or with fewer than 2 points; digitize "
            "at least two rods with 2+ indentations each"
        )
    affine = fit_affine(xl, xg) if len(rods) == 3 else None
    if method == "rigid":
        yl = xl - xl.mean(axis=0)
        yg = xg - xg.mean(axis=0)
        rot, _ = Rotation.align_vectors(yg, yl)
        r = rot.as_matrix()
        o = xg.mean(axis=0) - r @ xl.mean(axis=0)
    elif method == "affine":
        if affine is None:
            raise SetupError(
                "orientation: method 'affine' needs all three rods; use 'cross' or 'rigid'"
            )
        r = affine.nearest_rotation
        o = xg.mean(axis=0) - r @ xl.mean(axis=0)
    elif method == "cross":
        if len(rods) != 2:
            raise SetupError(
                "orientation: method 'cross' is for exactly two rods; use 'rigid' or 'affine'"
            )
        a, b = rods
        third = 3 - a - b
        cols = np.zeros((3, 3))
        other = np.zeros(3)
        for _ in range(2):  # second pass moves the (small) third-coordinate term to the left
            design = np.column_stack([xl[:, a], xl[:, b], np.ones(len(xl))])
            sol, *_ = np.linalg.lstsq(design, xg - np.outer(xl[:, third], other), rcond=None)
            ca = sol[0] / np.linalg.norm(sol[0])
            cb = sol[1] / np.linalg.norm(sol[1])
            cols[:, a], cols[:, b] = ca, cb
            # right-handed: e_{k+2} = e_k × e_{k+1} (indices mod 3)
            cols[:, third] = np.cross(cols[:, (third + 1) % 3], cols[:, (third + 2) % 3])
            cols[:, third] /= np.linalg.norm(cols[:, third])
            other = cols[:, third]
        r = nearest_rotation(cols)
        o = xg.mean(axis=0) - r @ xl.mean(axis=0)
    else:
        raise SetupError(f"orientation: method {method!r}; use 'rigid', 'affine' or 'cross'")
    res = xg - (xl @ r.T + o)
    std, unc = _uncertainty(r, xl, res)
    return Orientation(
        rotation=r,
        origin_m=o,
        method=method,
        rods=rods,
        residuals_m=res,
        residual_rms_m=float(np.sqrt(np.mean(np.sum(res**2, axis=1)))),
        angle_std_deg=std,
        uncertainty_deg=unc,
        affine=affine,
    )


def orthogonality_table(names: Sequence[str], checks: Sequence[ArrayLike], per_row: int = 6) -> str:
    """The thesis's Table 1: one ``C'ᵀC'`` 3 × 3 block per sensor, ``per_row`` sensors across."""
    blocks = [np.asarray(c, dtype=float) for c in checks]
    if len(blocks) != len(names):
        raise SetupError("orthogonality_table: one check matrix per name")
    width = 26
    lines: list[str] = []
    for start in range(0, len(blocks), per_row):
        chunk = range(start, min(start + per_row, len(blocks)))
        lines.append("".join(f"{names[i]:^{width}}" for i in chunk).rstrip())
        for row in range(3):
            lines.append(
                "".join(
                    " " + " ".join(f"{blocks[i][row, col]:7.4f}" for col in range(3)) + "  "
                    for i in chunk
                ).rstrip()
            )
        lines.append("")
    return "\n".join(lines).rstrip() + "\n"
