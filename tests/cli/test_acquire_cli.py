"""``dimacq acquire`` and ``dimacq loadcell calibrate --simulated`` end to end (short runs).

The full-size figures (24 inputs × 5 averages) are in tests/scripts/acquisition_must_show.py.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from _acq_support import calibration_scale, no_leaks

from dimacq.cli.main import main
from dimacq.config import Settings, scenario_rig_file
from dimacq.io.loadcell_calibration import read_calibration_json
from dimacq.io.rig_file import load_rig_file
from dimacq.io.uff import read_uff_test
from dimacq.simulators.lab.forward import CALIBRATION_MASS

__all__ = ["no_leaks"]


def test_acquire_writes_a_uff_that_solve_reads(tmp_path, capsys, no_leaks):
    """Through the service's rig (backends ``simulated``, the scenario's rig file): the drivers
    know the certificates, not the simulated transducers, so the mass carries the rig file's
    calibration factor."""
    uff = tmp_path / "cm.uff"
    rc = main(
        [
            "acquire",
            "calibration-mass-bungee",
            "--impacts-per-input",
            "1",
            "--frf",
            str(uff),
            "--data",
            str(tmp_path / "raw"),
            "--json",
            str(tmp_path / "acq.json"),
        ]
    )
    assert rc == 0
    cap = capsys.readouterr()
    assert "24 inputs × 1 averages" in cap.out
    # progress off a terminal: plain lines, no carriage return, the last at 100 % (the time left
    # depends on the wall clock: tests/cli/test_cli_contract.py checks it on a fake clock)
    assert "\r" not in cap.err
    assert "acquire: 100.0 %  [24/24]" in cap.err.splitlines()[-1]
    summary = json.loads((tmp_path / "acq.json").read_text())
    assert summary["averages_accepted"] == [1] * 24 and summary["n_responses"] == 30
    assert (tmp_path / "raw" / "acquisition.h5").stat().st_size > 1e6
    with np.load(tmp_path / "raw" / "frf.npz") as z:
        assert z["coherence"].shape == (2048, 30, 24)
    setup, frf = read_uff_test(uff)
    assert len(setup.load_cells) == 1 and frf.H.shape == (2048, 30, 24)
    assert [k for k in frf.output_kinds].count("reaction") == 6
    rc = main(["solve", str(uff), "--band", "20", "400", "--json", str(tmp_path / "sol.json")])
    assert rc == 0
    sol = json.loads((tmp_path / "sol.json").read_text())
    assert summary["rig_file"] == str(
        Settings(rig_file=scenario_rig_file("calibration-mass-bungee")).rig_path
    )
    # the simulated transducers are not their certificates; the rig file's hammer carries the
    # chain calibration measured on the reference block (chain_calibration), which removes most
    # of it: what is left is the accelerometers' certificate errors (mean of 24)
    raw = calibration_scale(Path(summary["rig_file"]), chain=False)
    scale = calibration_scale(Path(summary["rig_file"]))
    assert abs(raw - 1) > 0.005 and abs(scale - 1) < 0.002, (raw, scale)
    mass = sol["mass_kg"]
    assert abs(mass / (scale * CALIBRATION_MASS.mass_kg) - 1) < 5e-3, (mass, scale)
    assert abs(mass / CALIBRATION_MASS.mass_kg - 1) < 5e-3, mass
    assert sol["verdict"] == "ok"


def test_acquire_refuses_unknown_scenario(tmp_path, capsys):
    rc = main(["acquire", "nope", "--impacts-per-input", "1", "--frf", str(tmp_path / "a.uff")])
    assert rc != 0
    assert "scenario 'nope' is unknown" in capsys.readouterr().err


def test_loadcell_calibrate_simulated(tmp_path, capsys, no_leaks):
    out = tmp_path / "cal.json"
    mat = tmp_path / "lc501.json"
    rc = main(
        [
            "loadcell",
            "calibrate",
            "--simulated",
            "--impacts-per-input",
            "1",
            "--json",
            str(out),
            "--matrix",
            str(mat),
        ]
    )
    assert rc == 0
    res = json.loads(out.read_text())
    assert res["method"] == "inertial" and res["nonlinearity_pct_fs"] is None
    assert len(res["uncertainty_pct_fs"]) == 6
    # the bench's accelerometers are known by their certificates (0.5 % σ, config/rig.toml)
    assert res["matrix_error_rel"] < 1.5e-2
    expected = _circular_is_the_hammer_certificate(res)
    # the bench sees the hammer's error too: stated / true sensitivity
    ratio = res["fit"]["hammer_sensitivity_ratio"]
    assert abs(100 * (1 / ratio - 1) - expected) < 0.3, (ratio, expected)
    assert "circular check" in capsys.readouterr().out
    cal = read_calibration_json(mat)
    np.testing.assert_allclose(cal.matrix, np.array(res["matrix"]))
    assert cal.method == "inertial"


def _circular_is_the_hammer_certificate(res: dict) -> float:
    """DIM's mass scales with the hammer force: through a good cell calibration the circular
    check's mass error is the rig file's hammer sensitivity error (independent answer: the
    simulated hammer's true sensitivity), and the verdict follows the tolerance."""
    from dimacq.simulators.lab import transducers as tr

    hammer = load_rig_file(Settings(rig_file="").rig_path).hammers[0]
    true = tr.true_sensitivity(
        tr.NOMINAL_HAMMER_MV_PER_N, tr.HAMMER_TOLERANCE, tr.hammer_serial(hammer.physical_channel)
    )
    # what the acquisition uses: the certificate × the recorded chain calibration
    expected = 100 * (true / hammer.effective_sensitivity_mv_per_n - 1)
    assert abs(res["circular_mass_error_pct"] - expected) < 0.3, (res, expected)
    ok = abs(res["circular_mass_error_pct"]) <= res["circular_tolerance_pct"]
    blind = res["circular_cell_sensitivity"] < 0.05  # hung on bungees: the cell is hardly loaded
    assert res["circular_verdict"] == ("fail" if not ok else "inconclusive" if blind else "ok")
    return expected


def test_loadcell_calibrate_static_simulated_json_contract(tmp_path, capsys, no_leaks):
    out = tmp_path / "static.json"
    rc = main(
        [
            "loadcell",
            "calibrate",
            "--simulated",
            "--method",
            "static",
            "--plan",
            "minimal",
            "--impacts-per-input",
            "1",
            "--json",
            str(out),
            "--xml",
            str(tmp_path / "lc.xml"),
        ]
    )
    assert rc == 0
    res = json.loads(out.read_text())
    assert res["method"] == "static"
    assert res["matrix_error_rel"] < 1e-3
    for key in ("nonlinearity_pct_fs", "hysteresis_pct_fs", "uncertainty_pct_fs"):
        assert len(res[key]) == 6
    np.testing.assert_allclose(res["nonlinearity_pct_fs"], 0.05, rtol=0.1)  # simulated 0.05 %
    np.testing.assert_allclose(res["hysteresis_pct_fs"], 0.03, rtol=0.1)  # simulated 0.03 %
    _circular_is_the_hammer_certificate(res)
    assert "static calibration" in capsys.readouterr().out
    from dimacq.io.loadcell_calibration import read_calibration

    cal = read_calibration(tmp_path / "lc.xml")
    assert cal.method == "static" and cal.gauge_unit == "mV/V"


def test_loadcell_calibrate_refuses_piezo_and_the_shipped_simulated_rig(capsys):
    rc = main(["loadcell", "calibrate", "--simulated", "--method", "static", "--gauges", "piezo"])
    assert rc == 2
    assert "AC-coupled" in capsys.readouterr().err
    rc = main(["loadcell", "calibrate", "--method", "inertial"])
    assert rc == 2  # the shipped configuration is the simulated lab: its files stay as they are
    assert "use --simulated" in capsys.readouterr().err
