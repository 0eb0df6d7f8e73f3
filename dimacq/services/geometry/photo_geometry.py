"""Geometry from photographs: fiducial tags detected by OpenCV, a bundle adjustment, and the
triaxes' and inputs' geometry as the digitizing chain records it.

Steps (:func:`geometry_from_photos`): read each photo of a folder (its EXIF focal length, or a
camera file), detect the tags of the family the tags file names
(``cv2.aruco.ArucoDetector``, corners refined to sub-pixel), name every photo that cannot help
and why (unreadable, blurred, no tags, tags of another family, one tag only, another image
size), chain first poses from the reference plates outwards (``cv2.solvePnP`` per tag and per
photo), then adjust everything together (:func:`dimacq.pipeline.photogrammetry.bundle.adjust`,
the intrinsics refined unless a camera file fixes them). Each triax and input becomes an
:class:`~dimacq.services.geometry.records.Orientation` or
:class:`~dimacq.services.geometry.records.LineOfAction` record with its standard
uncertainty (the adjustment's covariance ⊕ the tags' placement on their bodies), the records a
digitized setup is built from (:func:`dimacq.services.geometry.geometry_trust.geometry_uncertainty`).

A body whose tags are seen in fewer than :data:`MIN_VIEWS` photos is not fixed: the result
names it and how many more photos it needs.
"""

from __future__ import annotations

import logging
import tomllib
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from dimacq.errors import DataError, SetupError
from dimacq.io.tags_file import TagsFile
from dimacq.io.validation import refuse
from dimacq.model.setup import TestSetup
from dimacq.pipeline.photogrammetry.bundle import (
    BodyEstimate,
    BodyModel,
    BundleResult,
    Observation,
    adjust,
)
from dimacq.pipeline.photogrammetry.camera import Intrinsics, tag_corners, undistort_normalised
from dimacq.services.geometry.geometry_trust import geometry_uncertainty
from dimacq.services.geometry.records import LineOfAction, Orientation

__all__ = [
    "MIN_VIEWS",
    "PHOTO_SUFFIXES",
    "PhotoGeometry",
    "PhotoIssue",
    "apply_to_setup",
    "detect_tags",
    "geometry_from_photos",
    "load_camera",
]

log = logging.getLogger(__name__)
FloatArray = NDArray[np.float64]

#: Photos a triax or input's tags must be seen in for its pose to count as fixed.
MIN_VIEWS = 3
PHOTO_SUFFIXES = (".jpg", ".jpeg", ".png", ".tif", ".tiff", ".bmp")
#: Tag views more oblique than this (angle between the tag's normal and the line of sight)
#: are left out of the adjustment.
MAX_INCIDENCE_DEG = 65.0
#: Variance of the Laplacian below which a photo without tags is called blurred.
BLUR_LIMIT = 20.0
_OTHER_FAMILIES = (
    "DICT_4X4_250",
    "DICT_5X5_250",
    "DICT_6X6_250",
    "DICT_7X7_250",
    "DICT_ARUCO_ORIGINAL",
    "DICT_APRILTAG_16h5",
    "DICT_APRILTAG_25h9",
    "DICT_APRILTAG_36h10",
    "DICT_APRILTAG_36h11",
)


# ------------------------------------------------------------------------------ camera file
class _CameraFile(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)
    schema_version: int = 1
    fx: float = Field(gt=0, description="focal length along x, pixels")
    fy: float = Field(gt=0, description="focal length along y, pixels")
    cx: float = Field(description="principal point x, pixels")
    cy: float = Field(description="principal point y, pixels")
    k1: float = 0.0
    k2: float = 0.0
    p1: float = 0.0
    p2: float = 0.0
    k3: float = 0.0
    width: int = Field(gt=0, description="image width the calibration holds for, pixels")
    height: int = Field(gt=0, description="image height, pixels")
    refine: bool = Field(
        default=False, description="refine the intrinsics in the adjustment (default: fixed)"
    )


def load_camera(path: str | Path) -> tuple[Intrinsics, bool]:
    """A camera file (TOML: ``fx, fy, cx, cy`` px, ``k1, k2, p1, p2, k3``, ``width, height``,
    ``refine``): the intrinsics and whether the adjustment may refine them."""
    p = Path(path)
    try:
        data = tomllib.loads(p.read_text(encoding="utf-8"))
    except FileNotFoundError as err:
        raise SetupError(f"camera file {p}: not found; give the path of the camera file") from err
    except tomllib.TOMLDecodeError as err:
        raise SetupError(f"camera file {p}: not valid TOML ({err}); fix the syntax") from err
    try:
        cam = _CameraFile.model_validate(data)
    except ValidationError as err:
        raise refuse(
            "camera file", str(p), err, _CameraFile, "see dimacq/manual/photo-geometry.md"
        ) from err
    d = cam.model_dump()
    refine = bool(d.pop("refine"))
    d.pop("schema_version")
    return Intrinsics(**d), refine


