"""Bundle adjustment of camera poses and tagged rigid bodies (and the camera's intrinsics).

Every fiducial tag is mounted on a rigid body (a triax block, an impact jig, a reference plate
of the article, a scale bar) at a known pose in the body's frame. The unknowns are each photo's
pose ``(R_c, t_c)`` (world → camera), each body's pose ``(R_b, p_b)`` (body → world) and,
optionally, the intrinsics (:data:`~dimacq.pipeline.photogrammetry.camera.INTRINSIC_NAMES`).
A corner ``c`` of tag ``k`` of body ``b`` in photo ``i`` is predicted at

    u = π(K, dist; R_c,i (R_b (R_bk c + o_bk) + p_b) + t_c,i)

(:func:`~dimacq.pipeline.photogrammetry.camera.project`), and the adjustment minimises

    Σ |u − u_obs|² / σ_px² + Σ_ref (|p_b − p̄_b|² / σ_p² + |log(R_b R̄_bᵀ)|² / σ_θ²)

over all corners and the reference bodies' stated poses ``(R̄_b, p̄_b)`` — the gauge (frame and
scale) comes from those priors; a scale bar is one more body whose two tags are a known distance
apart. Rotations are updated on the left, ``R = exp([δ]×) R₀`` with ``δ`` in the world frame
(camera frame for photos), so ``δ`` is the small rotation whose covariance is reported.

One more unknown is the detector's edge bias ``b`` (px): every observed corner is taken as
``u_obs − b n̂``, ``n̂`` the unit vector from its tag's observed centre out to the corner (a
corner found inside or outside the printed one by the same amount on every tag, which would
otherwise read as tags smaller or larger than printed, i.e. farther or nearer).

The covariance of the parameters is ``Σ = (JᵀJ)⁻¹`` of the whitened problem at the solution,
with ``σ_px² = Σ (r/s)² / (n − p)`` estimated from the corner residuals (the reprojection error
the photos actually show, not a nominal one; ``s`` each view's ``sigma_scale``). The tags'
placement on their bodies, an error all corners of a tag share, is added to each body's as a
considered covariance (:func:`placement_covariance`).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace

import numpy as np
import scipy.sparse as sp
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from dimacq.errors import SolverError
from dimacq.pipeline.photogrammetry.camera import Intrinsics, project, tag_corners

__all__ = [
    "BodyEstimate",
    "BodyModel",
    "BundleResult",
    "Observation",
    "Problem",
    "TagMount",
    "adjust",
    "placement_covariance",
]

FloatArray = NDArray[np.float64]
N_INTR = 8


@dataclass(frozen=True)
class TagMount:
    """A tag on a body: its id, side (m) and pose in the body frame (tag → body)."""

    tag_id: int
    side_m: float
    rotation: FloatArray
    offset_m: FloatArray

    def corners_body(self) -> FloatArray:
        """The tag's four corners in the body frame, shape (4, 3)."""
        return tag_corners(self.side_m) @ np.asarray(self.rotation).T + np.asarray(self.offset_m)


@dataclass(frozen=True)
class BodyModel:
    """A rigid body carrying tags.

    ``kind`` is ``"triax"`` (the body frame is the sensor's: origin at its measuring point,
    axes along its X, Y, Z), ``"input"`` (origin at the impact point, the line of action along
    ``−z``), ``"reference"`` (a plate whose pose in the article's frame is stated:
    ``prior_rotation``, ``prior_position_m`` with their 1σ) or ``"scalebar"``.
    """

    name: str
    kind: str
    tags: tuple[TagMount, ...]
    node: int | None = None
    prior_rotation: FloatArray | None = None
    prior_position_m: FloatArray | None = None
    prior_position_std_m: float = 0.0
    prior_angle_std_deg: float = 0.0


@dataclass(frozen=True)
class Observation:
    """Tag ``tag_id`` seen in photo ``photo``: its four corners in pixels, OpenCV's order.

    ``sigma_scale`` is this view's corner 1σ relative to the set's ``σ_px`` (a tag seen at
    incidence ``θ`` has its border foreshortened by ``cos θ``, and its edges located that much
    less well: ``1/cos θ``)."""

    photo: int
    tag_id: int
    corners_px: FloatArray
    sigma_scale: float = 1.0


