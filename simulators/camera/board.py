"""Photographs of a calibration board through the simulated camera.

The board of a board file (:class:`~dimacq.io.board_file.BoardFile`): a ChArUco board as ``cv2.aruco.CharucoBoard
.generateImage`` draws it, or a chessboard, printed black on white paper with a white margin of
half a square. A photo: the board at a drawn pose, warped (``cv2.warpPerspective``) onto the
ideal canvas through the pinhole and exposed as every simulated photo is
(:func:`~dimacq.simulators.camera.render.expose`: the lens blur and the pixels' area, the lens
distortion, exposure, noise), written as JPEG without EXIF: nothing but the image leaves this
module for the calibration.

The poses (:func:`board_poses`): the board tilted by ``θ`` (drawn in ``tilt_deg``) about a
random axis in its plane and turned by a random roll, its image ``fill`` (drawn) of the image's
diagonal, its centre at a random point of the image, redrawn until the whole board (a
chessboard) or half its inner corners (a ChArUco board) lie within the frame.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from dimacq.io.board_file import BoardFile
from dimacq.simulators.camera.render import (
    SUPERSAMPLE,
    CameraModel,
    background,
    canvas_matrix,
    expose,
    write_jpeg,
)

__all__ = ["board_image", "board_poses", "photograph_board", "render_board"]

FloatArray = NDArray[np.float64]

_INK, _PAPER = 25.0, 230.0  # grey levels of the printed black and of the paper


def board_image(board: BoardFile, px: int) -> tuple[NDArray[np.uint8], float]:
    """The printed board at ``px`` pixels a square, with a white margin of half a square:
    the image and its margin in metres. Board frame: origin at the board's top-left outer
    corner, ``x`` along its width, ``y`` down it, ``z`` into it (OpenCV's board frame)."""
    m = px // 2
    size = (board.squares_x * px + 2 * m, board.squares_y * px + 2 * m)
    if board.type == "charuco":
        assert board.marker_m is not None and board.dictionary is not None
        d = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, board.dictionary))
        b = cv2.aruco.CharucoBoard(
            (board.squares_x, board.squares_y), board.square_m, board.marker_m, d
        )
        b.setLegacyPattern(board.legacy_pattern)
        img = b.generateImage(size, marginSize=m, borderBits=1)
    else:
        cells = (np.add.outer(np.arange(board.squares_y), np.arange(board.squares_x)) % 2) == 1
        img = np.full((size[1], size[0]), 255, np.uint8)
        img[m : m + board.squares_y * px, m : m + board.squares_x * px] = np.where(
            np.kron(cells, np.ones((px, px), bool)), 255, 0
        ).astype(np.uint8)
    return np.asarray(img, np.uint8), m / px * board.square_m


def _outline(board: BoardFile, margin_m: float) -> FloatArray:
    """The printed sheet's four corners in the board frame, shape (4, 3)."""
    w = board.squares_x * board.square_m + margin_m
    h = board.squares_y * board.square_m + margin_m
    return np.array([[-margin_m, -margin_m, 0], [w, -margin_m, 0], [w, h, 0], [-margin_m, h, 0]])


def board_poses(
    board: BoardFile,
    cam: CameraModel,
    n: int,
    rng: np.random.Generator,
    *,
    tilt_deg: tuple[float, float] = (20.0, 45.0),
    fill: tuple[float, float] = (0.45, 0.9),
    whole: bool | None = None,
) -> list[tuple[FloatArray, FloatArray]]:
    """``n`` poses ``(R, t)`` (board → camera, ``X_c = R X + t``) as the module says: the whole
    board within the frame (``whole``; default for a chessboard, whose corners are found only
    all together), else at least half its inner corners (a ChArUco board seen in part, as a
    photographer frames it to reach the image's corners)."""
    whole = board.type == "chessboard" if whole is None else whole
    ctr = 0.5 * np.array([board.squares_x * board.square_m, board.squares_y * board.square_m, 0])
    sheet = _outline(board, 0.5 * board.square_m)
    grid = np.mgrid[1 : board.squares_x, 1 : board.squares_y].T.reshape(-1, 2) * board.square_m
    inner = np.column_stack([grid, np.zeros(len(grid))])
    diag_m = float(np.linalg.norm(sheet[2] - sheet[0]))
    diag_px = float(np.hypot(cam.width, cam.height))
    lo, hi = np.array([8.0, 8.0]), np.array([cam.width - 8.0, cam.height - 8.0])
    out: list[tuple[FloatArray, FloatArray]] = []
    while len(out) < n:
        for _try in range(500):
            phi, roll = rng.uniform(0, 2 * np.pi, 2)
            theta = np.radians(rng.uniform(*tilt_deg))
            r = (
                Rotation.from_rotvec(theta * np.array([np.cos(phi), np.sin(phi), 0.0]))
                * Rotation.from_rotvec([0.0, 0.0, roll])
            ).as_matrix()
            z = cam.f_px * diag_m / (rng.uniform(*fill) * diag_px)
            u, v = rng.uniform([0, 0], [cam.width, cam.height])
            t = z * np.array([(u - cam.cx) / cam.f_px, (v - cam.cy) / cam.f_px, 1.0]) - r @ ctr
            pts = sheet if whole else inner
            xc = pts @ r.T + t
            uv = (xc @ cam.matrix.T)[:, :2] / xc[:, 2:3]
            inside = np.all((uv > lo) & (uv < hi), axis=1) & (xc[:, 2] > 0)
            if inside.all() if whole else inside.mean() >= 0.5:
                out.append((r, t))
                break
        else:  # pragma: no cover - a board too large for the frame at the smallest fill
            raise ValueError("the board does not fit the frame at the fill asked for")
    return out