# ------------------------------------------------------------------------------ results
@dataclass(frozen=True)
class PhotoIssue:
    """A photo (or a body) that could not help fully: what is wrong and the fix."""

    photo: str
    severity: str  # "skipped" (not used) or "warn" (used)
    problem: str
    fix: str

    def to_json(self) -> dict[str, str]:
        return {
            "photo": self.photo,
            "severity": self.severity,
            "problem": self.problem,
            "fix": self.fix,
        }

    def __str__(self) -> str:
        return f"{self.photo}: {self.problem}; {self.fix}"


@dataclass(frozen=True)
class PhotoGeometry:
    """What the photographs give: the records, the adjustment and every issue met."""

    orientations: list[Orientation]
    lines_of_action: list[LineOfAction]
    bodies: list[BodyEstimate]
    bundle: BundleResult
    photos: list[str]
    used: list[str]
    issues: list[PhotoIssue]
    unfixed: list[str]
    intrinsics_source: str
    setup: TestSetup | None = None
    counts: dict[str, int] = field(default_factory=dict)

    @property
    def verdict(self) -> str:
        return "fail" if self.unfixed else ("warn" if self.issues else "ok")

    def to_json(self) -> dict[str, Any]:
        from dimacq.io.setup_file import dump_setup_dict

        b = self.bundle
        return {
            "schema_version": 1,
            "source": "photographs",
            "verdict": self.verdict,
            "orientations": [o.to_json() for o in self.orientations],
            "lines_of_action": [a.to_json() for a in self.lines_of_action],
            "references": [
                {
                    "name": e.name,
                    "position_m": [float(v) for v in e.position_m],
                    "position_std_m": [float(v) for v in e.position_std_m],
                }
                for e in self.bodies
                if e.kind in ("reference", "scalebar")
            ],
            "unfixed": list(self.unfixed),
            "issues": [i.to_json() for i in self.issues],
            "photos": {"found": len(self.photos), "used": len(self.used), "names": self.used},
            "camera": {
                "intrinsics": b.intrinsics.to_json(),
                "intrinsics_std": None if b.intrinsics_std is None else b.intrinsics_std.tolist(),
                "source": self.intrinsics_source,
            },
            "adjustment": {
                "sigma_px": b.sigma_px,
                "rms_px": b.rms_px,
                "corners": b.n_corners,
                "parameters": b.n_parameters,
                "evaluations": b.nfev,
                "condition": b.condition,
                "rejected": [
                    {"photo": self.used[p] if p < len(self.used) else p, "tag": t, "rms_px": r}
                    for p, t, r in b.rejected
                ],
            },
            "setup": None if self.setup is None else dump_setup_dict(self.setup),
        }


# ------------------------------------------------------------------------------ detection
def _cv2() -> Any:
    try:
        import cv2
    except ImportError as err:  # pragma: no cover - a dependency of the package
        raise SetupError(
            "geometry from photos needs OpenCV: pip install opencv-python-headless"
        ) from err
    return cv2


def _dictionary(family: str) -> Any:
    cv2 = _cv2()
    code = getattr(cv2.aruco, family, None)
    if not isinstance(code, int):
        raise SetupError(
            f"tag family {family!r} is not an OpenCV ArUco dictionary; use e.g. "
            "DICT_APRILTAG_36h11 or DICT_4X4_50"
        )
    return cv2.aruco.getPredefinedDictionary(code)


