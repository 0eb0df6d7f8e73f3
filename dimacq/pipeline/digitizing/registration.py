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

Uncertainty of the map (rigid, linearised like the jig fit, method.md §3): a small rotation
``δθ`` of the fitted map moves the image of reference node ``i`` by ``δθ × y_i`` with
``y_i = x_G,i - x̄_G``; with independent per-coordinate errors of standard deviation ``σ`` on the
nodes, ``cov(δθ) = σ² N⁻¹`` with ``N = Σ_i [y_i]×ᵀ [y_i]×`` (rad²), and the mapped image of a
point ``x`` has ``cov = σ² (I/n + [x - x̄_G]× N⁻¹ [x - x̄_G]×ᵀ)``. ``σ`` is estimated from the
residuals, ``σ̂² = Σ|r_i|² / (3n - p)`` (``p`` = 6, 7, 12 parameters for rigid, similarity,
affine); :class:`Registration` keeps ``N⁻¹`` and the centroid so that any ``σ`` (e.g. the larger
of ``σ̂`` and the stated accuracy) can be propagated (:meth:`Registration.rotation_std_deg`,
:meth:`Registration.position_std_m`).

Acceptance (:func:`registration_limit_m`, :func:`check_registration`): with per-coordinate
standard deviations ``σ_d`` of a digitized point and ``σ_r`` of a reference node's stated GCS
coordinates, a node's residual is ``r_i ~ N(0, σ_c² (1 - h_i) I₃)`` with
``σ_c² = σ_d² + σ_r²`` and leverage ``h_i < 1``, so ``|r_i|² / σ_c² ≤ χ²₃``. The limit is
``k σ_c`` with ``k = 5``: ``P(χ²₃ > 25) = 1.5·10⁻⁵`` per node, so a good registration of ten nodes
is refused about once in 7000; a node 5 mm off with ``σ_c = 0.6 mm`` is refused. Above the limit
the worst node is named; each node is also left out in turn and, when the others then fit
within the limit, that node is named as the one to re-digitize (or its coordinates to check).

Large structures are digitized in patches: each array position gets its own registration from the
reference nodes it can see; the service keeps every point with its patch.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation

from dimacq.errors import DataError, SetupError

__all__ = [
    "LIMIT_SIGMAS",
    "Registration",
    "RegistrationCheck",
    "check_registration",
    "planarity",
    "register",
    "registration_limit_m",
    "three_point_frame",
]

