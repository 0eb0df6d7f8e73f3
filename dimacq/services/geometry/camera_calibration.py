"""A camera file from photos of a calibration board.

Steps (:func:`calibrate_camera`): read each photo of a folder, find the board's inner corners
(a ChArUco board: ``cv2.aruco.CharucoDetector``, each corner named by the markers around it and
refined to sub-pixel; a chessboard: ``cv2.findChessboardCorners`` and ``cv2.cornerSubPix``),
name each photo that cannot help with the fix, calibrate with ``cv2.calibrateCameraExtended``
(OpenCV's pinhole with ``fx, fy, cx, cy`` and distortion ``k1, k2, p1, p2, k3``: the model of
:class:`~dimacq.pipeline.photogrammetry.camera.Intrinsics`), leave out a photo whose corners lie
far off the fit and calibrate again, and judge what the data support
(:func:`~dimacq.pipeline.photogrammetry.calibration.refusals`). The fit minimises

    Σ_photos Σ_corners ‖u_ij − π(K, d; R_i X_j + t_i)‖²

over the intrinsics and every photo's board pose; the intrinsics' standard deviations are
``σ = √diag(s² S⁻¹)``, ``S`` the normal matrix's Schur complement on the intrinsics (the
photos' poses eliminated) and ``s²`` the corners' a-posteriori variance
(:func:`~dimacq.pipeline.photogrammetry.calibration.intrinsic_covariance`).
:func:`write_camera_file` writes the camera file
:func:`~dimacq.services.geometry.photo_input.load_camera` reads.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import tomli_w
from numpy.typing import NDArray

from dimacq.errors import DataError, SetupError
from dimacq.io.board_file import BoardFile
from dimacq.pipeline.photogrammetry.calibration import (
    LIMIT_RMS_PX,
    MIN_PHOTOS,
    Coverage,
    board_tilt_deg,
    coverage,
    edge_std_px,
    intrinsic_covariance,
    refusals,
)
from dimacq.pipeline.photogrammetry.camera import Intrinsics
from dimacq.services.geometry.photo_input import blur_issue, load_cv2, read_gray
from dimacq.services.geometry.photo_records import PhotoIssue

__all__ = [
    "STD_NAMES",
    "BoardView",
    "CameraCalibration",
    "board_print",
    "calibrate_camera",
    "camera_toml",
    "find_board",
    "min_corners",
    "read_board_photos",
    "write_board_print",
    "write_camera_file",
]

FloatArray = NDArray[np.float64]

#: The intrinsics whose standard deviations are reported, in OpenCV's order.
STD_NAMES = ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3")
#: A photo whose corners' RMS is above this many times the set's median (and above the RMS
#: limit) is left out and the calibration run again.
OUTLIER_FACTOR = 3.0
_SUFFIXES = (".jpg", ".jpeg", ".png", ".tif", ".tiff", ".bmp")
_OTHER_DICTIONARIES = (
    "DICT_4X4_250",
    "DICT_5X5_250",
    "DICT_6X6_250",
    "DICT_7X7_250",
    "DICT_ARUCO_ORIGINAL",
    "DICT_APRILTAG_36h11",
)


@dataclass(frozen=True)
class BoardView:
    """One photo's board corners: ``image_px`` shape (n, 2) and ``board_m`` shape (n, 3) (the
    board frame, z = 0), their tilt from square-on and RMS reprojection error once calibrated."""

    name: str
    image_px: FloatArray
    board_m: FloatArray
    tilt_deg: float = float("nan")
    rms_px: float = float("nan")


@dataclass(frozen=True)
class CameraCalibration:
    """The calibration and what judges it: ``intrinsics`` (None when not computed), the 1σ of
    each (``std``), the RMS reprojection error, the photos used and the issues of the others,
    the corners' cover of the image, the refusals (empty: the camera file may be written) and
    the 1σ of where the camera images the image's corners
    (:func:`~dimacq.pipeline.photogrammetry.calibration.edge_std_px`)."""

    intrinsics: Intrinsics | None
    std: dict[str, float]
    rms_px: float | None
    photos: list[str]
    used: list[BoardView]
    issues: list[PhotoIssue]
    cover: Coverage
    refused: list[str] = field(default_factory=list)
    edge_std_px: float | None = None

    @property
    def verdict(self) -> str:
        return "fail" if self.refused else "ok"

    def to_json(self) -> dict[str, Any]:
        return {
            "verdict": self.verdict,
            "refused": self.refused,
            "camera": None if self.intrinsics is None else self.intrinsics.to_json(),
            "std": self.std,
            "rms_px": self.rms_px,
            "edge_std_px": self.edge_std_px,
            "photos": self.photos,
            "used": [
                {
                    "photo": v.name,
                    "corners": len(v.image_px),
                    "tilt_deg": v.tilt_deg,
                    "rms_px": v.rms_px,
                }
                for v in self.used
            ],
            "issues": [i.to_json() for i in self.issues],
            "coverage": {
                "cells": self.cover.cells,
                "reach": self.cover.reach,
                "empty": list(self.cover.empty),
            },
        }


# ------------------------------------------------------------------------------ detection
def _dictionary(name: str) -> Any:
    cv2 = load_cv2()
    return cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, name))


def _charuco(board: BoardFile) -> Any:
    """OpenCV's ``CharucoBoard`` of the board file."""
    cv2 = load_cv2()
    assert board.marker_m is not None and board.dictionary is not None
    b = cv2.aruco.CharucoBoard(
        (board.squares_x, board.squares_y),
        board.square_m,
        board.marker_m,
        _dictionary(board.dictionary),
    )
    b.setLegacyPattern(board.legacy_pattern)
    return b