def refine_corners_by_edges(img: FloatArray, corners: FloatArray, cells: int) -> FloatArray:
    """Corners as the intersections of the tag's four outer edges, each a line fitted to
    sub-pixel edge points.

    Along each side, away from the corners, the intensity profile across the edge (bilinear,
    ±0.4 cell) is located where it crosses the mean of its outer (white margin) and inner (black
    border) levels: under a symmetric blur that is the edge itself, whereas the corner of a
    blurred square, which ``cornerSubPix`` finds, lies inside it (0.2–0.4 px for a blur of
    0.4–1.1 px). The lines are fitted by total least squares and intersected. A side with too
    few edge points keeps the detector's corners.
    """
    from scipy.ndimage import map_coordinates

    c = np.asarray(corners, float)
    centre = c.mean(axis=0)
    lines = []
    for k in range(4):
        a, b = c[k], c[(k + 1) % 4]
        side = float(np.linalg.norm(b - a))
        if side < 8:
            return c
        t_dir = (b - a) / side
        n = np.array([-t_dir[1], t_dir[0]])
        if np.dot(n, 0.5 * (a + b) - centre) < 0:
            n = -n  # outward
        half = max(1.0, 0.4 * side / cells)
        ts = np.linspace(0.15, 0.85, max(6, int(side / 2)))
        offs = np.linspace(-half, half, max(7, int(4 * half) + 1))
        base = a[None, :] + ts[:, None] * (b - a)[None, :]
        pts = base[:, None, :] + offs[None, :, None] * n[None, None, :]
        prof = map_coordinates(
            img, [pts[..., 1].ravel(), pts[..., 0].ravel()], order=1, mode="nearest"
        ).reshape(len(ts), len(offs))
        inner = prof[:, :2].mean(axis=1)
        outer = prof[:, -2:].mean(axis=1)
        mid = 0.5 * (inner + outer)
        edge = []
        for j in np.flatnonzero((outer - inner) > 20.0):
            above = np.flatnonzero(prof[j] >= mid[j])
            if not len(above) or above[0] == 0:
                continue
            q = above[0]
            p0, p1 = prof[j, q - 1], prof[j, q]
            f = (mid[j] - p0) / (p1 - p0) if p1 != p0 else 0.5
            edge.append(base[j] + (offs[q - 1] + f * (offs[q] - offs[q - 1])) * n)
        if len(edge) < 4:
            return c
        e = np.array(edge)
        m = e.mean(axis=0)
        _, _, vt = np.linalg.svd(e - m)
        lines.append((m, vt[0]))
    out = np.empty((4, 2))
    for k in range(4):
        (p1_, d1), (p2_, d2) = lines[(k - 1) % 4], lines[k]
        a_mat = np.column_stack([d1, -d2])
        if abs(np.linalg.det(a_mat)) < 1e-6:
            return c
        s_ = np.linalg.solve(a_mat, p2_ - p1_)
        out[k] = p1_ + s_[0] * d1
    if np.max(np.linalg.norm(out - c, axis=1)) > 2.0:
        return c
    return out


def detect_tags(
    gray: NDArray[np.uint8], family: str = "DICT_APRILTAG_36h11", *, refine_edges: bool = True
) -> dict[int, FloatArray]:
    """Tags of ``family`` in a grey image: id → four corners in pixels (OpenCV's order:
    top-left, top-right, bottom-right, bottom-left of the printed tag), refined to sub-pixel
    by ``cornerSubPix`` and then, with ``refine_edges``, as the intersections of the fitted
    outer edges (:func:`refine_corners_by_edges`). A tag id seen twice in one photo is dropped
    (it cannot be told apart)."""
    cv2 = _cv2()
    params = cv2.aruco.DetectorParameters()
    params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    params.cornerRefinementWinSize = 4
    params.cornerRefinementMaxIterations = 60
    params.cornerRefinementMinAccuracy = 0.005
    det = cv2.aruco.ArucoDetector(_dictionary(family), params)
    corners, ids, _rej = det.detectMarkers(gray)
    out: dict[int, FloatArray] = {}
    dup: set[int] = set()
    if ids is None:
        return out
    img = np.asarray(gray, dtype=np.float64)
    cells = int(det.getDictionary().markerSize) + 2
    for c, i in zip(corners, ids.ravel(), strict=True):
        k = int(i)
        if k in out:
            dup.add(k)
        c4 = np.asarray(c, float).reshape(4, 2)
        out[k] = refine_corners_by_edges(img, c4, cells) if refine_edges else c4
    for k in dup:
        del out[k]
    return out


def _exif_focal_px(path: Path, width: int, height: int) -> float | None:
    """Focal length in pixels from EXIF ``FocalLengthIn35mmFilm`` (36 mm wide frame), else
    None."""
    try:
        from PIL import Image
    except ImportError:  # pragma: no cover
        return None
    try:
        with Image.open(path) as im:
            exif = im.getexif()
            sub = exif.get_ifd(0x8769)
    except OSError:
        return None
    f35 = sub.get(0xA405) or exif.get(0xA405)
    if not f35:
        return None
    return float(f35) / 36.0 * max(width, height)


# ------------------------------------------------------------------------------ the chain
@dataclass
class _Photo:
    name: str
    size: tuple[int, int]
    tags: dict[int, FloatArray]
    focal_px: float | None


