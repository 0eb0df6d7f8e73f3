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

A tag sits on its body only as well as it was glued: turned by a small ``ω`` (body frame,
about the tag's centre) and shifted by ``n`` in its plane, each with a stated 1σ. Given that 1σ
(``placement``), every tag of a body without a stated pose carries these five unknowns too,

    P = exp([ω]×) R_bk c + o_bk + R_bk[:, :2] n,

with the prior ``Σ |ω|²/σ_ω² + |n|²/σ_n²`` in the sum above. The photos fix where the tags sit
relative to one another; the priors fix the body in them, each tag by the same weight whatever
the number of views that show it (a block is where its tags, placed by the same hand, say it
is on average, not where the tag seen most says). A tag's placement error is then in each
body's covariance as it should be: shared by all its corners in every view, through the lever
arm of the block. A tag whose estimated placement is far outside its stated 1σ
(:attr:`TagPlacement.z`) was glued off its stated place.

The covariance of the parameters is ``Σ = (JᵀJ)⁻¹`` of the whitened problem at the solution,
with ``σ_px² = Σ (r/s)² / (n − p)`` estimated from the corner residuals (the reprojection error
the photos actually show, not a nominal one; ``s`` each view's ``sigma_scale``; ``p`` counts
only the unknowns no prior holds). Each body's part of it splits into what its priors give and
what its corners' noise gives (:attr:`BodyEstimate.prior_covariance`), and its corners'
residuals against ``σ_px`` give its :attr:`BodyEstimate.residual_factor`: a body whose tags are
partly hidden in many views shows there, where ``σ_px``, shared by the set, does not.
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
    "TagPlacement",
    "adjust",
]

