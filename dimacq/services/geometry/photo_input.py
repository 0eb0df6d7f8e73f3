"""What a photo set brings: the camera file, the tags detected in each photo (OpenCV's ArUco
detector; corners refined on the tag's fitted edges) and the focal length from EXIF."""

from __future__ import annotations

import tomllib
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from dimacq.errors import SetupError
from dimacq.io.validation import refuse
from dimacq.pipeline.photogrammetry.camera import Intrinsics
from dimacq.services.geometry.photo_records import PhotoIssue

FloatArray = NDArray[np.float64]


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


# ------------------------------------------------------------------------------ detection
def load_cv2() -> Any:
    """OpenCV (``cv2``), imported on first use; a :class:`SetupError` naming the package if absent."""
    try:
        import cv2
    except ImportError as err:  # pragma: no cover - a dependency of the package
        raise SetupError(
            "geometry from photos needs OpenCV: pip install opencv-python-headless"
        ) from err
    return cv2


def _dictionary(family: str) -> Any:
    cv2 = load_cv2()
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
    cv2 = load_cv2()
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


def exif_focal_px(path: Path, width: int, height: int) -> float | None:
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


@dataclass
class Photo:
    """One usable photo: its file name, size (px), the known tags' corners (px) and its EXIF
    focal length (px) if it has one."""

    name: str
    size: tuple[int, int]
    tags: dict[int, FloatArray]
    focal_px: float | None


def read_gray(path: Path, size0: tuple[int, int] | None) -> NDArray[np.uint8] | PhotoIssue:
    """A photo of a set as a grey image, or the issue that skips it: unreadable, or of another
    size than the set's first photo (``size0``, None for the first)."""
    cv2 = load_cv2()
    gray = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    if gray is None:
        return PhotoIssue(
            path.name, "skipped", "not an image OpenCV can read", "remove it or save it as JPEG/PNG"
        )
    size = (int(gray.shape[1]), int(gray.shape[0]))
    if size0 is not None and size != size0:
        return PhotoIssue(
            path.name,
            "skipped",
            f"{size[0]}x{size[1]} px while the first photo is {size0[0]}x{size0[1]} px",
            "take every photo with one camera at one zoom and resolution",
        )
    return np.asarray(gray, dtype=np.uint8)


def read_photos(
    paths: Sequence[Path], family: str, known: set[int], say: Callable[[str], None]
) -> tuple[list[Photo], list[PhotoIssue]]:
    """The photos' known tags (detected with OpenCV), and an issue naming each photo that is
    unreadable, of another size than the first, shows no known tag, foreign tags or one tag."""
    photos: list[Photo] = []
    issues: list[PhotoIssue] = []
    size0: tuple[int, int] | None = None
    for k, path in enumerate(paths):
        gray = read_gray(path, size0)
        if isinstance(gray, PhotoIssue):
            issues.append(gray)
            continue
        size = (int(gray.shape[1]), int(gray.shape[0]))
        size0 = size0 or size
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
        photos.append(Photo(path.name, size, ours, exif_focal_px(path, *size)))
    return photos, issues


def blur_issue(name: str, gray: NDArray[np.uint8], missing: str, subject: str) -> PhotoIssue | None:
    """The issue of a photo in which ``missing`` ("no tags found") when it is blurred: the
    variance of its Laplacian under :data:`BLUR_LIMIT`; None when it is sharp enough."""
    cv2 = load_cv2()
    sharp = float(cv2.Laplacian(gray, cv2.CV_64F).var())
    if sharp >= BLUR_LIMIT:
        return None
    return PhotoIssue(
        name,
        "skipped",
        f"{missing} and the photo is blurred (sharpness {sharp:.0f} < {BLUR_LIMIT:.0f})",
        f"hold the camera still, focus on {subject}, use more light or a faster shutter",
    )


def _why_no_tags(name: str, gray: NDArray[np.uint8], family: str, foreign: list[int]) -> PhotoIssue:
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
    blurred = blur_issue(name, gray, "no tags found", "the tags")
    if blurred is not None:
        return blurred
    return PhotoIssue(
        name,
        "skipped",
        "no tags found",
        "frame the tags, come closer (a tag should span at least 20 px) and avoid glare",
    )