def _read_photos(
    paths: Sequence[Path], family: str, known: set[int], say: Callable[[str], None]
) -> tuple[list[_Photo], list[PhotoIssue]]:
    cv2 = _cv2()
    photos: list[_Photo] = []
    issues: list[PhotoIssue] = []
    size0: tuple[int, int] | None = None
    for k, path in enumerate(paths):
        gray = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
        if gray is None:
            issues.append(
                PhotoIssue(
                    path.name,
                    "skipped",
                    "not an image OpenCV can read",
                    "remove it or save it as JPEG/PNG",
                )
            )
            continue
        size = (int(gray.shape[1]), int(gray.shape[0]))
        if size0 is None:
            size0 = size
        if size != size0:
            issues.append(
                PhotoIssue(
                    path.name,
                    "skipped",
                    f"{size[0]}x{size[1]} px while the first photo is {size0[0]}x{size0[1]} px",
                    "take one set with one camera at one zoom and resolution",
                )
            )
            continue
        tags = detect_tags(gray, family)
        say(f"photo {k + 1}/{len(paths)} {path.name}: {len(tags)} tags")
        ours = {i: c for i, c in tags.items() if i in known}
        foreign = sorted(set(tags) - known)
        if not ours:
            issues.append(_why_no_tags(path.name, gray, family, foreign))
            continue
        if foreign:
            issues.append(
                PhotoIssue(
                    path.name,
                    "warn",
                    f"tag ids {foreign} are not in the tags file (ignored)",
                    "add them to the tags file if they belong to the test",
                )
            )
        if len(ours) == 1:
            issues.append(
                PhotoIssue(
                    path.name,
                    "warn",
                    f"shows one known tag only (id {next(iter(ours))})",
                    "a photo ties tags together: show each tag with at least one other",
                )
            )
        photos.append(_Photo(path.name, size, ours, _exif_focal_px(path, *size)))
    return photos, issues


def _why_no_tags(name: str, gray: NDArray[np.uint8], family: str, foreign: list[int]) -> PhotoIssue:
    cv2 = _cv2()
    if foreign:
        return PhotoIssue(
            name,
            "skipped",
            f"only tags {foreign} not in the tags file",
            "photograph the test's tags",
        )
    for other in _OTHER_FAMILIES:
        if other != family and len(detect_tags(gray, other)) >= 2:
            return PhotoIssue(
                name,
                "skipped",
                f"tags of family {other} seen, none of {family} (the tags file's family)",
                f'set family = "{other}" in the tags file, or print {family} tags',
            )
    sharp = float(cv2.Laplacian(gray, cv2.CV_64F).var())
    if sharp < BLUR_LIMIT:
        return PhotoIssue(
            name,
            "skipped",
            f"no tags found and the photo is blurred (sharpness {sharp:.0f} < {BLUR_LIMIT:.0f})",
            "hold the camera still, focus on the tags, use more light or a faster shutter",
        )
    return PhotoIssue(
        name,
        "skipped",
        "no tags found",
        "frame the tags, come closer (a tag should span at least 20 px) and avoid glare",
    )


def _pose_from_points(
    obj: FloatArray, xy: FloatArray, planar_square: bool
) -> tuple[FloatArray, FloatArray, float]:
    """(R, t, rms) of object points seen at normalised image points (camera matrix I)."""
    cv2 = _cv2()
    k = np.eye(3)
    if planar_square:
        _n, rs, ts, errs = cv2.solvePnPGeneric(
            obj.astype(np.float64), xy.astype(np.float64), k, None, flags=cv2.SOLVEPNP_IPPE_SQUARE
        )
        best = int(np.argmin(np.asarray(errs).ravel()))
        r, t, e = rs[best], ts[best], float(np.asarray(errs).ravel()[best])
    else:
        ok, r, t = cv2.solvePnP(
            obj.astype(np.float64), xy.astype(np.float64), k, None, flags=cv2.SOLVEPNP_SQPNP
        )
        if not ok:
            raise DataError("pose: solvePnP failed")
        ok, r, t = cv2.solvePnP(obj, xy, k, None, r, t, True, cv2.SOLVEPNP_ITERATIVE)
        proj, _ = cv2.projectPoints(obj, r, t, k, None)
        e = float(np.sqrt(np.mean((proj.reshape(-1, 2) - xy) ** 2)))
    return cv2.Rodrigues(r)[0], np.asarray(t, float).ravel(), e