@dataclass(frozen=True)
class BodyEstimate:
    """A body's adjusted pose with its covariance.

    Attributes
    ----------
    rotation : ndarray, shape (3, 3)
        Body → world.
    position_m : ndarray, shape (3,)
    covariance : ndarray, shape (6, 6)
        Of ``(δ [rad], p [m])``, ``δ`` the small world-frame rotation of the body.
    n_photos : int
        Photos in which at least one of its tags was used.
    n_corners : int
    placement_covariance : ndarray, shape (6, 6), optional
        What the tags' placement on their bodies adds to ``covariance``
        (:func:`placement_covariance`); None when the adjustment was not given it.
    """

    name: str
    kind: str
    node: int | None
    rotation: FloatArray
    position_m: FloatArray
    covariance: FloatArray
    n_photos: int
    n_corners: int
    placement_covariance: FloatArray | None = None

    @property
    def position_std_m(self) -> FloatArray:
        """1σ of each world coordinate of the origin, m."""
        return np.sqrt(np.clip(np.diag(self.covariance)[3:], 0, None))

    @property
    def angle_std_deg(self) -> FloatArray:
        """1σ of the small rotation about each world axis, degrees."""
        return np.degrees(np.sqrt(np.clip(np.diag(self.covariance)[:3], 0, None)))


@dataclass(frozen=True)
class BundleResult:
    """The adjustment: bodies, photos, intrinsics and the fit's quality.

    ``sigma_px`` is the corner residuals' RMS estimate ``sqrt(Σr²/(n − p))``; ``rejected``
    lists ``(photo, tag_id, rms_px)`` of observations removed as gross errors
    (``rms > reject_sigma · σ_px``); ``photo_rms_px`` the RMS corner residual of each photo
    (NaN for photos not used).
    """

    bodies: tuple[BodyEstimate, ...]
    camera_rotations: FloatArray
    camera_translations: FloatArray
    intrinsics: Intrinsics
    intrinsics_std: FloatArray | None
    sigma_px: float
    n_corners: int
    n_parameters: int
    rms_px: float
    photo_rms_px: FloatArray
    rejected: tuple[tuple[int, int, float], ...]
    nfev: int
    condition: float
    messages: tuple[str, ...] = field(default_factory=tuple)
    edge_bias_px: float = 0.0
    edge_bias_std_px: float = 0.0

    def body(self, name: str) -> BodyEstimate:
        for b in self.bodies:
            if b.name == name:
                return b
        raise KeyError(name)


def _skew(v: FloatArray) -> FloatArray:
    """``[v]×`` for a stack of vectors, shape (..., 3) → (..., 3, 3)."""
    k = np.zeros((*v.shape[:-1], 3, 3))
    k[..., 0, 1], k[..., 0, 2], k[..., 1, 2] = -v[..., 2], v[..., 1], -v[..., 0]
    k[..., 1, 0], k[..., 2, 0], k[..., 2, 1] = v[..., 2], -v[..., 1], v[..., 0]
    return k


def _rot(delta: FloatArray, base: FloatArray) -> FloatArray:
    """``exp([δ]×) R₀`` for stacks ``δ`` (n, 3), ``R₀`` (n, 3, 3), with Rodrigues' formula
    ``exp([δ]×) = I + sin θ/θ [δ]× + (1 − cos θ)/θ² [δ]×²``, ``θ = |δ|``."""
    th2 = np.sum(delta * delta, axis=1)
    th = np.sqrt(th2)
    small = th < 1e-4
    a = np.where(small, 1.0 - th2 / 6.0, np.sin(th) / np.where(small, 1.0, th))
    b = np.where(small, 0.5 - th2 / 24.0, (1.0 - np.cos(th)) / np.where(small, 1.0, th2))
    k = _skew(delta)
    e = np.eye(3) + a[:, None, None] * k + b[:, None, None] * (k @ k)
    return np.asarray(e @ base)


def _left_jacobian(delta: FloatArray) -> FloatArray:
    """SO(3)'s left Jacobian ``J_l(δ) = I + (1 − cos θ)/θ² [δ]× + (θ − sin θ)/θ³ [δ]×²``
    for a stack ``δ`` (n, 3): ``exp([δ + ε]×) ≈ exp([J_l(δ) ε]×) exp([δ]×)``, so
    ``∂(exp([δ]×) v)/∂δ = −[exp([δ]×) v]× J_l(δ)``."""
    th2 = np.sum(delta * delta, axis=1)
    th = np.sqrt(th2)
    small = th < 1e-4
    safe = np.where(small, 1.0, th)
    a = np.where(small, 0.5 - th2 / 24.0, (1.0 - np.cos(th)) / safe**2)
    b = np.where(small, 1.0 / 6.0 - th2 / 120.0, (th - np.sin(th)) / safe**3)
    k = _skew(delta)
    return np.asarray(np.eye(3) + a[:, None, None] * k + b[:, None, None] * (k @ k))


