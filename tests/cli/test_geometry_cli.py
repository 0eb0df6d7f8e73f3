"""``dimacq geometry from-photos``: its arguments and its refusals (exit status and message)."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from dimacq.cli.main import main
from dimacq.io.setup_file import save_setup
from dimacq.simulators.lab.scenarios import build_scenario


def test_from_photos_without_tags_file_names_the_fix(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    photos = tmp_path / "photos"
    photos.mkdir()
    cv2.imwrite(str(photos / "a.png"), np.full((100, 100), 128, np.uint8))
    save_setup(build_scenario("calibration-mass-bungee", 0).setup, tmp_path / "setup.toml")
    code = main(
        [
            "geometry",
            "from-photos",
            str(photos),
            "--setup",
            str(tmp_path / "setup.toml"),
            "--out",
            str(tmp_path / "GEOMETRY.json"),
        ]
    )
    assert code != 0
    assert "--tags TAGS.toml" in capsys.readouterr().err
    assert not (tmp_path / "GEOMETRY.json").exists()
