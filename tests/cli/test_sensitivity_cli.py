"""``dimacq sensitivity cube``: table on stdout, JSON keys, refusals."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from dimacq.cli.main import main


def test_cube_json_and_table(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "s.json"
    rc = main(
        [
            "sensitivity",
            "cube",
            "--half-size",
            "0.01",
            "--sensors",
            "1",
            "--max-angle-deg",
            "1",
            "--trials",
            "500",
            "--seed",
            "3",
            "--json",
            str(out),
        ]
    )
    assert rc == 0
    text = capsys.readouterr().out
    assert "mass_kg" in text and "mean err %" in text
    data = json.loads(out.read_text())
    assert "mass_kg" in data and "Izz_kgm2" in data
    for key in ("min", "max", "mean", "std", "mean_error_pct"):
        assert key in data["mass_kg"]
    assert data["mass_kg"]["min"] <= data["mass_kg"]["mean"] <= data["mass_kg"]["max"]
    assert data["mass_kg"]["mean"] == pytest.approx(17.967635, rel=0.05)  # thesis Table 5
    assert data["study"]["n_trials"] == 500


def test_refusals(capsys: pytest.CaptureFixture[str]) -> None:
    assert (
        main(["sensitivity", "cube", "--half-size", "1", "--sensors", "9", "--max-angle-deg", "1"])
        == 2
    )
    assert "1..8" in capsys.readouterr().err
    assert main(["sensitivity", "cube", "--half-size", "-1", "--max-angle-deg", "1"]) == 2