def _left_jacobian_inv(phi: FloatArray) -> FloatArray:
    """``J_l(φ)⁻¹ = I − [φ]×/2 + (1/θ² − (1 + cos θ)/(2 θ sin θ)) [φ]×²`` for a stack
    ``φ`` (n, 3): ``log(exp([η]×) exp([φ]×)) ≈ φ + J_l(φ)⁻¹ η``."""
    th2 = np.sum(phi * phi, axis=1)
    th = np.sqrt(th2)
    small = th < 1e-4
    safe = np.where(small, 1.0, th)
    c = np.where(
        small,
        1.0 / 12.0 + th2 / 720.0,
        1.0 / safe**2 - (1 + np.cos(th)) / (2 * safe * np.sin(safe)),
    )
    k = _skew(phi)
    return np.asarray(np.eye(3) - 0.5 * k + c[:, None, None] * (k @ k))


def _projection_derivatives(xc: FloatArray, intr: Intrinsics) -> tuple[FloatArray, FloatArray]:
    """Derivatives of :func:`~dimacq.pipeline.photogrammetry.camera.project` at camera-frame
    points ``xc`` (shape (..., 3)): ``∂u/∂X_c`` (..., 2, 3) and ``∂u/∂(f, cx, cy, k1, k2, p1,
    p2, k3)`` (..., 2, 8).

    With ``x = X/Z``, ``y = Y/Z``, ``ρ = 1 + k1 r² + k2 r⁴ + k3 r⁶``, ``g = ∂ρ/∂(r²)``:
    ``∂x'/∂x = ρ + 2x²g + 2p1 y + 6p2 x``, ``∂x'/∂y = 2xy g + 2p1 x + 2p2 y``,
    ``∂y'/∂x = 2xy g + 2p1 x + 2p2 y``, ``∂y'/∂y = ρ + 2y²g + 6p1 y + 2p2 x``, and
    ``∂(x, y)/∂X_c = [[1/Z, 0, −x/Z], [0, 1/Z, −y/Z]]``; ``u = fx x' + cx``, ``v = fy y' + cy``
    with ``fy = f · (fy/fx)``.
    """
    z = xc[..., 2]
    x, y = xc[..., 0] / z, xc[..., 1] / z
    r2 = x * x + y * y
    k1, k2, k3, p1, p2 = intr.k1, intr.k2, intr.k3, intr.p1, intr.p2
    rho = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    g = k1 + 2.0 * k2 * r2 + 3.0 * k3 * r2 * r2
    cross = 2.0 * x * y * g + 2.0 * p1 * x + 2.0 * p2 * y
    dd = np.empty((*x.shape, 2, 2))
    dd[..., 0, 0] = rho + 2.0 * x * x * g + 2.0 * p1 * y + 6.0 * p2 * x
    dd[..., 0, 1] = cross
    dd[..., 1, 0] = cross
    dd[..., 1, 1] = rho + 2.0 * y * y * g + 6.0 * p1 * y + 2.0 * p2 * x
    dp = np.zeros((*x.shape, 2, 3))
    dp[..., 0, 0] = dp[..., 1, 1] = 1.0 / z
    dp[..., 0, 2] = -x / z
    dp[..., 1, 2] = -y / z
    f = np.array([intr.fx, intr.fy])
    d_xc = f[:, None] * (dd @ dp)
    xd = x * rho + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
    yd = y * rho + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
    aspect = intr.fy / intr.fx
    d_in = np.zeros((*x.shape, 2, N_INTR))
    d_in[..., 0, 0], d_in[..., 1, 0] = xd, aspect * yd
    d_in[..., 0, 1] = 1.0
    d_in[..., 1, 2] = 1.0
    for j, rad in ((3, r2), (4, r2 * r2), (7, r2**3)):
        d_in[..., 0, j], d_in[..., 1, j] = intr.fx * x * rad, intr.fy * y * rad
    d_in[..., 0, 5], d_in[..., 1, 5] = intr.fx * 2.0 * x * y, intr.fy * (r2 + 2.0 * y * y)
    d_in[..., 0, 6], d_in[..., 1, 6] = intr.fx * (r2 + 2.0 * x * x), intr.fy * 2.0 * x * y
    return d_xc, d_in


