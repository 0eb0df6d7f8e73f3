"""Photographs of a tagged article through a pinhole camera with lens distortion.

The world: every body of a tags plan (:class:`~dimacq.io.tags_file.TagsFile`) at its true pose
— triax blocks on the true sensors, impact jigs on the true inputs, reference plates where
stated plus a draw of their stated 1σ, a scale bar beside the article — each tag placed on its
body with a draw of the plan's placement 1σ. A photo: tags facing the camera are warped
(``cv2.warpPerspective``) from ``cv2.aruco.generateImageMarker`` onto a canvas at twice the
resolution through the ideal pinhole, the canvas is resampled through the lens distortion
(``cv2.undistortPoints`` of every sensor pixel, ``cv2.remap``) after the lens blur and the
pixels' area are applied to the canvas (a sensor integrates the blurred image), then exposed,
occluded in part by random shapes, given sensor noise, and written as JPEG with the EXIF a
camera writes (35 mm-equivalent focal length). The photographer (:func:`photograph_article`)
aims from where the bodies are and which way their tags face, as a person sees them; nothing but
the image files leaves this module for the solver.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from dimacq.io.tags_file import TagsFile
from dimacq.model.setup import TestSetup

__all__ = [
    "PHONE_12MP",
    "CameraModel",
    "Shot",
    "TaggedWorld",
    "camera_for",
    "photo_plan",
    "photograph_article",
    "tagged_world",
]

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class CameraModel:
    """The simulated camera: pinhole ``f`` px, principal point, OpenCV distortion, size."""

    f_px: float = 1450.0
    cx: float = 803.7
    cy: float = 596.2
    dist: tuple[float, float, float, float, float] = (-0.11, 0.07, 3e-4, -2e-4, 0.0)
    width: int = 1600
    height: int = 1200

    @property
    def matrix(self) -> FloatArray:
        return np.array([[self.f_px, 0, self.cx], [0, self.f_px, self.cy], [0, 0, 1.0]])


PHONE_12MP = CameraModel(
    f_px=2900.0, cx=2006.3, cy=1496.1, dist=(-0.08, 0.05, 2e-4, -1e-4, 0.0), width=4000, height=3000
)
LARGE_ARTICLE_M = 1.5  # tagged region (m across) beyond which the lab uses the 12 MP camera
FLOOR_Z = -0.25  # the lowest view: a direction to the camera at most this far below level
AIM_SCATTER_DEG = 18.0
HIDDEN = 1000  # a view the article hides (counted as that many bodies in front)
SUPERSAMPLE = 2  # the ideal canvas's pixels per sensor pixel (each way)
TRIAX_VIEWS = 3  # close-ups of each triax block a round (each impact jig: one)  # how far a close-up's direction strays from the one the plan aims


@dataclass(frozen=True)
class WorldTag:
    tag_id: int
    side_m: float
    rotation: FloatArray  # tag → world
    centre_m: FloatArray
    body: str
    hidden: bool  # against the article (a block's mounting face)


@dataclass(frozen=True)
class TaggedWorld:
    tags: tuple[WorldTag, ...]
    centre_m: FloatArray
    extent_m: FloatArray
    occluder_box: tuple[FloatArray, FloatArray] | None
    truth: dict[str, tuple[FloatArray, FloatArray]]  # body label → (R body→world, position)


def tagged_world(
    tags: TagsFile,
    setup_true: TestSetup,
    rng: np.random.Generator,
    occluder_box: tuple[Any, Any] | None = None,
) -> TaggedWorld:
    """The bodies of ``tags`` at their true poses (see the module)."""
    resp: dict[int, dict[int, tuple[FloatArray, FloatArray]]] = {}
    for ch in setup_true.responses:
        resp.setdefault(ch.node, {})[abs(ch.direction)] = (
            np.sign(ch.direction) * np.asarray(ch.direction_gcs, float),
            np.asarray(ch.position_m, float),
        )
    ins = {e.node: e for e in setup_true.excitations}
    pts = np.vstack([setup_true.response_positions, setup_true.input_positions])
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    centre = 0.5 * (lo + hi)
    truth: dict[str, tuple[FloatArray, FloatArray]] = {}
    out: list[WorldTag] = []
    for b in tags.bodies:
        if b.kind == "triax":
            assert b.node is not None
            axes = resp[b.node]
            r = np.column_stack([axes[k][0] for k in (1, 2, 3)])
            u, _, vt = np.linalg.svd(r)
            r = u @ vt
            p = axes[1][1]
        elif b.kind == "input":
            assert b.node is not None
            e = ins[b.node]
            z = -np.asarray(e.direction_gcs, float)
            rot, _ = Rotation.align_vectors([z], [[0.0, 0.0, 1.0]])
            r = (rot * Rotation.from_euler("z", rng.uniform(0, 360), degrees=True)).as_matrix()
            p = np.asarray(e.position_m, float)
        elif b.kind == "reference":
            assert b.rotation_deg is not None and b.position_m is not None
            r = (
                Rotation.from_rotvec(rng.normal(scale=np.radians(b.angle_std_deg), size=3))
                * Rotation.from_rotvec(np.radians(b.rotation_deg))
            ).as_matrix()
            p = np.asarray(b.position_m, float) + rng.normal(scale=b.position_std_m, size=3)
        else:  # the scale bar lies below the article, along its longest side
            k = int(np.argmax(hi - lo))
            rot, _ = Rotation.align_vectors([np.eye(3)[k]], [[1.0, 0.0, 0.0]])
            r = rot.as_matrix()
            p = centre.copy()
            p[2] = lo[2] - 0.15 * (hi[2] - lo[2]) - 0.05
            p[(k + 1) % 3] += 0.3 * (hi - lo)[(k + 1) % 3]
        truth[b.label()] = (r, p)
        inward = centre - p
        specs = tags.tags_of(b)
        normals = [
            r @ Rotation.from_rotvec(np.radians(t.rotation_deg)).apply([0, 0, 1.0]) for t in specs
        ]
        mount_face = (
            int(np.argmax([np.dot(n, inward) for n in normals])) if b.kind == "triax" else -1
        )
        for k, t in enumerate(specs):
            r_bt = (
                Rotation.from_rotvec(rng.normal(scale=np.radians(tags.placement_angle_deg), size=3))
                * Rotation.from_rotvec(np.radians(t.rotation_deg))
            ).as_matrix()
            o_bt = np.asarray(t.offset_m) + r_bt @ np.append(
                rng.normal(scale=tags.placement_position_m, size=2), 0.0
            )
            out.append(
                WorldTag(
                    b.first_id + t.index,
                    t.side_m,
                    r @ r_bt,
                    r @ o_bt + p,
                    b.label(),
                    k == mount_face or (b.kind == "input" and k == 5),
                )
            )
    box = None
    if occluder_box is not None:
        box = (np.asarray(occluder_box[0], float), np.asarray(occluder_box[1], float))
    all_c = np.array([t.centre_m for t in out])
    return TaggedWorld(
        tuple(out),
        0.5 * (all_c.min(0) + all_c.max(0)),
        all_c.max(0) - all_c.min(0),
        box,
        truth,
    )


def _segment_hits_box(a: FloatArray, b: FloatArray, lo: FloatArray, hi: FloatArray) -> bool:
    """Whether the segment a→b passes through the box (slab test)."""
    d = b - a
    t0, t1 = 0.0, 1.0
    for k in range(3):
        if abs(d[k]) < 1e-12:
            if a[k] < lo[k] or a[k] > hi[k]:
                return False
            continue
        ta, tb = (lo[k] - a[k]) / d[k], (hi[k] - a[k]) / d[k]
        t0, t1 = max(t0, min(ta, tb)), min(t1, max(ta, tb))
        if t0 > t1:
            return False
    return True


_DICT_CACHE: dict[str, Any] = {}


def _marker(tag_id: int, family: str, px: int) -> NDArray[np.uint8]:
    """The printed tag with a white margin of one cell: ``px`` pixels per cell."""
    d = _DICT_CACHE.setdefault(
        family, cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, family))
    )
    cells = d.markerSize + 2
    img = cv2.aruco.generateImageMarker(d, tag_id, cells * px)
    out: NDArray[np.uint8] = cv2.copyMakeBorder(
        img, px, px, px, px, cv2.BORDER_CONSTANT, value=255
    ).astype(np.uint8)
    return out


_MAP_CACHE: dict[CameraModel, tuple[NDArray[np.float32], NDArray[np.float32]]] = {}


def _distortion_map(cam: CameraModel, ss: int) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
    """For each sensor pixel, where it looks on the ideal (undistorted) canvas of ``ss``× size."""
    if cam not in _MAP_CACHE:
        u, v = np.meshgrid(
            np.arange(cam.width, dtype=np.float64), np.arange(cam.height, dtype=np.float64)
        )
        pts = np.stack([u.ravel(), v.ravel()], axis=1).reshape(-1, 1, 2)
        und = cv2.undistortPoints(
            pts,
            cam.matrix,
            np.array(cam.dist),
            R=np.eye(3),
            P=cam.matrix,
            criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 40, 1e-10),
        ).reshape(cam.height, cam.width, 2)
        mx = (ss * und[..., 0] + (ss - 1) / 2).astype(np.float32)
        my = (ss * und[..., 1] + (ss - 1) / 2).astype(np.float32)
        _MAP_CACHE[cam] = (mx, my)
    return _MAP_CACHE[cam]


def render(
    world: TaggedWorld,
    cam: CameraModel,
    r_wc: FloatArray,
    t_wc: FloatArray,
    rng: np.random.Generator,
    *,
    family: str = "DICT_APRILTAG_36h11",
    blur_px: float = 0.6,
    noise: float = 2.0,
    exposure: float = 1.0,
    occluders: int = 1,
) -> NDArray[np.uint8]:
    """One photo (grey, uint8) from the camera at ``X_c = r_wc X + t_wc``."""
    ss = SUPERSAMPLE
    h2, w2 = ss * cam.height, ss * cam.width
    canvas = background(cam, rng)
    k2 = canvas_matrix(cam)
    centre_cam = -r_wc.T @ t_wc
    order = sorted(world.tags, key=lambda t: -float(np.linalg.norm(r_wc @ t.centre_m + t_wc)))
    for t in order:
        if t.hidden:
            continue
        pc = r_wc @ t.centre_m + t_wc
        if pc[2] < 0.05:
            continue
        view = pc / np.linalg.norm(pc)
        normal = r_wc @ t.rotation[:, 2]
        if np.dot(normal, -view) < np.cos(np.radians(75)):
            continue
        if world.occluder_box is not None and _segment_hits_box(
            centre_cam, t.centre_m + 0.004 * t.rotation[:, 2], *world.occluder_box
        ):
            continue
        h = 0.5 * t.side_m
        cells = 8  # 36h11: 6 data cells + border; margin adds one each side
        margin = h / cells * 2  # a one-cell white margin
        hm = h + margin
        quad = np.array([[-hm, hm, 0], [hm, hm, 0], [hm, -hm, 0], [-hm, -hm, 0]])
        xw = quad @ t.rotation.T + t.centre_m
        xc = xw @ r_wc.T + t_wc
        if np.any(xc[:, 2] < 0.05):
            continue
        uv = (xc @ k2.T)[:, :2] / xc[:, 2:3]
        if np.any(uv < -200) or np.any(uv > [w2 + 200, h2 + 200]):
            continue
        size = float(np.max(np.linalg.norm(uv - np.roll(uv, 1, axis=0), axis=1)))
        px = int(np.clip(size / 10, 2, 40))
        mk = _marker(t.tag_id, family, px).astype(np.float32)
        n = mk.shape[0]
        src = np.array(
            [[-0.5, -0.5], [n - 0.5, -0.5], [n - 0.5, n - 0.5], [-0.5, n - 0.5]], np.float32
        )
        x0, y0 = np.floor(uv.min(0)).astype(int) - 2
        x1, y1 = np.ceil(uv.max(0)).astype(int) + 2
        x0, y0, x1, y1 = max(x0, 0), max(y0, 0), min(x1, w2), min(y1, h2)
        if x1 <= x0 or y1 <= y0:
            continue
        hmat = cv2.getPerspectiveTransform(src, (uv - [x0, y0]).astype(np.float32))
        roi = (x1 - x0, y1 - y0)
        shade = float(np.clip(0.55 + 0.45 * np.dot(normal, -view), 0.5, 1.0))
        warped = cv2.warpPerspective(mk * shade, hmat, roi, flags=cv2.INTER_LINEAR)
        mask = cv2.warpPerspective(np.ones_like(mk), hmat, roi, flags=cv2.INTER_LINEAR)
        sub = canvas[y0:y1, x0:x1]
        canvas[y0:y1, x0:x1] = sub * (1 - mask) + warped
    # partial occlusion: cables, a hand
    for _ in range(occluders):
        if rng.uniform() < 0.5:
            pts = rng.uniform([0, 0], [w2, h2], (2, 2)).astype(np.int32)
            cv2.line(
                canvas,
                tuple(pts[0]),
                tuple(pts[1]),
                float(rng.uniform(10, 60)),
                int(rng.uniform(6, 30)),
            )
        else:
            c = rng.uniform([0, 0], [w2, h2])
            poly = (c + rng.normal(scale=120, size=(5, 2))).astype(np.int32)
            cv2.fillPoly(canvas, [poly], float(rng.uniform(20, 200)))
    return expose(canvas, cam, rng, blur_px=blur_px, noise=noise, exposure=exposure)


def background(cam: CameraModel, rng: np.random.Generator) -> NDArray[Any]:
    """The ideal canvas (:data:`SUPERSAMPLE` × the sensor's size) filled with a smooth random
    background around grey level 100."""
    ss = SUPERSAMPLE
    h2, w2 = ss * cam.height, ss * cam.width
    low = rng.normal(0, 1, (h2 // 64 + 2, w2 // 64 + 2)).astype(np.float32)
    out: NDArray[Any] = 100 + 30 * cv2.resize(low, (w2, h2), interpolation=cv2.INTER_LINEAR)
    return out


def canvas_matrix(cam: CameraModel) -> FloatArray:
    """The ideal pinhole of the canvas: ``K`` scaled by :data:`SUPERSAMPLE`, pixel centres kept
    (a sensor pixel's centre ``u`` is the canvas's ``ss u + (ss − 1)/2``)."""
    ss = SUPERSAMPLE
    k2 = cam.matrix.copy()
    k2[:2] *= ss
    k2[0, 2] += (ss - 1) / 2
    k2[1, 2] += (ss - 1) / 2
    return k2


def expose(
    canvas: NDArray[Any],
    cam: CameraModel,
    rng: np.random.Generator,
    *,
    blur_px: float,
    noise: float,
    exposure: float,
) -> NDArray[np.uint8]:
    """The sensor's image of the ideal ``canvas``: the lens's blur and each pixel's area (a box
    of 1 px: variance 1/12 px²) act on the image before the sensor samples it through the lens
    distortion; then exposure and noise (read noise ``noise`` and shot noise, grey levels)."""
    ss = SUPERSAMPLE
    psf_px = float(np.sqrt(max(blur_px, 0.0) ** 2 + 1.0 / 12.0))
    canvas = cv2.GaussianBlur(canvas, (0, 0), ss * psf_px)
    mx, my = _distortion_map(cam, ss)
    img = cv2.remap(canvas, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    img = img * exposure
    sigma = np.sqrt(noise**2 + 0.02 * np.clip(img, 0, None))
    img = img + rng.standard_normal(img.shape, dtype=np.float32) * sigma
    return np.clip(np.round(img), 0, 255).astype(np.uint8)


def _look_at(
    eye: FloatArray,
    target: FloatArray,
    rng: np.random.Generator,
    across: FloatArray | None = None,
) -> tuple[FloatArray, FloatArray]:
    """The camera at ``eye`` looking at ``target``: ``X_c = r X + t``. Its image x axis lies
    along ``across`` turned by a roll of ±15° (a photographer turns the camera to frame two
    bodies side by side), or at a random roll without it."""
    z = target - eye
    z /= np.linalg.norm(z)
    if across is not None and np.linalg.norm(np.cross(z, across)) > 1e-9:
        x0 = across - np.dot(across, z) * z
        x0 /= np.linalg.norm(x0)
        roll = np.radians(rng.uniform(-15.0, 15.0)) + (np.pi if rng.uniform() < 0.5 else 0.0)
        x = np.cos(roll) * x0 + np.sin(roll) * np.cross(z, x0)
    else:
        x = np.cross(z, rng.normal(size=3))
        x /= np.linalg.norm(x)
    y = np.cross(z, x)
    r = np.array([x, y, z])
    return r, -r @ eye


def write_jpeg(
    path: Path, img: NDArray[np.uint8], cam: CameraModel | None, quality: int = 95
) -> None:
    """JPEG with the EXIF a camera writes (make, model, focal length and its 35 mm
    equivalent); ``cam=None`` writes none."""
    from PIL import Image

    im = Image.fromarray(img)
    if cam is None:
        im.save(path, quality=quality)
        return
    exif = Image.Exif()
    exif[0x010F] = "dimacq virtual lab"
    exif[0x0110] = "simulated camera"
    sensor_w_mm = 7.2
    sub = exif.get_ifd(0x8769)
    sub[0x920A] = round(cam.f_px / cam.width * sensor_w_mm, 2)
    sub[0xA405] = round(cam.f_px / cam.width * 36.0)
    im.save(path, quality=quality, exif=exif)


def camera_for(world: TaggedWorld) -> CameraModel:
    """The lab's camera for an article of the world's size: the 2 MP machine-vision camera
    (:class:`CameraModel`'s defaults, 1600 × 1200 px, ``f`` 1450 px) for a tagged region up to
    :data:`LARGE_ARTICLE_M` across, a 12 MP phone camera's main lens (:data:`PHONE_12MP`,
    4000 × 3000 px, ``f`` 2900 px: 26 mm equivalent) beyond, where the 2 MP camera's overviews
    would leave the block tags too few pixels."""
    if float(np.max(world.extent_m)) > LARGE_ARTICLE_M:
        return PHONE_12MP
    return CameraModel()


def _bodies(
    world: TaggedWorld,
) -> tuple[dict[str, FloatArray], dict[str, FloatArray], dict[str, FloatArray]]:
    """Where each body is (its tags' mean centre, m), which way its visible tags face (their
    outward normals, one row each) and which way it faces away from the article (the outward
    normal opposite its mounting face; its visible normals' mean without one): what a
    photographer sees of the article."""
    centres: dict[str, list[FloatArray]] = {}
    normals: dict[str, list[FloatArray]] = {}
    mounts: dict[str, FloatArray] = {}
    for t in world.tags:
        centres.setdefault(t.body, []).append(t.centre_m)
        if t.hidden:
            mounts[t.body] = t.rotation[:, 2]
        else:
            normals.setdefault(t.body, []).append(t.rotation[:, 2])
    out: dict[str, FloatArray] = {}
    for b, n in normals.items():
        away = -mounts[b] if b in mounts else np.mean(n, axis=0)
        out[b] = away / max(float(np.linalg.norm(away)), 1e-12)
    return (
        {b: np.mean(c, axis=0) for b, c in centres.items()},
        {b: np.array(n) for b, n in normals.items()},
        out,
    )


def _between_faces(
    normals: FloatArray, away: FloatArray, blockers: Callable[[FloatArray], int]
) -> list[FloatArray]:
    """Directions from which a body shows two or three of its tags together: the sums of the
    outward normals ``n_i + n_j (+ n_k)`` of mutually perpendicular visible faces, normalised;
    those at or above the floor limit (``z ≥`` :data:`FLOOR_Z`), not into the article
    (``d · away > −0.2``), from which the article does not hide the body and, of those, the
    ones the fewest other bodies stand in front of (``blockers``: their count,
    :data:`HIDDEN` when the article hides it). The edges (two tags at 45°) and the corners
    (three at 55°). The face most away from the article within the floor limit when none."""
    k = len(normals)
    perp = np.abs(normals @ normals.T) < 0.5
    cands = []
    for i in range(k):
        for j in range(i + 1, k):
            if not perp[i, j]:
                continue
            cands.append(normals[i] + normals[j])
            cands.extend(
                normals[i] + normals[j] + normals[m]
                for m in range(j + 1, k)
                if perp[i, m] and perp[j, m]
            )
    units = [d / np.linalg.norm(d) for d in cands]
    units = [u for u in units if u[2] >= FLOOR_Z and np.dot(u, away) > -0.2]
    scored = [(blockers(u), u) for u in units]
    scored = [(n, u) for n, u in scored if n < HIDDEN]
    if scored:
        least = min(n for n, _ in scored)
        return [u for n, u in scored if n == least]
    faces = [n for n in normals if n[2] >= FLOOR_Z] or [normals[int(np.argmax(normals[:, 2]))]]
    return [max(faces, key=lambda n: float(np.dot(n, away)))]


def _scatter(d: FloatArray, deg: float, rng: np.random.Generator) -> FloatArray:
    """``d`` turned by up to ``deg`` about a random axis across it (uniform over the cone),
    then raised to the floor limit if it fell below it."""
    axis = np.cross(d, rng.normal(size=3))
    axis /= np.linalg.norm(axis)
    ang = np.radians(deg) * np.sqrt(rng.uniform())
    out: FloatArray = Rotation.from_rotvec(ang * axis).apply(d)
    if out[2] < FLOOR_Z:
        flat = np.array([out[0], out[1], 0.0])
        n = np.linalg.norm(flat)
        flat = flat / n if n > 1e-9 else np.array([1.0, 0.0, 0.0])
        out = np.sqrt(1 - FLOOR_Z**2) * flat + np.array([0.0, 0.0, FLOOR_Z])
    return out


def _frame_neighbour(
    name: str,
    d: FloatArray,
    dist: tuple[float, float],
    cam: CameraModel,
    world: TaggedWorld,
    centres: dict[str, FloatArray],
    normals: dict[str, FloatArray],
    rng: np.random.Generator,
) -> tuple[FloatArray, FloatArray, FloatArray | None]:
    """Camera position, aim and the image's long axis for a close-up of ``name`` seen from
    direction ``d`` (the camera at ``p + D d``, ``D`` drawn in the close-up band
    ``dist = (near, far)``) that frames another tagged body with it: the camera aimed between
    the two (the bisector of their directions), pulled back within the band if both need it
    (each inside 40 % of the frame's width from its centre). The other body is one whose tags
    face the camera within 60° and that the article hides from neither camera (the segment to
    each body's centre, stood off by half a tag towards the camera): a triax block, reference
    plate or the scale bar before an impact jig, one of the three nearest. With none within
    reach, the body alone from ``D``."""
    p = centres[name]
    d_draw = rng.uniform(*dist)
    box = world.occluder_box
    stand = 0.5 * min(t.side_m for t in world.tags if t.body == name)
    half = np.arctan(0.4 * cam.width / cam.f_px)  # half the angle two framed bodies may span
    options = []
    for other, c in centres.items():
        if other == name or other not in normals:
            continue
        for dd in np.linspace(d_draw, max(d_draw, dist[1]), 4):
            eye = p + dd * d
            up, uc = (p - eye) / dd, (c - eye) / np.linalg.norm(c - eye)
            if np.arccos(np.clip(np.dot(up, uc), -1, 1)) <= 2 * half:
                break
        else:
            continue
        if np.max(normals[other] @ -uc) < np.cos(np.radians(60.0)):
            continue
        if box is not None and (
            _segment_hits_box(eye, c - stand * uc, *box)
            or _segment_hits_box(eye, p - stand * up, *box)
        ):
            continue
        options.append((other.startswith("input"), float(np.linalg.norm(c - p)), eye, up + uc))
    if not options:
        return p + d_draw * d, p, None
    options.sort(key=lambda o: (o[0], o[1]))
    pool = [o for o in options if o[0] == options[0][0]][:3]
    _, _, eye, mid = pool[int(rng.integers(0, len(pool)))]
    target = eye + mid / np.linalg.norm(mid) * float(np.linalg.norm(p - eye))
    return eye, target, target - p


def _round(names: list[str], rng: np.random.Generator) -> list[str]:
    """One round of close-ups: each triax block :data:`TRIAX_VIEWS` times (every block's
    ``k``-th close-up before any block's ``k + 1``-th, a fresh order each pass), each impact jig
    once, the two interleaved evenly, so that a set cut short leaves no block with fewer
    close-ups than another but one."""
    blocks = [n for n in names if n.startswith("triax")]
    jigs = [n for n in names if not n.startswith("triax")]
    tri = [blocks[k] for _ in range(TRIAX_VIEWS) for k in rng.permutation(len(blocks))]
    jig = [jigs[k] for k in rng.permutation(len(jigs))]
    n = len(tri) + len(jig)
    out, a, b = [], 0, 0
    for i in range(n):
        if b >= len(jig) or (a < len(tri) and a * n <= i * len(tri)):
            out.append(tri[a])
            a += 1
        else:
            out.append(jig[b])
            b += 1
    return out


@dataclass(frozen=True)
class Shot:
    """One photo of the plan: ``overview`` or ``close-up`` of ``body``, the camera at
    ``X_c = r_wc X + t_wc``."""

    kind: str
    body: str | None
    r_wc: FloatArray
    t_wc: FloatArray


def _blockers_of(
    b: str, centres: dict[str, FloatArray], sides: dict[str, float], world: TaggedWorld
) -> Callable[[FloatArray], int]:
    """How many bodies stand in front of body ``b`` seen from direction ``u`` (their centre
    within ``0.75 (s_b + s_other)`` of the line of sight), :data:`HIDDEN` when the article
    (the world's occluder box) hides it: what a photographer sees before taking the photo."""
    start = centres[b]
    stand = 0.75 * sides[b]
    box = world.occluder_box
    others = [(c, sides[o]) for o, c in centres.items() if o != b]

    def blockers(u: FloatArray) -> int:
        if box is not None and _segment_hits_box(start + stand * u, start + 0.5 * u, *box):
            return HIDDEN
        n = 0
        for c, side in others:
            along = float(np.dot(c - start, u))
            gap = float(np.linalg.norm(c - start - along * u))
            n += int(along > 0 and gap < 0.75 * (sides[b] + side))
        return n

    return blockers


def _shots(
    world: TaggedWorld,
    n_photos: int,
    rng: np.random.Generator,
    cam: CameraModel,
    distance_m: tuple[float, float] | None,
) -> Iterator[Shot]:
    """The plan's photos one after the other (see :func:`photograph_article`), drawn from
    ``rng``."""
    ext = float(np.max(world.extent_m))
    sides = {t.body: t.side_m for t in world.tags}
    centres, normals, away = _bodies(world)
    names = sorted(b for b in centres if b.startswith(("triax", "input")) and b in normals)
    blockers = {b: _blockers_of(b, centres, sides, world) for b in names}
    views = {b: _between_faces(normals[b], away[b], blockers[b]) for b in names}
    used = {b: np.zeros(len(views[b]), int) for b in names}
    last: dict[str, FloatArray] = {}
    small = min((sides[b] for b in names if b.startswith("triax")), default=max(sides.values()))
    queue: list[str] = []
    for i in range(n_photos):
        across: FloatArray | None = None
        name: str | None = None
        if i % 3 == 0 or not names:
            u = rng.uniform(-1.0, 1.0, 3)
            dist = min(cam.f_px * small / rng.uniform(30, 45), rng.uniform(2.2, 2.8) * ext)
            # aimed so that the frame keeps as much of the tagged region as it can: anywhere
            # along a region longer than the frame, near its middle across one that fits
            keep = 0.4 * cam.height / cam.f_px * dist
            slack = np.maximum(0.5 * world.extent_m - keep, 0.1 * 0.5 * world.extent_m)
            target = world.centre_m + u * slack
            d = rng.normal(size=3)
            d[2] = abs(d[2]) * 0.8 - 0.25
            d = _scatter(d / np.linalg.norm(d), 0.0, rng)
            eye = target + d * dist
        else:
            if not queue:
                queue = _round(names, rng)
            name = queue.pop(0)
            prev = last.get(name)
            far = [0.0 if prev is None else -float(np.dot(v, prev)) for v in views[name]]
            k = min(range(len(views[name])), key=lambda j: (used[name][j], -far[j], rng.uniform()))
            used[name][k] += 1
            last[name] = views[name][k]
            worst = blockers[name](views[name][k])
            for _try in range(20):  # nor through the article, nor past more bodies than planned
                d = _scatter(views[name][k], AIM_SCATTER_DEG, rng)
                if blockers[name](d) <= worst:
                    break
            else:
                d = views[name][k]
            band = distance_m or (cam.f_px * sides[name] / 110, cam.f_px * sides[name] / 60)
            eye, target, across = _frame_neighbour(name, d, band, cam, world, centres, normals, rng)
            target = target + rng.normal(scale=0.2 * sides[name], size=3)
        r, t = _look_at(eye, target, rng, across)
        yield Shot("overview" if name is None else "close-up", name, r, t)


def photo_plan(
    world: TaggedWorld,
    n_photos: int,
    seed: int,
    cam: CameraModel | None = None,
    *,
    distance_m: tuple[float, float] | None = None,
) -> list[Shot]:
    """The shots of the plan :func:`photograph_article` follows, without the photos (drawn
    from ``seed`` alone, so not the poses of that function's photos of the same seed, whose
    rendering draws from the same generator)."""
    cam = cam or camera_for(world)
    return list(_shots(world, n_photos, np.random.default_rng(seed), cam, distance_m))


def photograph_article(
    world: TaggedWorld,
    out_dir: str | Path,
    n_photos: int,
    seed: int,
    cam: CameraModel | None = None,
    *,
    distance_m: tuple[float, float] | None = None,
    family: str = "DICT_APRILTAG_36h11",
    exif: bool = True,
    suffix: str = ".jpg",
) -> list[Path]:
    """Write ``n_photos`` photos of ``world`` into ``out_dir``, as the manual's photo plan says.

    The camera is ``cam`` or the one :func:`camera_for` gives the article. Every third photo is
    an overview from a random direction of the hemisphere above the floor limit, from where the
    triax blocks' tags span 30–45 px (``f × side / 30…45``; at most 2.8 × the region's largest
    extent away), aimed at a random point of the tagged region that keeps as much of it in the
    frame as it can (within 40 % of the frame's height of its centre, or 10 % of the region's
    half-extent if that is more). The others are
    close-ups in rounds (:func:`_round`: each triax block :data:`TRIAX_VIEWS` times, each impact
    jig once), from where the body's tags span 60–110 px (``distance_m`` overrides): from
    between its visible faces (:func:`_between_faces`; each body's directions in turn, the least
    used first and the farthest from its last), turned by an aiming scatter of up to
    :data:`AIM_SCATTER_DEG` (drawn again, up to 20 times, while the article hides the body or
    more bodies stand in front of it than on the planned direction), the camera on that
    direction from the body and aimed between it and a neighbouring tagged body where one is
    within reach (:func:`_frame_neighbour`). Each photo has its own blur (0.4–1.1 px), exposure
    (0.7–1.3), noise and occluders.
    """
    cam = cam or camera_for(world)
    rng = np.random.default_rng(seed)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = []
    for i, shot in enumerate(_shots(world, n_photos, rng, cam, distance_m)):
        r, t = shot.r_wc, shot.t_wc
        img = render(
            world,
            cam,
            r,
            t,
            rng,
            family=family,
            blur_px=float(rng.uniform(0.4, 1.1)),
            exposure=float(rng.uniform(0.7, 1.3)),
            occluders=int(rng.integers(0, 3)),
        )
        p = out / f"IMG_{i:04d}{suffix}"
        if suffix.lower() in (".jpg", ".jpeg"):
            write_jpeg(p, img, cam if exif else None)
        else:
            cv2.imwrite(str(p), img)
        paths.append(p)
    return paths
