"""Camera calibration from board photos: the simulated camera's intrinsics recovered within their
stated 1σ from rendered photos (the calibration reads only the JPEGs), photos that cannot help
named with the fix, sets that cannot support a calibration refused with the reason, and the
ChArUco corners of a real photograph against a second method."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest

from dimacq.errors import DataError
from dimacq.io.board_file import BoardFile
from dimacq.pipeline.photogrammetry.calibration import LIMIT_F_REL_STD, image_difference_px
from dimacq.pipeline.photogrammetry.camera import Intrinsics
from dimacq.services.geometry.camera_calibration import (
    STD_NAMES,
    CameraCalibration,
    board_print,
    calibrate_camera,
    find_board,
    read_board_photos,
    write_camera_file,
)
from dimacq.services.geometry.photo_input import detect_tags, load_camera
from dimacq.simulators.camera.board import photograph_board
from dimacq.simulators.camera.render import CameraModel

BOARD = BoardFile(
    squares_x=8, squares_y=11, square_m=0.025, marker_m=0.018, dictionary="DICT_5X5_100"
)
DATA = Path(__file__).resolve().parents[1] / "data" / "photos"


def _truth(cam: CameraModel) -> Intrinsics:
    return Intrinsics(
        cam.f_px, cam.f_px, cam.cx, cam.cy, *cam.dist, width=cam.width, height=cam.height
    )


@pytest.fixture(scope="module")
def good(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, CameraCalibration]:
    folder = tmp_path_factory.mktemp("board") / "photos"
    photograph_board(BOARD, folder, 15, seed=1)
    lines: list[str] = []
    return folder, calibrate_camera(folder, BOARD, progress=lines.append)


def test_intrinsics_within_their_uncertainty(good: tuple[Path, CameraCalibration]) -> None:
    _, cal = good
    assert cal.verdict == "ok" and cal.refused == [] and len(cal.used) == 15
    assert cal.rms_px is not None and cal.rms_px < 0.2
    got, true = cal.intrinsics, _truth(CameraModel())
    assert got is not None and (got.width, got.height) == (1600, 1200)
    for name in STD_NAMES:
        err = getattr(got, name) - getattr(true, name)
        assert abs(err) <= 3 * cal.std[name], (name, err, cal.std[name])
    for name in ("fx", "fy", "cx", "cy"):  # and within a pixel, a sensible absolute bound
        assert abs(getattr(got, name) - getattr(true, name)) < 1.0
        assert 0 < cal.std[name] < 0.5
    # the distortion as a whole: every pixel of the image lands within 0.5 px of the truth
    assert image_difference_px(true, got) < 0.5
    assert cal.cover.cells == 1.0 and cal.edge_std_px is not None and cal.edge_std_px < 0.5
    assert all(15 < v.tilt_deg < 50 for v in cal.used)
    doc = json.loads(json.dumps(cal.to_json()))
    assert doc["verdict"] == "ok" and doc["camera"]["fx"] == got.fx and len(doc["used"]) == 15


def test_photos_that_cannot_help_are_named(
    good: tuple[Path, CameraCalibration], tmp_path: Path
) -> None:
    folder, _ = good
    bad = tmp_path / "mixed"
    shutil.copytree(folder, bad)
    sample = cv2.imread(str(folder / "BOARD_0001.jpg"), cv2.IMREAD_GRAYSCALE)
    cv2.imwrite(str(bad / "a_blank.png"), np.full((1200, 1600), 128, np.uint8))
    cv2.imwrite(str(bad / "b_small.png"), cv2.resize(sample, (800, 600)))
    cv2.imwrite(str(bad / "c_blur.png"), cv2.GaussianBlur(sample, (0, 0), 15))
    # a sliver of the board only: the part around the first row's first five corners
    corners, _ = find_board(sample, BOARD)
    lo = np.floor(corners[:5].min(axis=0)).astype(int) - 15
    hi = np.ceil(corners[:5].max(axis=0)).astype(int) + 15
    part = np.full_like(sample, 128)
    part[lo[1] : hi[1], lo[0] : hi[0]] = sample[lo[1] : hi[1], lo[0] : hi[0]]
    cv2.imwrite(str(bad / "d_part.png"), part)
    (bad / "e_text.jpg").write_text("not an image")
    lines: list[str] = []
    cal = calibrate_camera(bad, BOARD, progress=lines.append)
    by = {i.photo: i for i in cal.issues}
    assert "board not found" in by["a_blank.png"].problem
    assert "800x600 px while the first photo is 1600x1200" in by["b_small.png"].problem
    assert "blurred" in by["c_blur.png"].problem
    assert "corners found (fewer than 14)" in by["d_part.png"].problem
    assert "not an image" in by["e_text.jpg"].problem
    assert all(i.fix for i in cal.issues)
    assert len(cal.used) == 15 and cal.verdict == "ok"
    assert any("BOARD_0003.jpg:" in m and "of 70 corners" in m for m in lines)
    assert any(m.startswith("calibrating from 15 photos") for m in lines)


def test_too_few_photos_refused(good: tuple[Path, CameraCalibration], tmp_path: Path) -> None:
    folder, _ = good
    few = tmp_path / "few"
    few.mkdir()
    for p in sorted(folder.iterdir())[:4]:
        shutil.copy(p, few / p.name)
    cal = calibrate_camera(few, BOARD)
    assert cal.intrinsics is None and cal.verdict == "fail"
    assert len(cal.refused) == 1 and "4 usable photos, fewer than 6" in cal.refused[0]
    assert "take 11 more photos" in cal.refused[0]
    with pytest.raises(DataError, match="4 usable photos"):
        write_camera_file(cal, BOARD, tmp_path / "cam.toml")
    assert not (tmp_path / "cam.toml").exists()


def test_square_on_board_refused_for_its_focal_length(tmp_path: Path) -> None:
    """Square-on photos fix f only weakly: the stated 1σ is large (and covers the error)."""
    photograph_board(BOARD, tmp_path, 8, seed=2, tilt_deg=(0.0, 3.0))
    cal = calibrate_camera(tmp_path, BOARD)
    assert "focal length ±" in cal.refused[0] and "tilted 15° or more in 0 of 8" in cal.refused[0]
    assert "tilting the board 20–45°" in cal.refused[0]
    assert cal.intrinsics is not None
    err = cal.intrinsics.fx - CameraModel().f_px
    assert cal.std["fx"] > LIMIT_F_REL_STD * cal.intrinsics.fx and abs(err) < 3 * cal.std["fx"]


def test_wrong_dictionary_named(good: tuple[Path, CameraCalibration]) -> None:
    folder, _ = good
    wrong = BOARD.model_copy(update={"dictionary": "DICT_4X4_100"})
    cal = calibrate_camera(folder, wrong)
    assert cal.intrinsics is None and "no usable photo of the board" in cal.refused[0]
    assert len(cal.issues) == 15
    assert "markers of DICT_5X5_250 seen, none of DICT_4X4_100" in cal.issues[0].problem
    assert 'dictionary = "DICT_5X5_250"' in cal.issues[0].fix


def test_wrong_square_count_refused(good: tuple[Path, CameraCalibration]) -> None:
    """A board file with the squares across and down swapped: the markers are seen, no corner
    lies where the file puts it."""
    folder, _ = good
    swapped = BOARD.model_copy(update={"squares_x": 11, "squares_y": 8})
    cal = calibrate_camera(folder, swapped)
    assert cal.intrinsics is None and "no usable photo of the board" in cal.refused[0]
    assert len(cal.issues) == 15
    for issue in cal.issues:
        assert "markers seen but no corner between them where the board file" in issue.problem
        assert "check squares_x, squares_y and legacy_pattern" in issue.fix


def test_chessboard(tmp_path: Path) -> None:
    """A chessboard, found only whole: the intrinsics right within their 1σ, but its corners
    kept a square's width from the frame's edges leave the image's corners loose (refused)."""
    board = BoardFile(type="chessboard", squares_x=10, squares_y=7, square_m=0.03)
    photograph_board(board, tmp_path, 12, seed=5, tilt_deg=(20.0, 45.0), fill=(0.6, 0.9))
    cal = calibrate_camera(tmp_path, board)
    assert cal.intrinsics is not None and cal.rms_px is not None and cal.rms_px < 0.2
    assert len(cal.used) == 12 and len(cal.refused) == 1
    assert (
        "image's corners to ±" in cal.refused[0]
        and "lens distortion is not fixed" in cal.refused[0]
    )
    true = _truth(CameraModel())
    for name in ("fx", "fy", "cx", "cy"):
        err = getattr(cal.intrinsics, name) - getattr(true, name)
        assert abs(err) <= 3 * cal.std[name] and abs(err) < 1.0, (name, err)