class Problem:
    """The bundle adjustment: unknowns ``x`` (the intrinsics if refined, each camera's and body's
    rotation increment and position, one outward shift of the detected corners in pixels), the
    corner residuals and their sparse Jacobian."""

    def __init__(
        self,
        bodies: Sequence[BodyModel],
        obs: Sequence[Observation],
        intr: Intrinsics,
        cam_r: FloatArray,
        cam_t: FloatArray,
        body_r: FloatArray,
        body_p: FloatArray,
        refine_intrinsics: bool,
    ) -> None:
        self.bodies = list(bodies)
        self.intr = intr
        self.refine = refine_intrinsics
        self.n_cam = len(cam_r)
        self.n_body = len(bodies)
        self.cam_r0 = np.array(cam_r, float)
        self.body_r0 = np.array(body_r, float)
        self.x0 = np.concatenate(
            [
                intr.vector() if refine_intrinsics else np.zeros(0),
                np.column_stack([np.zeros((self.n_cam, 3)), cam_t]).ravel(),
                np.column_stack([np.zeros((self.n_body, 3)), body_p]).ravel(),
                [0.0],
            ]
        )
        mount = {t.tag_id: (i, t) for i, b in enumerate(bodies) for t in b.tags}
        self.set_observations(obs, mount)
        self.prior_idx = np.array(
            [i for i, b in enumerate(bodies) if b.prior_position_m is not None], dtype=int
        )
        ref = [self.bodies[i] for i in self.prior_idx]
        self.prior_p = np.array([np.asarray(b.prior_position_m, float) for b in ref]).reshape(-1, 3)
        self.prior_r = np.array([np.asarray(b.prior_rotation, float) for b in ref]).reshape(
            -1, 3, 3
        )
        self.prior_sp = np.array([max(b.prior_position_std_m, 1e-9) for b in ref])
        self.prior_sa = np.radians([max(b.prior_angle_std_deg, 1e-6) for b in ref])
        self.sigma_px = 1.0

    def set_observations(
        self, obs: Sequence[Observation], mount: dict[int, tuple[int, TagMount]]
    ) -> None:
        self.obs = list(obs)
        self.mount = mount
        self.o_cam = np.array([o.photo for o in obs], dtype=int)
        self.o_body = np.array([mount[o.tag_id][0] for o in obs], dtype=int)
        self.o_pts = np.array([mount[o.tag_id][1].corners_body() for o in obs]).reshape(-1, 4, 3)
        self.o_uv = np.array([o.corners_px for o in obs], dtype=float).reshape(-1, 4, 2)
        self.o_s = np.array([o.sigma_scale for o in obs], dtype=float).reshape(-1, 1, 1)
        out = self.o_uv - self.o_uv.mean(axis=1, keepdims=True)
        self.o_n = out / np.maximum(np.linalg.norm(out, axis=2, keepdims=True), 1e-12)

    def scaled_residuals(self, x: FloatArray) -> FloatArray:
        """Corner residuals over each view's ``sigma_scale``, pixels, shape (n_obs, 4, 2)."""
        return self.image_residuals(x) / self.o_s

    @property
    def n_intr(self) -> int:
        return N_INTR if self.refine else 0

    def unpack(
        self, x: FloatArray
    ) -> tuple[Intrinsics, FloatArray, FloatArray, FloatArray, FloatArray]:
        k = self.n_intr
        intr = self.intr.with_vector(x[:k]) if self.refine else self.intr
        c = x[k : k + 6 * self.n_cam].reshape(-1, 6)
        b = x[k + 6 * self.n_cam : k + 6 * (self.n_cam + self.n_body)].reshape(-1, 6)
        return intr, _rot(c[:, :3], self.cam_r0), c[:, 3:], _rot(b[:, :3], self.body_r0), b[:, 3:]

    def image_residuals(self, x: FloatArray) -> FloatArray:
        """Corner residuals in pixels, shape (n_obs, 4, 2)."""
        intr, rc, tc, rb, pb = self.unpack(x)
        xw = np.einsum("nij,nkj->nki", rb[self.o_body], self.o_pts) + pb[self.o_body][:, None]
        xc = np.einsum("nij,nkj->nki", rc[self.o_cam], xw) + tc[self.o_cam][:, None]
        return project(xc, intr) - (self.o_uv - x[-1] * self.o_n)

    def residuals(self, x: FloatArray) -> FloatArray:
        r_img = self.scaled_residuals(x).ravel() / self.sigma_px
        if not len(self.prior_idx):
            return r_img
        _, _, _, rb, pb = self.unpack(x)
        i = self.prior_idx
        dp = (pb[i] - self.prior_p) / self.prior_sp[:, None]
        dr = Rotation.from_matrix(rb[i] @ self.prior_r.transpose(0, 2, 1)).as_rotvec()
        pri = np.concatenate([dp, dr / self.prior_sa[:, None]], axis=1)
        return np.concatenate([r_img, pri.ravel()])

    def jacobian(self, x: FloatArray) -> sp.csr_matrix:
        """The analytic Jacobian of :meth:`residuals` at ``x``, sparse (n_residuals,
        n_parameters): a corner depends on the intrinsics, its photo's pose and its body's pose,

            ∂u/∂δ_c = U (−[R_c X_w]×) J_l(δ_c),  ∂u/∂t_c = U,
            ∂u/∂δ_b = U R_c (−[R_b P]×) J_l(δ_b),  ∂u/∂p_b = U R_c,

        ``U = ∂u/∂X_c`` (:func:`_projection_derivatives`); a reference prior's rotation
        residual ``φ = log(R_b R̄_bᵀ)`` has ``∂φ/∂δ_b = J_l(φ)⁻¹ J_l(δ_b)``."""
        intr, rc, tc, rb, pb = self.unpack(x)
        k = self.n_intr
        c = x[k : k + 6 * self.n_cam].reshape(-1, 6)
        b = x[k + 6 * self.n_cam : k + 6 * (self.n_cam + self.n_body)].reshape(-1, 6)
        jl_c, jl_b = _left_jacobian(c[:, :3]), _left_jacobian(b[:, :3])
        n_obs = len(self.obs)
        rcn = rc[self.o_cam][:, None]
        a = np.einsum("nij,nkj->nki", rb[self.o_body], self.o_pts)
        q = np.einsum("nkij,nkj->nki", rcn, a + pb[self.o_body][:, None])
        d_xc, d_in = _projection_derivatives(q + tc[self.o_cam][:, None], intr)
        d_pb = d_xc @ rcn
        blocks = [
            d_xc @ (-_skew(q) @ jl_c[self.o_cam][:, None]),
            d_xc,
            d_pb @ (-_skew(a) @ jl_b[self.o_body][:, None]),
            d_pb,
        ]
        body0 = k + 6 * self.n_cam
        n_par = k + 6 * (self.n_cam + self.n_body) + 1
        blocks.append(self.o_n[..., None])
        cols = [
            k + 6 * self.o_cam[:, None] + np.arange(6),
            body0 + 6 * self.o_body[:, None] + np.arange(6),
            np.full((n_obs, 1), n_par - 1),
        ]
        if k:
            blocks.insert(0, d_in)
            cols.insert(0, np.broadcast_to(np.arange(k), (n_obs, k)))
        vals = np.concatenate(blocks, axis=-1) / (self.sigma_px * self.o_s[..., None])
        col = np.broadcast_to(np.concatenate(cols, axis=1)[:, None, None], vals.shape)
        row = np.broadcast_to(np.arange(8 * n_obs).reshape(n_obs, 4, 2, 1), vals.shape)
        rows, colz, valz = [row.ravel()], [col.ravel()], [vals.ravel()]
        if len(self.prior_idx):
            i = self.prior_idx
            phi = Rotation.from_matrix(rb[i] @ self.prior_r.transpose(0, 2, 1)).as_rotvec()
            d_rot = _left_jacobian_inv(phi) @ jl_b[i] / self.prior_sa[:, None, None]
            d_pos = np.eye(3) / self.prior_sp[:, None, None]
            r0 = 8 * n_obs + 6 * np.arange(len(i))
            for off, blk, c0 in ((0, d_pos, 3), (3, d_rot, 0)):
                rr = r0[:, None, None] + off + np.arange(3)[None, :, None]
                cc = body0 + 6 * i[:, None, None] + c0 + np.arange(3)[None, None, :]
                rows.append(np.broadcast_to(rr, blk.shape).ravel())
                colz.append(np.broadcast_to(cc, blk.shape).ravel())
                valz.append(blk.ravel())
        n_rows = 8 * n_obs + 6 * len(self.prior_idx)
        return sp.csr_matrix(
            (np.concatenate(valz), (np.concatenate(rows), np.concatenate(colz))),
            shape=(n_rows, n_par),
        )

    def rebase(self, x: FloatArray) -> FloatArray:
        """Fold the rotations of ``x`` into the bases: the same poses with ``δ = 0``."""
        _, rc, _, rb, _ = self.unpack(x)
        self.cam_r0, self.body_r0 = rc, rb
        y = x.copy()
        k = self.n_intr
        c = y[k : k + 6 * self.n_cam].reshape(-1, 6)
        b = y[k + 6 * self.n_cam : k + 6 * (self.n_cam + self.n_body)].reshape(-1, 6)
        c[:, :3] = 0.0
        b[:, :3] = 0.0
        return y