FloatArray = NDArray[np.float64]
METHODS = ("rigid", "similarity", "affine")
N_PARAMETERS = {"rigid": 6, "similarity": 7, "affine": 12}
#: The residual limit in standard deviations of a node's residual (see module docstring).
LIMIT_SIGMAS = 5.0


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
    sigma_m : float
        ``σ̂``, per-coordinate standard deviation of a node estimated from the residuals
        (NaN when there are no redundant coordinates, e.g. the three-point frame).
    centroid_global_m : ndarray, shape (3,)
        ``x̄_G`` of the reference nodes.
    rotation_normal_inv : ndarray, shape (3, 3)
        ``N⁻¹`` (1/m²): ``cov(δθ) = σ² N⁻¹``; NaN for the three-point frame.
    """

    matrix: FloatArray
    offset_m: FloatArray
    method: str
    scale: float
    residuals_m: FloatArray
    residual_norm_m: FloatArray
    rms_m: float
    planarity: float
    sigma_m: float = float("nan")
    centroid_global_m: FloatArray = field(default_factory=lambda: np.zeros(3))
    rotation_normal_inv: FloatArray = field(default_factory=lambda: np.full((3, 3), np.nan))

    def rotation_std_deg(self, sigma_m: float | None = None) -> FloatArray:
        """1σ of the map's small rotation about the GCS axes, degrees, shape (3,).

        ``sigma_m``: per-coordinate node error to propagate (default :attr:`sigma_m`).
        """
        s = self.sigma_m if sigma_m is None else float(sigma_m)
        var = s**2 * np.clip(np.diag(self.rotation_normal_inv), 0.0, None)
        return np.asarray(np.degrees(np.sqrt(var)), dtype=np.float64)

    def rotation_uncertainty_deg(self, sigma_m: float | None = None) -> float:
        """``sqrt(Σ rotation_std²)``: the RMS misorientation the map gives every direction."""
        return float(np.sqrt(np.sum(self.rotation_std_deg(sigma_m) ** 2)))

    def position_std_m(
        self, points_global_m: ArrayLike, sigma_m: float | None = None
    ) -> FloatArray:
        """Per-coordinate 1σ the map adds to mapped points, shape (...,):
        ``sqrt(tr(σ² (I/n + [d]× N⁻¹ [d]×ᵀ)) / 3)`` with ``d = x - x̄_G``."""
        s = self.sigma_m if sigma_m is None else float(sigma_m)
        d = np.asarray(points_global_m, dtype=float) - self.centroid_global_m
        n = len(self.residual_norm_m)
        ninv = self.rotation_normal_inv
        # tr([d]× N⁻¹ [d]×ᵀ) = |d|² tr(N⁻¹) - dᵀ N⁻¹ d
        rot = np.sum(d * d, axis=-1) * np.trace(ninv) - np.einsum("...i,ij,...j->...", d, ninv, d)
        return np.asarray(np.sqrt(s**2 * (3.0 / n + np.clip(rot, 0.0, None)) / 3.0))

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
    dof = 3 * n - N_PARAMETERS[method]
    sigma = float(np.sqrt(np.sum(res**2) / dof)) if dof > 0 else float("nan")
    # N = Σ [y]×ᵀ[y]× = Σ (|y|² I - y yᵀ) on the centred known nodes
    normal = np.sum(yg * yg) * np.eye(3) - yg.T @ yg
    return Registration(
        matrix=np.asarray(t, dtype=np.float64),
        offset_m=o,
        method=method,
        scale=float(np.sign(det) * abs(det) ** (1.0 / 3.0)),
        residuals_m=res,
        residual_norm_m=norm,
        rms_m=float(np.sqrt(np.mean(norm**2))),
        planarity=flat,
        sigma_m=sigma,
        centroid_global_m=cg,
        rotation_normal_inv=np.linalg.inv(normal),
    )


def registration_limit_m(
    point_accuracy_m: float, reference_accuracy_m: float, sigmas: float = LIMIT_SIGMAS
) -> float:
    """The largest acceptable residual of one reference node, m: ``k sqrt(σ_d² + σ_r²)``.

    Parameters
    ----------
    point_accuracy_m : float
        ``σ_d``, 1σ per coordinate of a digitized point (the array's stated accuracy).
    reference_accuracy_m : float
        ``σ_r``, 1σ per coordinate of a reference node's known GCS coordinates.
    sigmas : float
        ``k`` (default 5: a false refusal about once in 7000 registrations of ten nodes; see the
        module docstring).
    """
    if point_accuracy_m < 0 or reference_accuracy_m < 0 or sigmas <= 0:
        raise SetupError(
            "registration limit: accuracies must be >= 0 m and sigmas > 0; give the digitizer's "
            "and the reference nodes' 1-sigma accuracy per coordinate"
        )
    limit = sigmas * float(np.hypot(point_accuracy_m, reference_accuracy_m))
    if limit <= 0:
        raise SetupError(
            "registration limit: both accuracies are 0 m; give the digitizer's point accuracy"
        )
    return limit


@dataclass(frozen=True)
class RegistrationCheck:
    """A registration judged against its residual limit.

    Attributes
    ----------
    verdict : {"ok", "warn", "fail"}
        ``fail``: a node's residual is above ``limit_m``; ``warn``: above 0.7 ``limit_m`` (the
        chance of that from noise alone is below 10⁻³ per node at k = 5).
    reasons : tuple of str
        Why, naming the worst node with its residual in mm (empty when ok).
    limit_m : float
    labels : tuple of str
    worst_label : str
    worst_residual_m : float
    leave_one_out_rms_m : ndarray, shape (n,)
        RMS residual of the other nodes when each node is left out (NaN where the rest cannot be
        registered: fewer than 4, or coplanar).
    suspect : str or None
        The node whose removal brings every other node within the limit (the one to re-digitize
        or whose coordinates to check), when there is exactly one such best candidate.
    """

    verdict: Literal["ok", "warn", "fail"]
    reasons: tuple[str, ...]
    limit_m: float
    labels: tuple[str, ...]
    worst_label: str
    worst_residual_m: float
    leave_one_out_rms_m: FloatArray
    suspect: str | None


#: A residual above this fraction of the limit is a warning.
WARN_FRACTION = 0.7


def check_registration(
    points_array_m: ArrayLike,
    points_global_m: ArrayLike,
    labels: tuple[str, ...] | list[str],
    limit_m: float,
    method: str = "rigid",
) -> tuple[Registration, RegistrationCheck]:
    """Register and judge the fit against ``limit_m`` (see :func:`registration_limit_m`).

    Parameters
    ----------
    points_array_m, points_global_m : array_like, shape (n, 3)
        As :func:`register`.
    labels : sequence of str, length n
        The reference nodes' names (for the reasons).
    limit_m : float
        Largest acceptable residual of one node, m.
    method : {"rigid", "similarity", "affine"}

    Returns
    -------
    (Registration, RegistrationCheck)
        The fit (whatever its verdict) and its check; the caller refuses a ``fail``.
    """
    xa = _points("points_array_m", points_array_m)
    xg = _points("points_global_m", points_global_m)
    labs = tuple(str(x) for x in labels)
    if len(labs) != len(xa):
        raise SetupError(f"registration: {len(labs)} labels for {len(xa)} nodes; name every node")
    if not limit_m > 0:
        raise SetupError(f"registration: limit {limit_m} m; give a positive residual limit")
    reg = register(xa, xg, method=method)
    n = len(xa)
    loo = np.full(n, np.nan)
    worst_after = np.full(n, np.nan)
    if n >= 5:
        for i in range(n):
            keep = np.arange(n) != i
            try:
                sub = register(xa[keep], xg[keep], method=method)
            except SetupError:
                continue
            loo[i] = sub.rms_m
            worst_after[i] = float(sub.residual_norm_m.max())
    k = int(np.argmax(reg.residual_norm_m))
    worst = float(reg.residual_norm_m[k])
    suspect = None
    fits = np.flatnonzero(worst_after <= limit_m)
    if len(fits) == 1:
        suspect = labs[int(fits[0])]
    reasons: list[str] = []
    verdict: Literal["ok", "warn", "fail"] = "ok"
    mm = 1e3
    head = (
        f"registration residual of reference node {labs[k]!r} is {mm * worst:.2f} mm "
        f"(RMS over {n} nodes {mm * reg.rms_m:.2f} mm)"
    )
    if worst > limit_m:
        verdict = "fail"
        hint = (
            f"without {suspect!r} the other nodes fit within {mm * worst_after[labs.index(suspect)]:.2f} mm: "
            f"re-digitize {suspect!r} or check its known coordinates"
            if suspect is not None
            else "re-digitize the reference nodes (has the array moved? start a new patch after "
            "moving it) or check their known coordinates"
        )
        reasons.append(f"{head}, above the limit {mm * limit_m:.2f} mm; {hint}")
    elif worst > WARN_FRACTION * limit_m:
        verdict = "warn"
        reasons.append(
            f"{head}, near the limit {mm * limit_m:.2f} mm; check that node and its coordinates"
        )
    return reg, RegistrationCheck(
        verdict=verdict,
        reasons=tuple(reasons),
        limit_m=float(limit_m),
        labels=labs,
        worst_label=labs[k],
        worst_residual_m=worst,
        leave_one_out_rms_m=loo,
        suspect=suspect,
    )