def _initial_poses(
    models: list[BodyModel],
    photos: list[_Photo],
    intr: Intrinsics,
    say: Callable[[str], None],
) -> tuple[dict[int, tuple[FloatArray, FloatArray]], dict[int, tuple[FloatArray, FloatArray]]]:
    """First poses, chained from the reference plates: photos (world → camera) and bodies
    (body → world) that can be reached; the rest stay out."""
    mount = {t.tag_id: (i, t) for i, b in enumerate(models) for t in b.tags}
    norm = [
        {tid: undistort_normalised(c, intr) for tid, c in p.tags.items() if tid in mount}
        for p in photos
    ]
    bodies: dict[int, tuple[FloatArray, FloatArray]] = {
        i: (np.asarray(b.prior_rotation), np.asarray(b.prior_position_m))
        for i, b in enumerate(models)
        if b.prior_position_m is not None
    }
    cams: dict[int, tuple[FloatArray, FloatArray]] = {}
    while True:
        progress = False
        # photos that see placed bodies: pose from all their corners
        for c, obs in enumerate(norm):
            if c in cams:
                continue
            pts_w, pts_xy = [], []
            for tid, xy in obs.items():
                bi, t = mount[tid]
                if bi in bodies:
                    rb, pb = bodies[bi]
                    pts_w.append(t.corners_body() @ rb.T + pb)
                    pts_xy.append(xy)
            if not pts_w:
                continue
            w, xy = np.concatenate(pts_w), np.concatenate(pts_xy)
            if len(pts_w) == 1:  # one tag: its own square solution, mapped to the world
                tid = next(t for t in obs if mount[t][0] in bodies)
                bi, t = mount[tid]
                r_ct, t_ct, _ = _pose_from_points(tag_corners(t.side_m), obs[tid], True)
                rb, pb = bodies[bi]
                r_wt = rb @ t.rotation
                p_wt = rb @ t.offset_m + pb
                rc = r_ct @ r_wt.T
                cams[c] = (rc, t_ct - rc @ p_wt)
            else:
                rc, tc, _ = _pose_from_points(w, xy, False)
                cams[c] = (rc, tc)
            progress = True
        # bodies seen by placed photos: from the photo where their tags look largest
        for bi, b in enumerate(models):
            if bi in bodies:
                continue
            best: tuple[float, int] | None = None
            for c in cams:
                seen = [t for t in b.tags if t.tag_id in norm[c]]
                if seen:
                    area = sum(_area(photos[c].tags[t.tag_id]) for t in seen)
                    if best is None or area > best[0]:
                        best = (area, c)
            if best is None:
                continue
            c = best[1]
            seen = [t for t in b.tags if t.tag_id in norm[c]]
            if len(seen) == 1:
                t = seen[0]
                r_ct, t_ct, _ = _pose_from_points(tag_corners(t.side_m), norm[c][t.tag_id], True)
                r_cb = r_ct @ t.rotation.T
                t_cb = t_ct - r_cb @ t.offset_m
            else:
                obj = np.concatenate([t.corners_body() for t in seen])
                xy = np.concatenate([norm[c][t.tag_id] for t in seen])
                r_cb, t_cb, _ = _pose_from_points(obj, xy, False)
            rc, tc = cams[c]
            bodies[bi] = (rc.T @ r_cb, rc.T @ (t_cb - tc))
            progress = True
        if not progress:
            break
    say(f"first poses: {len(cams)} of {len(photos)} photos, {len(bodies)} of {len(models)} bodies")
    return cams, bodies


def _area(c: FloatArray) -> float:
    x, y = c[:, 0], c[:, 1]
    return 0.5 * abs(float(np.dot(x, np.roll(y, 1)) - np.dot(y, np.roll(x, 1))))