def min_corners(board: BoardFile) -> int:
    """Fewest corners a photo must show to be used: a fifth of the board's, at least 8 (the
    chessboard: all of them)."""
    if board.type == "chessboard":
        return board.inner_corners
    return max(8, board.inner_corners // 5)


class _Finder:
    """The board's corners in a grey image (see :func:`find_board`)."""

    def __init__(self, board: BoardFile) -> None:
        self.board = board
        cv2 = load_cv2()
        if board.type == "charuco":
            self.cb = _charuco(board)
            self.detector = cv2.aruco.CharucoDetector(self.cb)

    def __call__(self, gray: NDArray[np.uint8]) -> tuple[FloatArray, FloatArray, int]:
        """``(image_px, board_m, markers)``: the corners found (shapes (n, 2), (n, 3)) and
        the markers seen (ChArUco)."""
        cv2 = load_cv2()
        b = self.board
        if b.type == "chessboard":
            pattern = (b.squares_x - 1, b.squares_y - 1)
            flags = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE
            ok, corners = cv2.findChessboardCorners(gray, pattern, flags=flags)
            if not ok:
                return np.zeros((0, 2)), np.zeros((0, 3)), 0
            crit = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 50, 1e-3)
            corners = cv2.cornerSubPix(gray, corners, (5, 5), (-1, -1), crit)
            grid = np.mgrid[1 : pattern[0] + 1, 1 : pattern[1] + 1].T.reshape(-1, 2)
            obj = np.column_stack([grid * b.square_m, np.zeros(len(grid))])
            return np.asarray(corners, float).reshape(-1, 2), obj, 0
        cc, ci, _mc, mi = self.detector.detectBoard(gray)
        markers = 0 if mi is None else len(mi)
        if ci is None or len(ci) < 4:
            return np.zeros((0, 2)), np.zeros((0, 3)), markers
        if self.cb.checkCharucoCornersCollinear(ci):
            return np.zeros((0, 2)), np.zeros((0, 3)), markers
        obj, img = self.cb.matchImagePoints(cc, ci)
        return np.asarray(img, float).reshape(-1, 2), np.asarray(obj, float).reshape(-1, 3), markers


def find_board(gray: NDArray[np.uint8], board: BoardFile) -> tuple[FloatArray, FloatArray]:
    """The board's inner corners in a grey image: ``(image_px, board_m)``, shapes (n, 2) and
    (n, 3) (n = 0: not found; a ChArUco board's corners on one line count as not found)."""
    img, obj, _ = _Finder(board)(gray)
    return img, obj