FloatArray = NDArray[np.float64]
N_INTR = 8
#: A placement component is tested for a misplaced tag only when the photos hold at least this
#: share of its variance (its redundancy as a prior observation).
MIN_REDUNDANCY = 0.2


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
    residual_factor : float
        ``f = sqrt(Σ (r/s)² / (σ_px² ν))`` over this body's corners, ``ν = 8 n − 6 − 5 k`` (its
        ``n`` views less its own pose and its ``k`` placed tags' unknowns): how its corners
        agree with the set's ``σ_px`` (about 1; well above where its tags are partly hidden,
        bent or misread in many views, which the set's ``σ_px`` and ``covariance`` do not
        hold). 1 where ``ν ≤ 0``.
    prior_covariance : ndarray, shape (6, 6)
        The part of ``covariance`` the priors give (the stated poses and the tags'
        placements): ``Σ J_pᵀ J_p Σ`` over the prior rows ``J_p``; the rest, ``Σ J_cᵀ J_c Σ``,
        is the corners' noise, the part a ``residual_factor`` scales.
    """

    name: str
    kind: str
    node: int | None
    rotation: FloatArray
    position_m: FloatArray
    covariance: FloatArray
    n_photos: int
    n_corners: int
    residual_factor: float = 1.0
    prior_covariance: FloatArray = field(default_factory=lambda: np.zeros((6, 6)))

    @property
    def position_std_m(self) -> FloatArray:
        """1σ of each world coordinate of the origin, m."""
        return np.sqrt(np.clip(np.diag(self.covariance)[3:], 0, None))

    @property
    def angle_std_deg(self) -> FloatArray:
        """1σ of the small rotation about each world axis, degrees."""
        return np.degrees(np.sqrt(np.clip(np.diag(self.covariance)[:3], 0, None)))


@dataclass(frozen=True)
class TagPlacement:
    """A tag's estimated placement on its body: the small rotation ``ω`` (body frame, rad)
    about its centre and the shift ``n`` along its own x, y (m), each with its 1σ.

    ``z`` is the largest ``|η̂| / sqrt(σ_prior² − σ_post²)`` over the five: the estimate against
    the spread it has when the tag sits within its stated 1σ (a prior's standardised residual;
    about N(0, 1) for a tag placed as stated, several for one glued off its place). Only the
    components the photos check are tested: those whose redundancy ``r = 1 − σ_post²/σ_prior²``
    is at least :data:`MIN_REDUNDANCY` (below it the estimate is mostly the prior's, its spread
    small, and any small model error would read as a large ``z``; an error there is also
    what the photos cannot see). ``freed``:
    the tag was found off its place (``z`` over the adjustment's limit, the value shown) and
    its prior dropped, so its body's pose no longer leans on where it was stated to sit.
    """

    tag_id: int
    body: str
    angle_rad: FloatArray
    shift_m: FloatArray
    angle_std_rad: FloatArray
    shift_std_m: FloatArray
    z: float
    n_views: int
    freed: bool = False


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
    placements: tuple[TagPlacement, ...] = ()

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
    rotation increment and position, each placed tag's ``(ω, n)``, one outward shift of the
    detected corners in pixels), the residuals and their sparse Jacobian.

    ``placement`` is the tags' placement 1σ ``(angle rad, in-plane shift m)``; None takes every
    tag as placed exactly (no placement unknowns)."""

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
        placement: tuple[float, float] | None = None,
    ) -> None:
        self.bodies = list(bodies)
        self.intr = intr
        self.refine = refine_intrinsics
        self.n_cam = len(cam_r)
        self.n_body = len(bodies)
        self.cam_r0 = np.array(cam_r, float)
        self.body_r0 = np.array(body_r, float)
        mount = {t.tag_id: (i, t) for i, b in enumerate(bodies) for t in b.tags}
        seen = {o.tag_id for o in obs}
        placed = (
            []
            if placement is None or max(placement) <= 0
            else [
                t.tag_id
                for b in bodies
                if b.prior_position_m is None
                for t in b.tags
                if t.tag_id in seen
            ]
        )
        self.placed_tags = np.array(placed, dtype=int)
        self.n_place = len(placed)
        sa, sn = placement if placement is not None else (0.0, 0.0)
        self.place_scale = np.array([max(sa, 1e-9)] * 3 + [max(sn, 1e-12)] * 2)
        self.x0 = np.concatenate(
            [
                intr.vector() if refine_intrinsics else np.zeros(0),
                np.column_stack([np.zeros((self.n_cam, 3)), cam_t]).ravel(),
                np.column_stack([np.zeros((self.n_body, 3)), body_p]).ravel(),
                np.zeros(5 * self.n_place),
                [0.0],
            ]
        )
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
        tags = [mount[o.tag_id][1] for o in obs]
        self.o_pts = np.array([t.corners_body() for t in tags]).reshape(-1, 4, 3)
        self.o_c = np.array(
            [tag_corners(t.side_m) @ np.asarray(t.rotation).T for t in tags]
        ).reshape(-1, 4, 3)
        self.o_a = np.array([np.asarray(t.rotation)[:, :2] for t in tags]).reshape(-1, 3, 2)
        index = {int(t): j for j, t in enumerate(self.placed_tags)}
        self.o_place = np.array([index.get(o.tag_id, -1) for o in obs], dtype=int)
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

    @property
    def place0(self) -> int:
        """Index in ``x`` of the first placed tag's ``(ω, n)``."""
        return self.n_intr + 6 * (self.n_cam + self.n_body)

    @property
    def n_prior_rows(self) -> int:
        """Residuals that are priors: six per stated pose, five per placed tag."""
        return 6 * len(self.prior_idx) + 5 * self.n_place

    def body_points(self, x: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Each observed corner in its body's frame with its tag's placement in ``x``,
        ``P = exp([ω]×) R_bk c + o_bk + R_bk[:, :2] n`` (shape (n_obs, 4, 3)), and the
        placement rotations ``exp([ω]×) R_bk c`` (the corners from the tag's centre)."""
        if not self.n_place:
            return self.o_pts, self.o_c
        eta = np.zeros((len(self.obs), 5))
        m = self.o_place >= 0
        eta[m] = x[self.place0 : self.place0 + 5 * self.n_place].reshape(-1, 5)[self.o_place[m]]
        turn = _rot(eta[:, :3], np.broadcast_to(np.eye(3), (len(eta), 3, 3)))
        v = np.einsum("nij,nkj->nki", turn, self.o_c)
        shift = np.einsum("nij,nj->ni", self.o_a, eta[:, 3:])
        return self.o_pts - self.o_c + v + shift[:, None], v

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
        pts, _ = self.body_points(x)
        xw = np.einsum("nij,nkj->nki", rb[self.o_body], pts) + pb[self.o_body][:, None]
        xc = np.einsum("nij,nkj->nki", rc[self.o_cam], xw) + tc[self.o_cam][:, None]
        return project(xc, intr) - (self.o_uv - x[-1] * self.o_n)

    def residuals(self, x: FloatArray) -> FloatArray:
        """Whitened residuals: the corners, then the stated poses' priors, then the placed
        tags' priors ``η / σ``."""
        r_img = self.scaled_residuals(x).ravel() / self.sigma_px
        parts = [r_img]
        if len(self.prior_idx):
            _, _, _, rb, pb = self.unpack(x)
            i = self.prior_idx
            dp = (pb[i] - self.prior_p) / self.prior_sp[:, None]
            dr = Rotation.from_matrix(rb[i] @ self.prior_r.transpose(0, 2, 1)).as_rotvec()
            parts.append(np.concatenate([dp, dr / self.prior_sa[:, None]], axis=1).ravel())
        if self.n_place:
            eta = x[self.place0 : self.place0 + 5 * self.n_place].reshape(-1, 5)
            parts.append((eta / self.place_scale).ravel())
        return np.concatenate(parts)

    def jacobian(self, x: FloatArray) -> sp.csr_matrix:
        """The analytic Jacobian of :meth:`residuals` at ``x``, sparse (n_residuals,
        n_parameters): a corner depends on the intrinsics, its photo's pose and its body's pose,

            ∂u/∂δ_c = U (−[R_c X_w]×) J_l(δ_c),  ∂u/∂t_c = U,
            ∂u/∂δ_b = U R_c (−[R_b P]×) J_l(δ_b),  ∂u/∂p_b = U R_c,
            ∂u/∂ω = U R_c R_b (−[exp([ω]×) R_bk c]×) J_l(ω),  ∂u/∂n = U R_c R_b R_bk[:, :2],

        ``U = ∂u/∂X_c`` (:func:`_projection_derivatives`); a reference prior's rotation
        residual ``φ = log(R_b R̄_bᵀ)`` has ``∂φ/∂δ_b = J_l(φ)⁻¹ J_l(δ_b)``, a placement's
        prior ``η/σ`` the diagonal ``1/σ``."""
        intr, rc, tc, rb, pb = self.unpack(x)
        k = self.n_intr
        c = x[k : k + 6 * self.n_cam].reshape(-1, 6)
        b = x[k + 6 * self.n_cam : k + 6 * (self.n_cam + self.n_body)].reshape(-1, 6)
        jl_c, jl_b = _left_jacobian(c[:, :3]), _left_jacobian(b[:, :3])
        n_obs = len(self.obs)
        rcn = rc[self.o_cam][:, None]
        pts, v = self.body_points(x)
        a = np.einsum("nij,nkj->nki", rb[self.o_body], pts)
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
        n_par = self.place0 + 5 * self.n_place + 1
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
        if self.n_place:
            self._placement_jacobian(x, d_pb, v, rows, colz, valz)
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
        if self.n_place:
            rows.append(8 * n_obs + 6 * len(self.prior_idx) + np.arange(5 * self.n_place))
            colz.append(self.place0 + np.arange(5 * self.n_place))
            valz.append(np.tile(1.0 / self.place_scale, self.n_place))
        n_rows = 8 * n_obs + self.n_prior_rows
        return sp.csr_matrix(
            (np.concatenate(valz), (np.concatenate(rows), np.concatenate(colz))),
            shape=(n_rows, n_par),
        )

    def _placement_jacobian(
        self,
        x: FloatArray,
        d_pb: FloatArray,
        v: FloatArray,
        rows: list[NDArray[np.int_]],
        colz: list[NDArray[np.int_]],
        valz: list[FloatArray],
    ) -> None:
        """Append the corners' derivatives by their tags' ``(ω, n)`` (see :meth:`jacobian`;
        ``d_pb = U R_c``, ``v`` the turned corners from the tags' centres)."""
        _, _, _, rb, _ = self.unpack(x)
        m = np.flatnonzero(self.o_place >= 0)
        j = self.o_place[m]
        eta = x[self.place0 : self.place0 + 5 * self.n_place].reshape(-1, 5)
        rbn = rb[self.o_body[m]][:, None]
        d_w = d_pb[m] @ rbn @ (-_skew(v[m]) @ _left_jacobian(eta[j, :3])[:, None])
        d_n = d_pb[m] @ rbn @ self.o_a[m][:, None]
        vals = np.concatenate([d_w, d_n], axis=-1) / (self.sigma_px * self.o_s[m][..., None])
        col = self.place0 + 5 * j[:, None] + np.arange(5)
        rows.append(
            np.broadcast_to(
                (8 * m[:, None] + np.arange(8)).reshape(-1, 4, 2, 1), vals.shape
            ).ravel()
        )
        colz.append(np.broadcast_to(col[:, None, None], vals.shape).ravel())
        valz.append(vals.ravel())

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

    def placement_z(self, x: FloatArray, cov: FloatArray) -> FloatArray:
        """Each placed tag's :attr:`TagPlacement.z` at ``x`` with the covariance ``cov``."""
        eta = x[self.place0 : self.place0 + 5 * self.n_place].reshape(-1, 5)
        post = np.clip(np.diag(cov)[self.place0 : self.place0 + 5 * self.n_place], 0.0, None)
        var = self.place_scale**2 - post.reshape(-1, 5)
        tested = var >= MIN_REDUNDANCY * self.place_scale**2
        z = np.abs(eta) / np.sqrt(np.where(tested, var, 1.0))
        return np.asarray(np.max(np.where(tested, z, 0.0), axis=1))

    def placements(
        self, x: FloatArray, cov: FloatArray, found: dict[int, tuple[float, bool]] | None = None
    ) -> tuple[TagPlacement, ...]:
        """The placed tags' estimates at ``x`` with their 1σ from ``cov``; ``found`` maps the
        index of each tag found off its place to its ``z`` then and whether its prior was
        dropped."""
        found = found or {}
        z = self.placement_z(x, cov) if self.n_place else np.zeros(0)
        out = []
        for j, tag_id in enumerate(self.placed_tags):
            s = slice(self.place0 + 5 * j, self.place0 + 5 * j + 5)
            eta = x[s]
            post = np.clip(np.diag(cov)[s], 0.0, None)
            out.append(
                TagPlacement(
                    tag_id=int(tag_id),
                    body=self.bodies[self.mount[int(tag_id)][0]].name,
                    angle_rad=eta[:3].copy(),
                    shift_m=eta[3:].copy(),
                    angle_std_rad=np.sqrt(post[:3]),
                    shift_std_m=np.sqrt(post[3:]),
                    z=float(found[j][0] if j in found else z[j]),
                    n_views=int(np.sum(self.o_place == j)),
                    freed=found.get(j, (0.0, False))[1],
                )
            )
        return tuple(out)


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
    misplaced_z: float | None = None,
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
        How well each tag sits on its body (per axis; in its plane): the tags of the bodies
        without a stated pose are then placed by the adjustment (see the module), and the
        bodies' covariances hold their placement. Without it the tags are taken as placed
        exactly.
    misplaced_z : float, optional
        A placed tag whose :attr:`TagPlacement.z` exceeds it is taken as glued off its place
        and its prior dropped, worst first (:func:`_free_misplaced`); None keeps every prior.

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
        None if placement is None else (float(np.radians(placement[0])), float(placement[1])),
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
    dof = max(res.size - len(x) + prob.n_prior_rows, 1)
    sigma = float(np.sqrt(np.sum(res**2) / dof))
    prob.sigma_px = max(sigma, 1e-3)
    x = prob.rebase(x)
    cov, cond = _covariance(prob, x)
    x, cov, found = _free_misplaced(prob, x, cov, misplaced_z)
    out = _result(prob, bodies, x, cov, cond, sigma, rejected, nfev[0])
    parts = _prior_parts(prob, x, cov, [j for j, (_, freed) in found.items() if freed])
    return replace(
        out,
        bodies=tuple(
            replace(b, prior_covariance=p) for b, p in zip(out.bodies, parts, strict=True)
        ),
        placements=prob.placements(x, cov, found),
    )


def _prior_parts(prob: Problem, x: FloatArray, cov: FloatArray, freed: list[int]) -> FloatArray:
    """Each body's ``(Σ J_pᵀ J_p Σ)_bb`` (shape (n_bodies, 6, 6)): what the prior rows ``J_p``
    (the stated poses; the placed tags' priors but those of the tags ``freed``) give its
    covariance. ``Σ = (J_cᵀ J_c + J_pᵀ J_p)⁻¹`` splits as ``Σ J_cᵀ J_c Σ + Σ J_pᵀ J_p Σ``."""
    n_img = 8 * len(prob.obs)
    jp = prob.jacobian(x)[n_img:].tocsr()
    if freed:
        keep = np.ones(jp.shape[0], dtype=bool)
        r0 = 6 * len(prob.prior_idx)
        for j in freed:
            keep[r0 + 5 * j : r0 + 5 * j + 5] = False
        jp = jp[keep]
    body0 = prob.n_intr + 6 * prob.n_cam
    a = np.asarray(jp @ cov[:, body0 : body0 + 6 * prob.n_body])
    blocks = a.reshape(a.shape[0], prob.n_body, 6)
    return np.einsum("rbi,rbj->bij", blocks, blocks)


def _free_misplaced(
    prob: Problem, x: FloatArray, cov: FloatArray, z_limit: float | None
) -> tuple[FloatArray, FloatArray, dict[int, tuple[float, bool]]]:
    """Drop, one at a time, the prior of the placed tag with the largest ``z`` while it is
    over ``z_limit`` (iterative data snooping: a tag glued off its place pulls its block, and
    the block's other tags then look off too until the worst is freed).

    Dropping tag ``j``'s prior rows ``U = ∂r_p/∂x`` (``1/σ`` on its five unknowns, residual
    ``r_p = η_j/σ``) from the normal matrix ``H = Σ⁻¹`` gives, by Woodbury,

        Σ' = (H − U Uᵀ)⁻¹ = Σ + Σ U (I − Uᵀ Σ U)⁻¹ Uᵀ Σ,    x' = x + Σ' U r_p

    (one Gauss-Newton step of the objective without that prior from its minimum ``x``, where
    the image terms' gradient is ``−U r_p``). ``Uᵀ Σ U`` is the tag's posterior over prior
    variance: a tag the photos do not place by themselves (the eigenvalues of
    ``I − Uᵀ Σ U`` below 0.05, e.g. its body's only tag) keeps its prior and is reported as
    found. Returns ``x'``, ``Σ'`` and ``{tag index: (z when found, prior dropped)}``."""
    found: dict[int, tuple[float, bool]] = {}
    if z_limit is None or not prob.n_place:
        return x, cov, found
    for _ in range(prob.n_place):
        z = prob.placement_z(x, cov)
        z[list(found)] = 0.0
        j = int(np.argmax(z))
        if z[j] <= z_limit:
            break
        s = slice(prob.place0 + 5 * j, prob.place0 + 5 * j + 5)
        u = 1.0 / prob.place_scale
        m = np.eye(5) - u[:, None] * cov[s, s] * u[None, :]
        free = bool(np.min(np.linalg.eigvalsh(m)) >= 0.05)
        found[j] = (float(z[j]), free)
        if not free:
            continue
        cu = cov[:, s] * u
        cov = cov + cu @ np.linalg.solve(m, cu.T)
        g = np.zeros(len(x))
        g[s] = u * (x[s] * u)
        x = x + cov @ g
    return x, cov, found


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
    dof = max(res.size - len(x) + prob.n_prior_rows, 1)
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
    index), the intrinsics, a tag's placement or the edge bias."""
    k = prob.n_intr
    if j < k:
        return "the camera's intrinsics"
    if j < k + 6 * prob.n_cam:
        return f"photo {(j - k) // 6}"
    if j < k + 6 * (prob.n_cam + prob.n_body):
        return f"body {prob.bodies[(j - k - 6 * prob.n_cam) // 6].name}"
    if j < prob.place0 + 5 * prob.n_place:
        return f"the placement of tag {prob.placed_tags[(j - prob.place0) // 5]}"
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
    chi2 = np.sum(prob.scaled_residuals(x) ** 2, axis=(1, 2)) / max(sigma, 1e-3) ** 2
    intr, rc, tc, rb, pb = prob.unpack(x)
    k = prob.n_intr
    body0 = k + 6 * prob.n_cam
    out = []
    for i, b in enumerate(bodies):
        sel = prob.o_body == i
        s = slice(body0 + 6 * i, body0 + 6 * i + 6)
        placed = prob.o_place[sel]
        nu = 8 * int(sel.sum()) - 6 - 5 * len(set(placed[placed >= 0].tolist()))
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
                residual_factor=float(np.sqrt(chi2[sel].sum() / nu)) if nu > 0 else 1.0,
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