def adjust(
    bodies: Sequence[BodyModel],
    observations: Sequence[Observation],
    intrinsics: Intrinsics,
    camera_rotations: ArrayLike,
    camera_translations: ArrayLike,
    body_rotations: ArrayLike,
    body_positions: ArrayLike,
    *,
    refine_intrinsics: bool = True,
    reject_sigma: float = 6.0,
    progress: Callable[[int, float], None] | None = None,
    max_nfev: int = 200,
    placement: tuple[float, float] | None = None,
) -> BundleResult:
    """Adjust photos, bodies (and intrinsics) to the observed tag corners (see the module).

    Parameters
    ----------
    bodies : sequence of BodyModel
        Every observed tag must be mounted on one of them; at least one with a stated pose
        (``prior_position_m``) or the frame is not fixed.
    observations : sequence of Observation
        ``photo`` indexes the camera arrays.
    intrinsics : Intrinsics
        Start (or fixed, with ``refine_intrinsics=False``).
    camera_rotations, camera_translations : array_like, shapes (n_photos, 3, 3), (n_photos, 3)
        Start poses, world → camera.
    body_rotations, body_positions : array_like, shapes (n_bodies, 3, 3), (n_bodies, 3)
        Start poses, body → world.
    reject_sigma : float
        An observation whose corner RMS exceeds ``reject_sigma · σ_px`` after the first fit is
        removed (worst first, never a photo's or a body's last one) and the fit repeated
        (once).
    progress : callable (evaluations, cost), optional
        Called as the adjustment evaluates its residuals.
    placement : (angle 1σ deg, position 1σ m), optional
        How well each tag sits on its body (per axis; in its plane): each body's
        ``placement_covariance`` is then what the tags of the bodies without a stated pose add
        (:func:`placement_covariance`).

    Raises
    ------
    SolverError
        No stated pose fixes the frame, or the normal matrix is singular (a body or photo not
        tied to the rest): the message names it.
    """
    if not any(b.prior_position_m is not None for b in bodies):
        raise SolverError(
            "bundle adjustment: no reference tag with a stated pose fixes the article's frame; "
            "put reference tags at known positions and state them in the tags file"
        )
    prob = Problem(
        bodies,
        observations,
        intrinsics,
        np.asarray(camera_rotations, float),
        np.asarray(camera_translations, float),
        np.asarray(body_rotations, float),
        np.asarray(body_positions, float),
        refine_intrinsics,
    )
    nfev = [0]

    def fun(x: FloatArray) -> FloatArray:
        r = prob.residuals(x)
        nfev[0] += 1
        if progress is not None and nfev[0] % 20 == 1:
            progress(nfev[0], 0.5 * float(r @ r))
        return r

    x = _solve(prob, fun, prob.x0, "soft_l1", max_nfev)
    rejected = _reject_gross(prob, x, reject_sigma)
    x = _solve(prob, fun, prob.rebase(x), "linear", max_nfev)
    res = prob.scaled_residuals(x)
    dof = max(res.size - len(x) + 6 * len(prob.prior_idx), 1)
    sigma = float(np.sqrt(np.sum(res**2) / dof))
    prob.sigma_px = max(sigma, 1e-3)
    x = prob.rebase(x)
    cov, cond = _covariance(prob, x)
    out = _result(prob, bodies, x, cov, cond, sigma, rejected, nfev[0])
    if placement is None:
        return out
    extra = placement_covariance(prob, x, cov, np.radians(placement[0]), placement[1])
    return replace(
        out,
        bodies=tuple(
            replace(b, placement_covariance=e) for b, e in zip(out.bodies, extra, strict=True)
        ),
    )