def test_written_file_reads_back(good: tuple[Path, CameraCalibration], tmp_path: Path) -> None:
    _, cal = good
    write_camera_file(cal, BOARD, tmp_path / "cam.toml", refine=True)
    intr, refine = load_camera(tmp_path / "cam.toml")
    assert refine is True and intr == cal.intrinsics
    assert "# reprojection RMS" in (tmp_path / "cam.toml").read_text()


def test_board_print_is_found_by_the_detector() -> None:
    img = board_print(BOARD, dpi=100)
    px = round(0.025 / 0.0254 * 100)
    assert img.shape == (11 * px + 2 * (px // 2), 8 * px + 2 * (px // 2))
    image_px, board_m = find_board(img, BOARD)
    assert len(image_px) == 70
    # the board frame maps onto the print: x = margin + X / square × px − ½
    np.testing.assert_allclose(image_px, px // 2 + board_m[:, :2] / 0.025 * px - 0.5, atol=0.3)


def test_real_charuco_photo_corners_against_its_markers() -> None:
    """OpenCV's tutorial photo of its 5 × 7 ChArUco board: all 24 inner corners found, and each
    where the plane through the 17 markers' own corners (found by the tag detector, a second
    method) puts it, within a pixel."""
    gray = cv2.imread(str(DATA / "choriginal.jpg"), cv2.IMREAD_GRAYSCALE)
    board = BoardFile(
        squares_x=5, squares_y=7, square_m=0.04, marker_m=0.02, dictionary="DICT_6X6_250"
    )
    image_px, board_m = find_board(gray, board)
    assert len(image_px) == 24
    cb = cv2.aruco.CharucoBoard(
        (5, 7), 0.04, 0.02, cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_6X6_250)
    )
    obj = {
        int(i): np.asarray(p, float) for i, p in zip(cb.getIds(), cb.getObjPoints(), strict=True)
    }
    tags = detect_tags(gray, "DICT_6X6_250")
    src = np.concatenate([obj[i][:, :2] for i in sorted(tags)])
    dst = np.concatenate([tags[i] for i in sorted(tags)])
    h, _ = cv2.findHomography(src, dst, 0)
    pred = cv2.perspectiveTransform(board_m[:, :2].reshape(-1, 1, 2), h).reshape(-1, 2)
    assert np.max(np.linalg.norm(pred - image_px, axis=1)) < 1.0


def test_a_bent_board_photo_is_left_out(
    good: tuple[Path, CameraCalibration], tmp_path: Path
) -> None:
    """A photo whose board is bent (its image warped by a 5 px wave) lies far off the fit of the
    others: named, left out, and the calibration run again without it."""
    folder, first = good
    bent = tmp_path / "bent"
    shutil.copytree(folder, bent)
    sample = cv2.imread(str(folder / "BOARD_0001.jpg"), cv2.IMREAD_GRAYSCALE)
    v, u = np.mgrid[0:1200, 0:1600].astype(np.float32)
    wave = (5.0 * np.sin(2 * np.pi * u / 400.0)).astype(np.float32)
    cv2.imwrite(str(bent / "z_bent.png"), cv2.remap(sample, u, v + wave, cv2.INTER_LINEAR))
    lines: list[str] = []
    cal = calibrate_camera(bent, BOARD, progress=lines.append)
    (issue,) = cal.issues
    assert issue.photo == "z_bent.png" and "px RMS off the calibration" in issue.problem
    assert "board flat" in issue.fix
    assert any("1 photos far off the fit left out" in m for m in lines)
    assert len(cal.used) == 15 and cal.verdict == "ok"
    assert cal.intrinsics is not None and first.intrinsics is not None
    # the same 15 photos as the good set: the same calibration, to far below its 1σ (0.1-0.6 px;
    # the refit's iterations may end a hair apart from the first fit's on another BLAS path)
    assert cal.intrinsics.fx == pytest.approx(first.intrinsics.fx, rel=1e-6)
    assert image_difference_px(first.intrinsics, cal.intrinsics) < 1e-3


def test_legacy_pattern_board(tmp_path: Path) -> None:
    """A board printed by OpenCV before 4.6 (even squares down: the first square white): found
    with ``legacy_pattern = true``, named with that fix without it."""
    legacy = BoardFile(
        squares_x=7,
        squares_y=10,
        square_m=0.025,
        marker_m=0.018,
        dictionary="DICT_5X5_100",
        legacy_pattern=True,
    )
    paths = photograph_board(legacy, tmp_path, 3, seed=3)
    views, issues, _size = read_board_photos(paths, legacy, lambda _m: None)
    assert len(views) == 3 and not issues
    modern = legacy.model_copy(update={"legacy_pattern": False})
    views, issues, _size = read_board_photos(paths, modern, lambda _m: None)
    assert not views and len(issues) == 3
    assert all("legacy_pattern" in i.fix for i in issues)


def test_missing_or_empty_folder_named(tmp_path: Path) -> None:
    with pytest.raises(DataError, match="not found; give the folder of the board photos"):
        calibrate_camera(tmp_path / "none", BOARD)
    (tmp_path / "notes.txt").write_text("x")
    with pytest.raises(DataError, match=r"no photos .*put the board photos in it"):
        calibrate_camera(tmp_path, BOARD)