def geometry_from_photos(
    photos_dir: str | Path,
    tags: TagsFile,
    *,
    setup: TestSetup | None = None,
    camera: tuple[Intrinsics, bool] | None = None,
    progress: Callable[[str], None] | None = None,
) -> PhotoGeometry:
    """Triax orientations and lines of action from the photos in ``photos_dir``.

    Parameters
    ----------
    photos_dir : path
        A folder of photos (JPEG, PNG, TIFF), one camera at one zoom.
    tags : TagsFile
    setup : TestSetup, optional
        The setup to put the geometry into (:func:`apply_to_setup`); its triax and input nodes
        without tags are named in ``unfixed``.
    camera : (Intrinsics, refine), optional
        A camera file's intrinsics (:func:`load_camera`); default: the photos' EXIF focal
        length, principal point at the image centre, no distortion, all refined.
    progress : callable (message), optional

    Raises
    ------
    DataError
        No usable photo, no focal length (EXIF-less photos and no camera file), or no reference
        plate seen: the message names the photos and the fix.
    """
    say = progress or (lambda _m: None)
    folder = Path(photos_dir)
    if not folder.is_dir():
        raise SetupError(f"photos folder {folder}: not a folder; give the folder of the photos")
    paths = sorted(p for p in folder.iterdir() if p.suffix.lower() in PHOTO_SUFFIXES)
    if not paths:
        raise DataError(
            f"photos folder {folder}: no photos ({', '.join(PHOTO_SUFFIXES)}); copy the photos there"
        )
    models = tags.body_models()
    known = {t.tag_id for b in models for t in b.tags}
    photos, issues = _read_photos(paths, tags.family, known, say)
    if not photos:
        raise DataError(
            f"photos folder {folder}: none of {len(paths)} photos shows a tag of the tags file: "
            + "; ".join(str(i) for i in issues[:5])
        )
    w, h = photos[0].size
    if camera is not None:
        intr, refine = camera
        if (intr.width, intr.height) != (w, h):
            raise SetupError(
                f"camera file is for {intr.width}x{intr.height} px, the photos are {w}x{h} px; "
                "calibrate the camera at the photos' resolution"
            )
        source = "camera file"
    else:
        focals = [p.focal_px for p in photos if p.focal_px]
        if not focals:
            raise DataError(
                f"{len(photos)} photos carry no EXIF focal length (e.g. {photos[0].name}): give "
                "--camera CAM.toml (fx, fy, cx, cy in pixels from a calibration) or use the "
                "camera's original files, whose EXIF states the focal length"
            )
        no_exif = [p.name for p in photos if not p.focal_px]
        if no_exif:
            issues.append(
                PhotoIssue(
                    ", ".join(no_exif[:5]),
                    "warn",
                    f"{len(no_exif)} photos without EXIF focal length (the others' is used)",
                    "keep the camera's original files",
                )
            )
        f = float(np.median(focals))
        intr = Intrinsics(fx=f, fy=f, cx=(w - 1) / 2, cy=(h - 1) / 2, width=w, height=h)
        refine = True
        source = "EXIF focal length, refined in the adjustment"
    # bodies with too few views are not fixed
    views: dict[int, int] = {}
    for bi, b in enumerate(models):
        ids = {t.tag_id for t in b.tags}
        views[bi] = sum(1 for p in photos if ids & set(p.tags))
    unfixed = []
    for bi, b in enumerate(models):
        if b.kind in ("triax", "input") and views[bi] < MIN_VIEWS:
            id_list = sorted(t.tag_id for t in b.tags)
            need = MIN_VIEWS - views[bi]
            unfixed.append(
                f"{b.name}: its tags (ids {id_list[0]}–{id_list[-1]}) are seen in {views[bi]} photo(s); "
                f"take at least {need} more photo(s) showing them from other directions"
            )
    if setup is not None:
        have = {b.node for b in models if b.kind == "triax"}
        have_in = {b.node for b in models if b.kind == "input"}
        for n in sorted({ch.node for ch in setup.responses} - have):
            unfixed.append(f"triax {n}: no tags in the tags file; add its block to the tags file")
        for n in sorted({e.node for e in setup.excitations} - have_in):
            unfixed.append(f"input {n}: no tags in the tags file; add its jig to the tags file")
    for tid in sorted(known):
        n = sum(1 for p in photos if tid in p.tags)
        if n == 1:
            issues.append(
                PhotoIssue(
                    next(p.name for p in photos if tid in p.tags),
                    "warn",
                    f"tag {tid} is seen in this photo only",
                    "a tag seen once fixes nothing: show it in at least two more photos",
                )
            )
    use_bodies = [
        bi
        for bi, b in enumerate(models)
        if views[bi] >= (1 if b.kind in ("reference", "scalebar") else MIN_VIEWS)
    ]
    sub_models = [models[bi] for bi in use_bodies]
    cams, poses = _initial_poses(sub_models, photos, intr, say)
    if not any(sub_models[i].prior_position_m is not None for i in poses):
        raise DataError(
            "no reference plate is seen in any photo: the article's frame is not fixed; "
            "photograph the reference plates together with the triaxes and inputs"
        )
    for i, b in enumerate(sub_models):
        if i not in poses and b.kind in ("triax", "input"):
            unfixed.append(
                f"{b.name}: its tags are never seen in a photo with tags already tied to the "
                "reference plates; take photos showing it with its neighbours"
            )
    for c, p in enumerate(photos):
        if c not in cams:
            issues.append(
                PhotoIssue(
                    p.name,
                    "skipped",
                    "its tags are not tied to the reference plates by any other photo",
                    "take photos bridging these tags and the rest",
                )
            )
    cam_idx = sorted(cams)
    body_idx = sorted(poses)
    final_models = [sub_models[i] for i in body_idx]
    remap = {c: k for k, c in enumerate(cam_idx)}
    mount = {t.tag_id for b in final_models for t in b.tags}
    obs = [
        Observation(remap[c], tid, corners)
        for c in cam_idx
        for tid, corners in photos[c].tags.items()
        if tid in mount
    ]
    obs, oblique = _drop_oblique(
        obs, final_models, [cams[c] for c in cam_idx], [poses[i] for i in body_idx]
    )
    if oblique:
        say(f"{oblique} tag views more oblique than {MAX_INCIDENCE_DEG:g} deg left out")
    # photos and bodies left without a view are left out (nothing would fix them)
    seen_cams = sorted({o.photo for o in obs})
    tag_body = {t.tag_id: k for k, b in enumerate(final_models) for t in b.tags}
    seen_bodies = sorted({tag_body[o.tag_id] for o in obs})
    for k, b in enumerate(final_models):
        if k not in seen_bodies and b.kind in ("triax", "input"):
            unfixed.append(
                f"{b.name}: its tags are seen only edge-on (more than {MAX_INCIDENCE_DEG:g} deg "
                "from square on); take photos facing them"
            )
    cam_idx = [cam_idx[k] for k in seen_cams]
    cmap = {old: new_ for new_, old in enumerate(seen_cams)}
    body_idx = [body_idx[k] for k in seen_bodies]
    final_models = [sub_models[i] for i in body_idx]
    obs = [Observation(cmap[o.photo], o.tag_id, o.corners_px) for o in obs]
    say(f"adjusting {len(cam_idx)} photos, {len(final_models)} bodies, {4 * len(obs)} corners")
    bundle = adjust(
        final_models,
        obs,
        intr,
        [cams[c][0] for c in cam_idx],
        [cams[c][1] for c in cam_idx],
        [poses[i][0] for i in body_idx],
        [poses[i][1] for i in body_idx],
        refine_intrinsics=refine,
        progress=lambda n, cost: say(f"adjustment: {n} evaluations, cost {cost:.4g}"),
    )
    used = [photos[c].name for c in cam_idx]
    for k, r in enumerate(bundle.photo_rms_px):
        if np.isfinite(r) and r > 4 * max(bundle.sigma_px, 0.1):
            issues.append(
                PhotoIssue(
                    used[k],
                    "warn",
                    f"corner residual {r:.2f} px, {r / bundle.sigma_px:.1f} times the set's",
                    "motion blur or a tag misread: retake it",
                )
            )
    for k_photo, t, r in bundle.rejected:
        issues.append(
            PhotoIssue(
                used[k_photo],
                "warn",
                f"tag {t} left out as a gross error ({r:.1f} px)",
                "a tag partly hidden or misread: retake it",
            )
        )
    depth = float(np.median(np.linalg.norm(bundle.camera_translations, axis=1)))
    scale_m = bundle.sigma_px * depth / bundle.intrinsics.fx
    orientations, loas = _records(bundle, final_models, tags, scale_m)
    say(
        f"adjusted: σ {bundle.sigma_px:.3f} px, {len(orientations)} triaxes, {len(loas)} inputs, "
        f"{len(unfixed)} not fixed"
    )
    result = PhotoGeometry(
        orientations=orientations,
        lines_of_action=loas,
        bodies=list(bundle.bodies),
        bundle=bundle,
        photos=[p.name for p in paths],
        used=used,
        issues=issues,
        unfixed=unfixed,
        intrinsics_source=source,
        counts={"photos": len(paths), "used": len(used), "observations": len(obs)},
    )
    if setup is not None and not unfixed:
        result = replace(result, setup=apply_to_setup(setup, result))
    return result


