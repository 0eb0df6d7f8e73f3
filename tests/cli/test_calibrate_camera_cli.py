"""``dimacq geometry calibrate-camera`` end to end: rendered board photos (JPEG, no EXIF) → CAM.toml
that ``load_camera`` reads back, a refused set (exit status 2, nothing written), the board to
print; then ``from-photos`` with that camera file on EXIF-less photos of the article."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from _photo_support import small_photo_set

from dimacq.cli.main import main
from dimacq.io.board_file import BoardFile, dump_board
from dimacq.pipeline.photogrammetry.calibration import image_difference_px
from dimacq.pipeline.photogrammetry.camera import Intrinsics
from dimacq.services.geometry.photo_input import exif_focal_px, load_camera
from dimacq.simulators.camera.board import photograph_board
from dimacq.simulators.camera.render import CameraModel

BOARD = BoardFile(
    squares_x=8, squares_y=11, square_m=0.025, marker_m=0.018, dictionary="DICT_5X5_100"
)


@pytest.fixture(scope="module")
def calibrated(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """CAM.toml from 12 rendered board photos, through the command."""
    root = tmp_path_factory.mktemp("camcal")
    photograph_board(BOARD, root / "board", 12, seed=7)
    dump_board(BOARD, root / "board.toml")
    code = main(
        [
            "geometry",
            "calibrate-camera",
            str(root / "board"),
            "--board",
            str(root / "board.toml"),
            "--out",
            str(root / "cam.toml"),
            "--quiet",
        ]
    )
    assert code == 0
    return root


def test_camera_file_written_and_read_back(
    calibrated: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    intr, refine = load_camera(calibrated / "cam.toml")
    assert refine is False
    cam = CameraModel()
    true = Intrinsics(cam.f_px, cam.f_px, cam.cx, cam.cy, *cam.dist, width=1600, height=1200)
    assert (intr.width, intr.height) == (1600, 1200)
    assert image_difference_px(true, intr) < 0.5
    assert exif_focal_px(calibrated / "board" / "BOARD_0000.jpg", 1600, 1200) is None


def test_report_and_refine_flag(calibrated: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = calibrated / "cam_refine.toml"
    args = ["geometry", "calibrate-camera", str(calibrated / "board"), "--board"]
    code = main([*args, str(calibrated / "board.toml"), "--out", str(out), "--refine"])
    text = capsys.readouterr().out
    assert code == 0 and load_camera(out)[1] is True
    assert "photo 12/12 BOARD_0011.jpg:" in text and "of 70 corners" in text
    assert "12 of 12 photos used" in text and "reprojection RMS" in text
    assert "fx = " in text and " px (1σ)" in text and "k3 = " in text
    assert f"camera written to {out} (refine = true)" in text


def test_refused_set_writes_nothing(
    calibrated: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    few = tmp_path / "few"
    few.mkdir()
    for p in sorted((calibrated / "board").iterdir())[:3]:
        (few / p.name).write_bytes(p.read_bytes())
    out = tmp_path / "cam.toml"
    code = main(
        [
            "geometry",
            "calibrate-camera",
            str(few),
            "--board",
            str(calibrated / "board.toml"),
            "--out",
            str(out),
            "-q",
        ]
    )
    text = capsys.readouterr().out
    assert code == 2 and not out.exists()
    assert "refused: 3 usable photos, fewer than 6" in text and "not written" in text


def test_bad_board_file_names_the_item(
    calibrated: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    (tmp_path / "b.toml").write_text("squares_x = 8\nsquares_y = 11\nsquare_m = 0.025\n")
    code = main(
        [
            "geometry",
            "calibrate-camera",
            str(calibrated / "board"),
            "--board",
            str(tmp_path / "b.toml"),
            "--out",
            str(tmp_path / "cam.toml"),
        ]
    )
    assert code != 0 and "a charuco board needs marker_m" in capsys.readouterr().err


def test_board_print(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from PIL import Image

    dump_board(BOARD, tmp_path / "board.toml")
    code = main(
        ["geometry", "board", str(tmp_path / "board.toml"), "--out", str(tmp_path / "b.png")]
    )
    assert code == 0 and "200 x 275 mm" in capsys.readouterr().out
    with Image.open(tmp_path / "b.png") as im:
        px = round(0.025 / 0.0254 * 300)
        assert im.size == (8 * px + 2 * (px // 2), 11 * px + 2 * (px // 2))
        assert round(im.info["dpi"][0]) == 300


def test_from_photos_with_the_camera_file(
    calibrated: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """EXIF-less photos of the article: refused without a camera file, adjusted with the
    calibrated one (held fixed), the triaxes where the simulator put them."""
    ps = small_photo_set(tmp_path / "photos", exif=False)
    (tmp_path / "setup.json").write_text(json.dumps(ps.setup), encoding="utf-8")
    args = ["geometry", "from-photos", str(ps.folder), "--setup", str(tmp_path / "setup.json")]
    assert main([*args, "--out", str(tmp_path / "g0.json"), "-q"]) != 0
    assert "--camera CAM.toml" in capsys.readouterr().err
    code = main(
        [*args, "--camera", str(calibrated / "cam.toml"), "--out", str(tmp_path / "g.json"), "-q"]
    )
    assert code == 0, capsys.readouterr()
    g = json.loads((tmp_path / "g.json").read_text())
    origins = {o["node"]: (np.array(o["origin_m"]), o["origin_std_m"]) for o in g["orientations"]}
    assert sorted(origins) == sorted(ps.nodes)
    for node, (p, std) in origins.items():
        err = float(np.linalg.norm(p - ps.truth[f"triax {node}"][1]))
        assert err < 1e-3 and err < 4 * np.sqrt(3) * std, (node, err, std)
