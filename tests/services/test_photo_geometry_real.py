"""Real photographs through the detector and pose: OpenCV's own tutorial photos of printed ArUco
markers (Apache-2.0, ``tests/data/photos/README.md``), checked against what OpenCV's tests
assert they show (``modules/objdetect/test/test_aruco_tutorial.cpp``: ids and corners within
1 px) and against the printed ChArUco board's layout."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from dimacq.pipeline.photogrammetry.camera import tag_corners
from dimacq.services.geometry.photo_geometry import detect_tags, pose_from_points

DATA = Path(__file__).resolve().parents[1] / "data" / "photos"

#: test_aruco_tutorial.cpp, CV_ArucoTutorial.can_find_singlemarkersoriginal
GOLD_SINGLE = {
    40: (359, 310, 404, 310, 410, 350, 362, 350),
    98: (427, 255, 469, 256, 477, 289, 434, 288),
    62: (233, 273, 190, 273, 196, 241, 237, 241),
    23: (298, 185, 334, 186, 335, 212, 297, 211),
    124: (425, 163, 430, 186, 394, 186, 390, 162),
    203: (195, 155, 230, 155, 227, 178, 190, 178),
}


def _gray(name: str) -> np.ndarray:
    img = cv2.imread(str(DATA / name), cv2.IMREAD_GRAYSCALE)
    assert img is not None
    return img


def test_single_markers_photo_ids_and_corners() -> None:
    det = detect_tags(_gray("singlemarkersoriginal.jpg"), "DICT_6X6_250")
    assert sorted(det) == sorted(GOLD_SINGLE)
    for tid, gold in GOLD_SINGLE.items():
        np.testing.assert_allclose(det[tid], np.reshape(gold, (4, 2)), atol=1.0)


def test_charuco_photo_matches_the_board() -> None:
    """The tutorial's ChArUco board (5 × 7 squares of 40 mm, markers of 20 mm, 6X6_250, ids
    0–16): every marker is found, one plane maps the board's printed corners onto all of them
    within a pixel, and each marker's own pose (IPPE) puts it where the board says relative to
    marker 0, within a few per cent of the 40 mm pitch."""
    d = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_6X6_250)
    board = cv2.aruco.CharucoBoard((5, 7), 0.04, 0.02, d)
    det = detect_tags(_gray("choriginal.jpg"), "DICT_6X6_250")
    assert sorted(det) == list(range(17))
    obj = {
        int(i): np.asarray(p, float)
        for i, p in zip(board.getIds(), board.getObjPoints(), strict=True)
    }
    src = np.concatenate([obj[i][:, :2] for i in sorted(det)])
    dst = np.concatenate([det[i] for i in sorted(det)])
    h, _ = cv2.findHomography(src, dst, 0)
    proj = cv2.perspectiveTransform(src.reshape(-1, 1, 2), h).reshape(-1, 2)
    assert np.sqrt(np.mean((proj - dst) ** 2)) < 1.0
    # pose of each marker from its own corners; f from the homography (K = diag(f, f, 1))
    hh, ww = _gray("choriginal.jpg").shape
    k = _focal_from_homography(h, ww / 2, hh / 2)
    centres = {}
    for i, c in det.items():
        xy = np.column_stack([(c[:, 0] - ww / 2) / k, (c[:, 1] - hh / 2) / k])
        _r, t, _e = pose_from_points(tag_corners(0.02), xy, True)
        centres[i] = t
    for i in sorted(det)[1:]:
        board_d = np.linalg.norm(obj[i].mean(axis=0) - obj[0].mean(axis=0))
        photo_d = np.linalg.norm(centres[i] - centres[0])
        assert abs(photo_d - board_d) < 0.06 * board_d + 0.002, (i, photo_d, board_d)


def _focal_from_homography(h: np.ndarray, cx: float, cy: float) -> float:
    """Zhang's constraint ``h1ᵀ ω h2 = 0`` with ``ω = K⁻ᵀK⁻¹``, ``K = [[f,0,cx],[0,f,cy],[0,0,1]]``:
    after moving the principal point to the origin, ``f² = −(a1 a2 + b1 b2) / (c1 c2)``."""
    t = np.array([[1, 0, -cx], [0, 1, -cy], [0, 0, 1.0]])
    g = t @ h
    a1, b1, c1 = g[:, 0]
    a2, b2, c2 = g[:, 1]
    return float(np.sqrt(abs((a1 * a2 + b1 * b2) / (c1 * c2))))