def _why_not_found(
    name: str, gray: NDArray[np.uint8], board: BoardFile, markers: int, corners: int
) -> PhotoIssue:
    """The issue of a photo whose board was not found or showed too few corners."""
    cv2 = load_cv2()
    need = min_corners(board)
    if corners:
        return PhotoIssue(
            name,
            "skipped",
            f"{corners} of the board's {board.inner_corners} corners found (fewer than {need})",
            "show more of the board: all of it, or at least the part near the frame's corner",
        )
    if board.type == "charuco" and not markers:
        for other in _OTHER_DICTIONARIES:
            if other == board.dictionary:
                continue
            det = cv2.aruco.ArucoDetector(_dictionary(other), cv2.aruco.DetectorParameters())
            _c, ids, _r = det.detectMarkers(gray)
            if ids is not None and len(ids) >= 4:
                return PhotoIssue(
                    name,
                    "skipped",
                    f"markers of {other} seen, none of {board.dictionary} (the board file's)",
                    f'set dictionary = "{other}" in the board file if that is the board printed',
                )
    blurred = blur_issue(name, gray, "board not found", "the board")
    if blurred is not None:
        return blurred
    if board.type == "charuco" and markers >= 4:
        return PhotoIssue(
            name,
            "skipped",
            f"board not found: {markers} of its markers seen but no corner between them where "
            "the board file puts them",
            "check squares_x, squares_y and legacy_pattern in the board file against the print",
        )
    what = (
        f"no {board.squares_x} x {board.squares_y} squares"
        if board.type == "chessboard"
        else f"no marker of {board.dictionary}"
    )
    return PhotoIssue(
        name,
        "skipped",
        f"board not found ({what})",
        "show the whole board in the frame and avoid glare; for a chessboard check squares_x "
        "and squares_y in the board file",
    )


def read_board_photos(
    paths: Sequence[Path], board: BoardFile, say: Callable[[str], None]
) -> tuple[list[BoardView], list[PhotoIssue], tuple[int, int] | None]:
    """Each photo's board corners; an issue naming each photo that is unreadable, of another
    size than the first, blurred, shows no board or too few corners. Also the image size."""
    finder = _Finder(board)
    views: list[BoardView] = []
    issues: list[PhotoIssue] = []
    size0: tuple[int, int] | None = None
    for k, path in enumerate(paths):
        gray = read_gray(path, size0)
        if isinstance(gray, PhotoIssue):
            issues.append(gray)
            say(f"photo {k + 1}/{len(paths)} {path.name}: {gray.problem}")
            continue
        size0 = size0 or (int(gray.shape[1]), int(gray.shape[0]))
        img, obj, markers = finder(gray)
        say(f"photo {k + 1}/{len(paths)} {path.name}: {len(img)} of {board.inner_corners} corners")
        if len(img) < min_corners(board):
            issues.append(_why_not_found(path.name, gray, board, markers, len(img)))
            continue
        views.append(BoardView(path.name, img, obj))
    return views, issues, size0


# ------------------------------------------------------------------------------ calibration
@dataclass(frozen=True)
class _Fit:
    intrinsics: Intrinsics
    std: dict[str, float]
    rms_px: float
    per_view_px: FloatArray
    tilts_deg: list[float]
    edge_std_px: float


