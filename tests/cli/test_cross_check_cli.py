"""``dimacq solve`` reports the mass-line cross-check beside the DIM: on the simulator's noise-free
model FRFs (files and truth from ``dimacq simulate``) and on the independent sample files."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from _samples import samples_dir

from dimacq.cli.main import main

SAMPLES = samples_dir()


def _rel(a: float, b: float) -> float:
    return abs(a / b - 1)


@pytest.mark.slow
def test_noise_free_calibration_mass_files_give_the_truth(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    uff, truth_p, out = tmp_path / "m.uff", tmp_path / "t.json", tmp_path / "sol.json"
    assert (
        main(["simulate", "calibration-mass-bungee", "--frf", str(uff), "--truth", str(truth_p)])
        == 0
    )
    capsys.readouterr()
    assert main(["solve", str(uff), "--json", str(out), "--reference", str(truth_p)]) == 0
    text = capsys.readouterr().out
    assert "cross-check (mass line" in text and "mass line" in text
    data = json.loads(out.read_text())
    truth = json.loads(truth_p.read_text())
    cc = data["cross_check"]
    assert cc["method"] == "mass-line"
    assert _rel(cc["mass_kg"], truth["mass_kg"]) < 1e-6
    assert np.allclose(cc["cg_m"], truth["cg_m"], atol=1e-8)
    i_max = max(truth["principal_moments_kgm2"])
    assert (
        np.max(np.abs(np.subtract(cc["inertia_cg_kgm2"], truth["inertia_cg_kgm2"]))) < 1e-6 * i_max
    )
    assert cc["agrees"]["all"] is True
    assert cc["agrees"]["cg"] == [True, True, True]
    reasons = {r["check"]: r for r in data["verdict_reasons"]}
    assert reasons["cross_check"]["severity"] == "ok"


@pytest.mark.slow
@pytest.mark.skipif(not SAMPLES.is_dir(), reason="shared samples folder absent")
@pytest.mark.parametrize(
    ("name", "mass_rel", "cg_m"),
    [("bracket_clean_binary.uff", 1e-9, 1e-10), ("bracket_noisy_ascii.uff", 0.01, 0.002)],
)
def test_independent_sample_files(name: str, mass_rel: float, cg_m: float, tmp_path: Path) -> None:
    out = tmp_path / "sol.json"
    assert main(["solve", str(SAMPLES / name), "--json", str(out)]) == 0
    cc = json.loads(out.read_text())["cross_check"]
    truth = json.loads((SAMPLES / "bracket_truth.json").read_text())
    assert _rel(cc["mass_kg"], truth["mass_kg"]) < mass_rel
    assert np.max(np.abs(np.subtract(cc["cg_m"], truth["cg_m"]))) < cg_m
    assert cc["agrees"]["all"] is True