def _drop_oblique(
    obs: list[Observation],
    models: list[BodyModel],
    cams: list[tuple[FloatArray, FloatArray]],
    poses: list[tuple[FloatArray, FloatArray]],
) -> tuple[list[Observation], int]:
    """The observations whose tag faces the camera within :data:`MAX_INCIDENCE_DEG` at the
    first poses (a tag seen edge-on has its corners located far less well)."""
    mount = {t.tag_id: (i, t) for i, b in enumerate(models) for t in b.tags}
    keep = []
    for o in obs:
        bi, t = mount[o.tag_id]
        rb, pb = poses[bi]
        rc, tc = cams[o.photo]
        centre = rc @ (rb @ t.offset_m + pb) + tc
        normal = rc @ rb @ t.rotation[:, 2]
        cos = -float(np.dot(normal, centre)) / float(np.linalg.norm(centre))
        if cos >= np.cos(np.radians(MAX_INCIDENCE_DEG)):
            keep.append(o)
    return keep, len(obs) - len(keep)


def _records(
    bundle: BundleResult, models: list[BodyModel], tags: TagsFile, residual_m: float
) -> tuple[list[Orientation], list[LineOfAction]]:
    """The adjusted bodies as the digitizing chain's records. The tags' placement on their body
    (1σ ``placement_*`` per tag) adds ``σ_place/√k`` over the ``k`` tags the body has."""
    ori, loas = [], []
    for est, model in zip(bundle.bodies, models, strict=True):
        k = max(len(model.tags), 1)
        pa = np.radians(tags.placement_angle_deg) / np.sqrt(k)
        pp = tags.placement_position_m / np.sqrt(k)
        cov_r = est.covariance[:3, :3] + pa**2 * np.eye(3)
        cov_p = est.covariance[3:, 3:] + pp**2 * np.eye(3)
        pos_std = float(np.sqrt(np.max(np.linalg.eigvalsh(cov_p))))
        if est.kind == "triax" and est.node is not None:
            axis_std = np.degrees(np.sqrt(np.diag(est.rotation.T @ cov_r @ est.rotation)))
            ori.append(
                Orientation(
                    node=est.node,
                    rotation=np.asarray(est.rotation).tolist(),
                    origin_m=[float(v) for v in est.position_m],
                    method="photos",
                    rods=[],
                    n_points=est.n_corners,
                    residual_rms_m=float(residual_m),
                    angle_std_deg=[float(v) for v in axis_std],
                    uncertainty_deg=float(np.degrees(np.sqrt(np.trace(cov_r)))),
                    jig_uncertainty_deg=float(
                        np.degrees(np.sqrt(np.trace(est.covariance[:3, :3])))
                    ),
                    registration_uncertainty_deg=None,
                    origin_std_m=pos_std,
                )
            )
        elif est.kind == "input" and est.node is not None:
            d = -est.rotation[:, 2]
            proj = np.eye(3) - np.outer(d, d)
            ang = float(np.degrees(np.sqrt(np.trace(proj @ cov_r @ proj))))
            fit = float(np.degrees(np.sqrt(np.trace(proj @ est.covariance[:3, :3] @ proj))))
            loas.append(
                LineOfAction(
                    node=est.node,
                    direction=[float(v) for v in d],
                    point_m=[float(v) for v in est.position_m],
                    method="photos",
                    perpendicular_rms_m=float(residual_m),
                    angle_std_deg=ang,
                    fit_angle_std_deg=fit,
                    registration_uncertainty_deg=None,
                    point_std_m=pos_std,
                )
            )
    return ori, loas