def _fit(views: Sequence[BoardView], size: tuple[int, int]) -> _Fit:
    """``cv2.calibrateCameraExtended`` on the views (flags 0: ``fx``, ``fy``, ``cx``, ``cy``,
    ``k1, k2, p1, p2, k3`` all estimated); the standard deviations from the fit's Jacobian
    (:func:`_std`)."""
    cv2 = load_cv2()
    obj = [np.ascontiguousarray(v.board_m, np.float32) for v in views]
    img = [np.ascontiguousarray(v.image_px, np.float32).reshape(-1, 1, 2) for v in views]
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-12)
    rms, k, d, rvecs, tvecs, _std_i, _std_e, per_view = cv2.calibrateCameraExtended(
        obj, img, size, None, None, flags=0, criteria=crit
    )
    d = np.asarray(d, float).ravel()
    intr = Intrinsics(
        fx=float(k[0, 0]),
        fy=float(k[1, 1]),
        cx=float(k[0, 2]),
        cy=float(k[1, 2]),
        k1=float(d[0]),
        k2=float(d[1]),
        p1=float(d[2]),
        p2=float(d[3]),
        k3=float(d[4]),
        width=size[0],
        height=size[1],
    )
    cov = _covariance(views, intr, rvecs, tvecs)
    s = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    std = {n: float(s[i]) for i, n in enumerate(STD_NAMES)}
    tilts = [board_tilt_deg(r) for r in rvecs]
    per_view_px = np.asarray(per_view, float).ravel()
    return _Fit(intr, std, float(rms), per_view_px, tilts, edge_std_px(intr, cov))


def _covariance(
    views: Sequence[BoardView], intr: Intrinsics, rvecs: Sequence[Any], tvecs: Sequence[Any]
) -> FloatArray:
    """The covariance of ``fx, fy, cx, cy, k1, k2, p1, p2, k3``: :func:`intrinsic_covariance` with the
    Jacobians ``cv2.projectPoints`` gives at the fit (columns: rvec 3, tvec 3, f 2, c 2,
    distortion 5). OpenCV's own ``stdDeviationsIntrinsics`` is not used: on a board seen
    square-on in every photo, where ``f`` and the distance trade against each other, it states
    a 1σ far below the focal length's actual error."""
    cv2 = load_cv2()
    a_blocks, b_blocks, res = [], [], []
    for v, rv, tv in zip(views, rvecs, tvecs, strict=True):
        proj, jac = cv2.projectPoints(
            np.asarray(v.board_m, float), rv, tv, intr.matrix, intr.distortion
        )
        jac = np.asarray(jac, float)
        a_blocks.append(jac[:, 6:15])
        b_blocks.append(jac[:, :6])
        res.append((np.asarray(proj, float).reshape(-1, 2) - v.image_px).ravel())
    return intrinsic_covariance(a_blocks, b_blocks, np.concatenate(res))


def _outliers(fit: _Fit, names: Sequence[str]) -> list[tuple[int, PhotoIssue]]:
    """The photos whose corners' RMS is above :data:`OUTLIER_FACTOR` × the median and the
    RMS limit, with their issue."""
    med = float(np.median(fit.per_view_px))
    cut = max(OUTLIER_FACTOR * med, LIMIT_RMS_PX)
    return [
        (
            i,
            PhotoIssue(
                names[i],
                "skipped",
                f"its corners lie {e:.2f} px RMS off the calibration (the photos' median "
                f"{med:.2f} px): left out",
                "retake it with the board flat, still and sharp",
            ),
        )
        for i, e in enumerate(fit.per_view_px)
        if e > cut
    ]


def calibrate_camera(
    photos_dir: str | Path,
    board: BoardFile,
    *,
    progress: Callable[[str], None] | None = None,
) -> CameraCalibration:
    """The camera's intrinsics from the photos of ``board`` in ``photos_dir`` (see the module).

    Raises
    ------
    DataError
        No such folder, or no photo in it.
    """
    say = progress or (lambda _m: None)
    folder = Path(photos_dir)
    if not folder.is_dir():
        raise DataError(f"photo folder {folder}: not found; give the folder of the board photos")
    paths = sorted(p for p in folder.iterdir() if p.suffix.lower() in _SUFFIXES)
    if not paths:
        raise DataError(
            f"photo folder {folder}: no photos ({', '.join(_SUFFIXES)}); put the board photos in it"
        )
    views, issues, size = read_board_photos(paths, board, say)
    names = [p.name for p in paths]
    if len(views) < MIN_PHOTOS or size is None:
        cover = coverage([v.image_px for v in views], *(size or (1, 1)))
        return CameraCalibration(
            None, {}, None, names, views, issues, cover, refusals(len(views), None, None, cover, [])
        )
    n_corners = sum(len(v.image_px) for v in views)
    say(f"calibrating from {len(views)} photos, {n_corners} corners")
    fit = _fit(views, size)
    bad = _outliers(fit, [v.name for v in views])
    if bad and len(views) - len(bad) >= MIN_PHOTOS:
        drop = {i for i, _ in bad}
        issues.extend(issue for _, issue in bad)
        views = [v for i, v in enumerate(views) if i not in drop]
        say(f"{len(bad)} photos far off the fit left out; calibrating again from {len(views)}")
        fit = _fit(views, size)
    used = [
        BoardView(v.name, v.image_px, v.board_m, t, float(e))
        for v, t, e in zip(views, fit.tilts_deg, fit.per_view_px, strict=True)
    ]
    cover = coverage([v.image_px for v in views], *size)
    intr = fit.intrinsics
    f_rel = max(fit.std["fx"] / intr.fx, fit.std["fy"] / intr.fy)
    return CameraCalibration(
        intr,
        fit.std,
        fit.rms_px,
        names,
        used,
        issues,
        cover,
        refusals(len(views), f_rel, fit.rms_px, cover, fit.tilts_deg, fit.edge_std_px),
        fit.edge_std_px,
    )


