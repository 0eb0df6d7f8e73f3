"""``dimacq simulate``: scenario FRFs in UFF and truth in JSON that ``dimacq solve`` turns back
into the truth."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from dimacq.cli.main import main


def _errors(sol: dict, truth: dict, size_m: float) -> tuple[float, float, float]:
    it = np.array(truth["inertia_p_kgm2"])
    return (
        abs(sol["mass_kg"] / truth["mass_kg"] - 1),
        float(np.abs(np.array(sol["cg_m"]) - truth["cg_m"]).max() / size_m),
        float(np.abs(np.array(sol["inertia_p_kgm2"]) - it).max() / np.linalg.eigvalsh(it).max()),
    )


def test_list_names_every_scenario(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["simulate", "--list"]) == 0
    out = capsys.readouterr().out
    for name in (
        "calibration-mass-bungee",
        "calibration-mass-air-ride",
        "calibration-mass-ground",
        "x38",
        "cube-0.02",
        "cube-2",
        "cube-200",
    ):
        assert name in out


@pytest.mark.slow
@pytest.mark.parametrize(("name", "size"), [("calibration-mass-ground", 0.3), ("cube-200", 200.0)])
def test_rigid_only_model_frfs_solve_to_the_truth(tmp_path: Path, name: str, size: float) -> None:
    uff, truth, sol = tmp_path / "t.uff", tmp_path / "truth.json", tmp_path / "sol.json"
    assert main(["simulate", name, "--rigid-only", "--frf", str(uff), "--truth", str(truth)]) == 0
    t = json.loads(truth.read_text())
    assert t["scenario"] == name and {"mass_kg", "cg_m", "inertia_p_kgm2"} <= set(t)
    rc = main(["solve", str(uff), "--json", str(sol)])
    s = json.loads(sol.read_text())
    assert max(_errors(s, t, size)) < 1e-9  # exact FRFs: the estimate is the truth
    assert rc == 0  # the refined geometry: the redundancy of exact FRFs identifies it
    if size >= 100:
        # with the stated geometry taken as exact, the default geometry uncertainty (0.5° triax
        # orientation) leaves the principal moments of the 200 m cube unknown to ±thousands of %
        # (thesis Table 5): refused with why
        rc = main(["solve", str(uff), "--json", str(sol), "--no-refine-geometry"])
        s = json.loads(sol.read_text())
        assert rc == 3 and s["verdict"] == "fail"
        prec = next(r for r in s["verdict_reasons"] if r["check"] == "precision")
        assert prec["severity"] == "fail" and "I1 ±" in prec["message"]


@pytest.mark.slow
def test_flexible_x38_in_its_recommended_band_is_within_half_a_percent(tmp_path: Path) -> None:
    uff, truth, sol = tmp_path / "x.uff", tmp_path / "truth.json", tmp_path / "sol.json"
    assert main(["simulate", "x38", "--frf", str(uff), "--truth", str(truth)]) == 0
    t = json.loads(truth.read_text())
    lo, hi = t["recommended"]["band_hz"]
    args = ["solve", str(uff), "--band", str(lo), str(hi), "--json", str(sol)]
    assert main([*args, "--select-responses"]) == 0
    s = json.loads(sol.read_text())
    assert max(_errors(s, t, 9.0)) < 5e-3
    pm, pt = np.array(s["principal_moments_kgm2"]), np.array(t["principal_moments_kgm2"])
    assert np.abs(pm / pt - 1).max() < 5e-3
    # the default solve selects responses too: the chute triaxes go, the answer is as good
    assert main(args) == 0
    assert max(_errors(json.loads(sol.read_text()), t, 9.0)) < 5e-3
    # without leaving out the chute triaxes the elastic modes spoil the equation-error answer
    # (the default estimator's refinement would leave the chute nodes out as gross errors)
    # (and without the modal correction, which would take the chute's modes out: its own tests)
    plain = ["--no-select", "--no-unbiased", "--no-refine-geometry", "--modal-correction", "off"]
    assert main([*args, *plain]) in (0, 3)
    assert max(_errors(json.loads(sol.read_text()), t, 9.0)) > 2e-2
    # the default (selection, output error with the geometry refined) stays within 0.5 %
    assert main(args) == 0
    assert max(_errors(json.loads(sol.read_text()), t, 9.0)) < 5e-3


def test_time_domain_and_noise_options(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    uff, truth, sol = tmp_path / "c.uff", tmp_path / "truth.json", tmp_path / "sol.json"
    assert (
        main(
            [
                "simulate",
                "cube-2",
                "--time-domain",
                "--noise",
                "0",
                "--seed",
                "3",
                "--frf",
                str(uff),
                "--truth",
                str(truth),
            ]
        )
        == 0
    )
    assert "time domain: 30 strikes" in capsys.readouterr().out
    rc = main(["solve", str(uff), "--band", "20", "60", "--json", str(sol)])
    s = json.loads(sol.read_text())
    assert max(_errors(s, json.loads(truth.read_text()), 2.0)) < 1e-6
    assert rc == 0  # the refined geometry: the noise-free FRFs identify it
    args = ["solve", str(uff), "--band", "20", "60", "--json", str(sol), "--no-refine-geometry"]
    rc = main(args)
    s = json.loads(sol.read_text())
    assert max(_errors(s, json.loads(truth.read_text()), 2.0)) < 1e-6
    # the estimate is the truth, but with inputs near the origin (moment arms of centimetres) the
    # default geometry uncertainty (2 mm, 0.5°, 1°) taken as it is leaves the mass unknown to
    # tens of %: refused
    assert rc == 3 and s["verdict"] == "fail"
    prec = next(r for r in s["verdict_reasons"] if r["check"] == "precision")
    assert prec["severity"] == "fail" and "mass ±" in prec["message"]


def test_bad_scenarios_exit_2_naming_the_fix(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["simulate", "moon-lander", "--truth", str(tmp_path / "t.json")]) == 2
    assert "dimacq simulate --list" in capsys.readouterr().err
    bad = tmp_path / "bad.toml"
    bad.write_text(
        'schema_version = 1\nname = "b"\n[article]\nmodel = "cube"\n[band]\nlo_hz = 1\nhi_hz = 2\n'
    )
    assert main(["simulate", str(bad), "--truth", str(tmp_path / "t.json")]) == 2
    err = capsys.readouterr().err
    assert "half_size_m" in err and "fix:" in err
    assert main(["simulate", "cube-2"]) == 2
    assert "--frf" in capsys.readouterr().err


@pytest.mark.slow
@pytest.mark.parametrize("excitation", ["random", "swept-sine"])
def test_shaker_time_domain_solves_to_the_truth(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], excitation: str
) -> None:
    uff, truth, sol = tmp_path / "s.uff", tmp_path / "truth.json", tmp_path / "sol.json"
    args = ["simulate", "cube-2", "--time-domain", "--excitation", excitation, "--shakers", "2"]
    assert main([*args, "--frf", str(uff), "--truth", str(truth)]) == 0
    out = capsys.readouterr().out
    assert f"{excitation} excitation, 2 shakers × 3 positions" in out
    t = json.loads(truth.read_text())
    assert t["excitation"] == excitation
    rc = main(["solve", str(uff), "--band", "20", "60", "--json", str(sol)])
    s = json.loads(sol.read_text())
    assert max(_errors(s, t, 2.0)) < 2e-3
    assert rc == 0  # the refined geometry
    rc = main(["solve", str(uff), "--band", "20", "60", "--json", str(sol), "--no-refine-geometry"])
    s = json.loads(sol.read_text())
    assert max(_errors(s, t, 2.0)) < 2e-3
    # refused for the default geometry uncertainty taken as it is, as the impact test on this cube
    assert rc == 3 and s["verdict"] == "fail"
    prec = next(r for r in s["verdict_reasons"] if r["check"] == "precision")
    assert prec["severity"] == "fail" and "mass ±" in prec["message"]


def test_shaker_options_need_the_time_domain(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    t = str(tmp_path / "t.json")
    assert main(["simulate", "cube-2", "--excitation", "random", "--truth", t]) == 2
    assert "--time-domain" in capsys.readouterr().err
    assert main(["simulate", "cube-2", "--time-domain", "--shakers", "2", "--truth", t]) == 2
    assert "--excitation" in capsys.readouterr().err
    args = ["simulate", "cube-2", "--time-domain", "--excitation", "random", "--shakers", "9"]
    assert main([*args, "--truth", t]) == 2
    assert "shakers" in capsys.readouterr().err