def apply_to_setup(setup: TestSetup, result: PhotoGeometry) -> TestSetup:
    """``setup`` with each photographed triax's channels and each input at the photographed
    geometry (a channel ``±k`` along ``±`` column ``k`` of the triax's rotation), and the
    geometry uncertainty the records state
    (:func:`dimacq.services.geometry.geometry_trust.geometry_uncertainty`), as a digitized setup."""
    ori = {o.node: o for o in result.orientations}
    loas = {a.node: a for a in result.lines_of_action}
    responses = []
    for ch in setup.responses:
        o = ori.get(ch.node)
        if o is None:
            responses.append(ch)
            continue
        r = np.asarray(o.rotation, float)
        sign = 1.0 if ch.direction > 0 else -1.0
        col = sign * r[:, abs(ch.direction) - 1]
        responses.append(
            ch.model_copy(
                update={
                    "position_m": tuple(o.origin_m),
                    "direction_gcs": tuple(float(v) for v in col / np.linalg.norm(col)),
                }
            )
        )
    excitations = []
    for e in setup.excitations:
        a = loas.get(e.node)
        if a is None:
            excitations.append(e)
            continue
        d = np.asarray(a.direction, float)
        excitations.append(
            e.model_copy(
                update={
                    "position_m": tuple(a.point_m),
                    "direction_gcs": tuple(float(v) for v in d / np.linalg.norm(d)),
                }
            )
        )
    geo = geometry_uncertainty(
        [o.to_json() for o in result.orientations if o.node in {c.node for c in setup.responses}],
        [
            a.to_json()
            for a in result.lines_of_action
            if a.node in {e.node for e in setup.excitations}
        ],
        [],
        point_accuracy_m=0.0,
        registration_limit_m=None,
    )
    try:
        return TestSetup.model_validate(
            {
                **setup.model_dump(),
                "responses": [c.model_dump() for c in responses],
                "excitations": [e.model_dump() for e in excitations],
                "geometry_uncertainty": geo.model_dump(),
            }
        )
    except ValidationError as err:
        raise SetupError(f"setup from photographs: {err}") from err