def placement_covariance(
    prob: Problem, x: FloatArray, cov: FloatArray, angle_rad: float, position_m: float
) -> FloatArray:
    """What the tags' placement on their bodies adds to each body's covariance, shape
    (n_bodies, 6, 6).

    A tag sits on its body turned by a small ``ω`` (1σ ``angle_rad`` per axis, about its
    centre) and shifted by ``n`` in its plane (1σ ``position_m`` per axis): every corner of
    that tag, in every photo, moves by the same

        ΔX = −[v]× R_b ω + R_b R_t[:, :2] n,    v = R_b R_t c  (the corner from the tag's centre),

    an error the corners share, which the adjustment's ``(JᵀJ)⁻¹`` (independent corners) does
    not hold. The adjusted parameters follow it as ``Δθ = −Σ Jᵀ J_η η``
    (``J_η = ∂r/∂X · ∂X/∂η`` over that tag's rows, whitened as ``J``), so the considered
    covariance is ``Σ Jᵀ J_η S J_ηᵀ J Σ``, ``S`` the placements' variances, summed over the
    tags. Tags of bodies with a stated pose are left out: their placement is in the stated
    pose's 1σ. Through its lever arm (half the block's edge) a tag's shift turns the block,
    and a body seen through few of its tags keeps most of their placement: both are in this
    term, neither in a per-tag ``σ/√k``.
    """
    out = np.zeros((prob.n_body, 6, 6))
    if angle_rad <= 0 and position_m <= 0:
        return out
    jac = prob.jacobian(x).tocsr()
    _, _, _, rb, _ = prob.unpack(x)
    body0 = prob.n_intr + 6 * prob.n_cam
    scale = np.array([angle_rad] * 3 + [position_m] * 2)
    o_tag = np.array([o.tag_id for o in prob.obs], dtype=int)
    corner_of_row = np.arange(8) // 2
    sens = []
    for tag_id in np.unique(o_tag):
        bi, t = prob.mount[int(tag_id)]
        if prob.bodies[bi].prior_position_m is not None:
            continue
        idx = np.flatnonzero(o_tag == tag_id)
        rows = (8 * idx[:, None] + np.arange(8)).ravel()
        jr = jac[rows]
        d_x = jr[:, body0 + 6 * bi + 3 : body0 + 6 * bi + 6].toarray()
        v = tag_corners(t.side_m) @ np.asarray(t.rotation).T @ rb[bi].T
        a_pos = rb[bi] @ np.asarray(t.rotation)[:, :2]
        j_eta = np.empty((len(rows), 5))
        corner = np.tile(corner_of_row, len(idx))
        for k in range(4):
            sel = corner == k
            j_eta[sel, :3] = d_x[sel] @ (-_skew(v[k]) @ rb[bi])
            j_eta[sel, 3:] = d_x[sel] @ a_pos
        sens.append(jr.T @ (j_eta * scale))
    if not sens:
        return out
    b_all = np.hstack(sens)
    for i in range(prob.n_body):
        d = cov[body0 + 6 * i : body0 + 6 * i + 6] @ b_all
        out[i] = d @ d.T
    return out