def render_board(
    board: BoardFile,
    cam: CameraModel,
    r: FloatArray,
    t: FloatArray,
    rng: np.random.Generator,
    *,
    blur_px: float = 0.6,
    noise: float = 2.0,
    exposure: float = 1.0,
) -> NDArray[np.uint8]:
    """One photo (grey, uint8) of the board at ``X_c = r X + t``."""
    canvas = background(cam, rng)
    k2 = canvas_matrix(cam)
    x_c = np.array([[0, 0, 0], [board.square_m, 0, 0]]) @ r.T + t
    uv = (x_c @ k2.T)[:, :2] / x_c[:, 2:3]
    px = int(np.clip(np.linalg.norm(uv[1] - uv[0]), 8, 64))
    img, margin_m = board_image(board, px)
    xc = _outline(board, margin_m) @ r.T + t
    dst = ((xc @ k2.T)[:, :2] / xc[:, 2:3]).astype(np.float32)
    h, w = img.shape
    src = np.array([[-0.5, -0.5], [w - 0.5, -0.5], [w - 0.5, h - 0.5], [-0.5, h - 0.5]], np.float32)
    hmat = cv2.getPerspectiveTransform(src, dst)
    normal = r[:, 2]
    shade = float(np.clip(0.6 + 0.4 * abs(normal[2]), 0.5, 1.0))
    printed = (_INK + (_PAPER - _INK) * img.astype(np.float32) / 255.0) * shade
    size = (SUPERSAMPLE * cam.width, SUPERSAMPLE * cam.height)
    warped = cv2.warpPerspective(printed, hmat, size, flags=cv2.INTER_LINEAR)
    mask = cv2.warpPerspective(np.ones_like(printed), hmat, size, flags=cv2.INTER_LINEAR)
    canvas = canvas * (1 - mask) + warped
    return expose(canvas, cam, rng, blur_px=blur_px, noise=noise, exposure=exposure)


def photograph_board(
    board: BoardFile,
    out_dir: str | Path,
    n_photos: int,
    seed: int,
    cam: CameraModel | None = None,
    *,
    tilt_deg: tuple[float, float] = (20.0, 45.0),
    fill: tuple[float, float] = (0.45, 0.9),
    whole: bool | None = None,
    exif: bool = False,
) -> list[Path]:
    """Write ``n_photos`` JPEG photos of ``board`` into ``out_dir`` (poses :func:`board_poses`;
    each photo its own blur 0.4–1.0 px and exposure 0.8–1.2), without EXIF unless ``exif``."""
    cam = cam or CameraModel()
    rng = np.random.default_rng(seed)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = []
    for i, (r, t) in enumerate(
        board_poses(board, cam, n_photos, rng, tilt_deg=tilt_deg, fill=fill, whole=whole)
    ):
        img = render_board(
            board,
            cam,
            r,
            t,
            rng,
            blur_px=float(rng.uniform(0.4, 1.0)),
            exposure=float(rng.uniform(0.8, 1.2)),
        )
        p = out / f"BOARD_{i:04d}.jpg"
        write_jpeg(p, img, cam if exif else None)
        paths.append(p)
    return paths