def camera_toml(cal: CameraCalibration, board: BoardFile, *, refine: bool = False) -> str:
    """The camera file's text (TOML, ``load_camera``'s items), headed by comments stating the
    calibration's figures."""
    if cal.intrinsics is None:
        raise DataError("no calibration to write: " + "; ".join(cal.refused))
    stds = ", ".join(f"{n} {cal.std[n]:.3g}" for n in STD_NAMES)
    head = [
        f"# calibrated from {len(cal.used)} photos of a {board.squares_x} x {board.squares_y} "
        f"{board.type} board ({1000 * board.square_m:g} mm squares)",
        f"# reprojection RMS {cal.rms_px:.3f} px; 1σ: {stds} (px for fx … cy)",
    ]
    data = {"schema_version": 1, **cal.intrinsics.to_json(), "refine": refine}
    return "\n".join(head) + "\n" + tomli_w.dumps(data)


def write_camera_file(
    cal: CameraCalibration, board: BoardFile, path: str | Path, *, refine: bool = False
) -> None:
    """Write the camera file (:func:`camera_toml`); a refused calibration is not written.

    Raises
    ------
    DataError
        The calibration was refused: the message lists why.
    """
    if cal.refused:
        raise DataError("camera not calibrated: " + " | ".join(cal.refused))
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    p.write_text(camera_toml(cal, board, refine=refine), encoding="utf-8")


def board_print(board: BoardFile, dpi: float = 300.0) -> NDArray[np.uint8]:
    """The board to print at ``dpi`` (dots per inch) so that its squares are ``square_m``, with
    a white margin of half a square (grey image). A chessboard starts with a black square."""
    px = max(8, round(board.square_m / 0.0254 * dpi))
    m = px // 2
    size = (board.squares_x * px + 2 * m, board.squares_y * px + 2 * m)
    if board.type == "charuco":
        return np.asarray(_charuco(board).generateImage(size, marginSize=m, borderBits=1), np.uint8)
    cells = (np.add.outer(np.arange(board.squares_y), np.arange(board.squares_x)) % 2) == 1
    out = np.full((size[1], size[0]), 255, np.uint8)
    out[m : m + board.squares_y * px, m : m + board.squares_x * px] = np.where(
        np.kron(cells, np.ones((px, px), bool)), 255, 0
    ).astype(np.uint8)
    return out


def write_board_print(board: BoardFile, path: str | Path, dpi: float = 300.0) -> Path:
    """Write :func:`board_print` as an image file (PNG or TIFF, its resolution stated in the
    file so that a printer at 100 % prints ``square_m`` squares)."""
    from PIL import Image  # a dependency of matplotlib, one of ours

    p = Path(path)
    img = board_print(board, dpi)
    p.parent.mkdir(parents=True, exist_ok=True)
    try:
        Image.fromarray(img).save(p, dpi=(dpi, dpi))
    except (ValueError, OSError) as err:
        raise SetupError(
            f"cannot write the board image {p} ({err}); give a .png path in a writable folder"
        ) from err
    return p