def _solve(
    prob: Problem, fun: Callable[[FloatArray], FloatArray], x0: FloatArray, loss: str, nmax: int
) -> FloatArray:
    """Minimise ``fun`` from ``x0`` (scipy's trust-region reflective method, the analytic
    sparse Jacobian) with the robust ``loss``, the focal length kept within a factor 4 of the
    start (a diverging first pass would otherwise reach a negative one)."""
    lo, hi = np.full(x0.size, -np.inf), np.full(x0.size, np.inf)
    if prob.n_intr:  # the focal length stays within a factor 4 of its start
        f0 = prob.intr.fx
        lo[0], hi[0] = f0 / 4, 4 * f0
        x0 = x0.copy()
        x0[0] = np.clip(x0[0], lo[0] * 1.0001, hi[0] * 0.9999)
    sol = least_squares(
        fun,
        x0,
        jac=prob.jacobian,
        bounds=(lo, hi),
        loss=loss,
        f_scale=3.0,
        x_scale="jac",
        max_nfev=nmax,
        method="trf",
        tr_solver="lsmr",
        xtol=1e-8,
        ftol=1e-8,
        gtol=1e-10,
    )
    return np.asarray(sol.x)


def _reject_gross(
    prob: Problem, x: FloatArray, reject_sigma: float
) -> list[tuple[int, int, float]]:
    """Remove from ``prob`` the observations whose corner RMS exceeds ``reject_sigma · σ_px``
    at ``x`` (worst first; a photo or body keeps its last view) and set ``prob.sigma_px`` to
    the first fit's ``σ_px = sqrt(Σr²/(n − p))`` (``r`` over each view's ``sigma_scale``);
    returns ``(photo, tag_id, rms_px)`` of those removed."""
    res = prob.scaled_residuals(x)
    dof = max(res.size - len(x) + 6 * len(prob.prior_idx), 1)
    sigma = float(np.sqrt(np.sum(res**2) / dof))
    per_obs = np.sqrt(np.mean(res.reshape(len(prob.obs), -1) ** 2, axis=1))
    bad = np.zeros(len(per_obs), dtype=bool)
    n_cam_obs = np.bincount(prob.o_cam, minlength=prob.n_cam)
    n_body_obs = np.bincount(prob.o_body, minlength=prob.n_body)
    for i in np.argsort(-per_obs):
        if per_obs[i] <= reject_sigma * max(sigma, 0.05):
            break
        c, b = prob.o_cam[i], prob.o_body[i]
        if n_cam_obs[c] > 1 and n_body_obs[b] > 1:
            bad[i] = True
            n_cam_obs[c] -= 1
            n_body_obs[b] -= 1
    rejected: list[tuple[int, int, float]] = []
    if bad.any():
        rejected = [
            (prob.obs[i].photo, prob.obs[i].tag_id, float(per_obs[i])) for i in np.flatnonzero(bad)
        ]
        prob.set_observations([o for o, b in zip(prob.obs, bad, strict=True) if not b], prob.mount)
    prob.sigma_px = max(sigma, 1e-3)
    return rejected


def _covariance(prob: Problem, x: FloatArray) -> tuple[FloatArray, float]:
    """``Σ = (JᵀJ)⁻¹`` of the whitened problem at ``x`` (equilibrated by the diagonal) and the
    equilibrated normal matrix's condition number.

    Raises
    ------
    SolverError
        The normal matrix is singular: a photo or body not tied to the reference tags.
    """
    jac = prob.jacobian(x)
    jtj = (jac.T @ jac).toarray()
    d = np.sqrt(np.clip(np.diag(jtj), 1e-300, None))
    scaled = jtj / np.outer(d, d)
    ev, vec = np.linalg.eigh(scaled)
    cond = float(ev[-1] / max(ev[0], 1e-300))
    if ev[0] <= 1e-12 * ev[-1]:
        raise SolverError(
            f"bundle adjustment: the normal matrix is singular (condition {cond:.2g}): "
            f"{_parameter_name(prob, int(np.argmax(np.abs(vec[:, 0]))))} is not fixed by the "
            "photos; take photos that show it together with tags already fixed"
        )
    return np.linalg.inv(scaled) / np.outer(d, d), cond


def _parameter_name(prob: Problem, j: int) -> str:
    """What parameter ``j`` of the adjustment belongs to: a body (by name), a photo (by its
    index), the intrinsics or the edge bias."""
    k = prob.n_intr
    if j < k:
        return "the camera's intrinsics"
    if j < k + 6 * prob.n_cam:
        return f"photo {(j - k) // 6}"
    if j < k + 6 * (prob.n_cam + prob.n_body):
        return f"body {prob.bodies[(j - k - 6 * prob.n_cam) // 6].name}"
    return "the detector's edge bias"


def _result(
    prob: Problem,
    bodies: Sequence[BodyModel],
    x: FloatArray,
    cov: FloatArray,
    cond: float,
    sigma: float,
    rejected: list[tuple[int, int, float]],
    nfev: int,
) -> BundleResult:
    """The adjustment at ``x`` with its covariance ``cov`` as a :class:`BundleResult`."""
    res = prob.image_residuals(x)
    intr, rc, tc, rb, pb = prob.unpack(x)
    k = prob.n_intr
    body0 = k + 6 * prob.n_cam
    out = []
    for i, b in enumerate(bodies):
        sel = prob.o_body == i
        s = slice(body0 + 6 * i, body0 + 6 * i + 6)
        out.append(
            BodyEstimate(
                name=b.name,
                kind=b.kind,
                node=b.node,
                rotation=rb[i],
                position_m=pb[i],
                covariance=cov[s, s],
                n_photos=len(set(prob.o_cam[sel].tolist())),
                n_corners=4 * int(sel.sum()),
            )
        )
    per_photo = np.full(prob.n_cam, np.nan)
    r2 = np.sum(res**2, axis=(1, 2))
    for c in range(prob.n_cam):
        m = prob.o_cam == c
        if m.any():
            per_photo[c] = float(np.sqrt(r2[m].sum() / (8 * m.sum())))
    return BundleResult(
        bodies=tuple(out),
        camera_rotations=rc,
        camera_translations=tc,
        intrinsics=intr,
        intrinsics_std=np.sqrt(np.clip(np.diag(cov)[:k], 0, None)) if k else None,
        sigma_px=sigma,
        n_corners=4 * len(prob.obs),
        n_parameters=len(x),
        rms_px=float(np.sqrt(np.mean(res**2))),
        photo_rms_px=per_photo,
        rejected=tuple(rejected),
        nfev=nfev,
        condition=cond,
        edge_bias_px=float(x[-1]),
        edge_bias_std_px=float(np.sqrt(max(cov[-1, -1], 0.0))),
    )
