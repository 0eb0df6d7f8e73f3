"""``dimacq acquire`` and ``dimacq loadcell calibrate --simulated`` end to end (short runs).

The full-size figures (24 inputs × 5 averages) are in tests/scripts/acquisition_must_show.py.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from _acq_support import calibration_scale, no_leaks

from dimacq.cli.main import main
from dimacq.config import Settings, scenario_rig_file
from dimacq.io.loadcell_calibration import read_calibration_json
from dimacq.io.rig_file import load_rig_file
from dimacq.io.uff import read_uff_test
from dimacq.simulators.lab.forward import CALIBRATION_MASS

__all__ = ["no_leaks"]


@pytest.mark.slow
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


@pytest.mark.slow
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
    # the bench's accelerometers are known by their certificates (0.5 % σ, config/rig.toml):
    # their scatter is taken out by the rigid-body gains, their common scale is in the matrix
    # and in its uncertainty
    assert res["matrix_error_rel"] < res["matrix_uncertainty_rel"] < 3e-3
    eta_h, eta_a = _chain_errors_pct()
    # the calibrated cell reads with the accelerometers' scale
    _circular_is_the_chain_against_the_cell(res, eta_a)
    # the bench sees the hammer against the accelerometers: stated / implied sensitivity
    ratio = res["fit"]["hammer_sensitivity_ratio"]
    assert abs(100 * (1 / ratio - 1) - (eta_h - eta_a)) < 0.3, (ratio, eta_h, eta_a)
    assert "circular check" in capsys.readouterr().out
    cal = read_calibration_json(mat)
    np.testing.assert_allclose(cal.matrix, np.array(res["matrix"]))
    assert cal.method == "inertial"


def _chain_errors_pct() -> tuple[float, float]:
    """How far the simulated hammer and accelerometers read from the truth through the rig
    file (independent answer: the simulated transducers' true sensitivities): the hammer's
    ``η_h`` (certificate × recorded chain calibration, what the acquisition uses) and the
    accelerometers' common scale ``η_a`` (log-mean; their scatter the rigid-body gains take
    out), in %."""
    from dimacq.simulators.lab import transducers as tr

    rig = load_rig_file(Settings(rig_file="").rig_path)
    hammer = rig.hammers[0]
    true = tr.true_sensitivity(
        tr.NOMINAL_HAMMER_MV_PER_N, tr.HAMMER_TOLERANCE, tr.hammer_serial(hammer.physical_channel)
    )
    eta_h = 100 * (true / hammer.effective_sensitivity_mv_per_n - 1)
    acc = [
        tr.true_sensitivity(
            tr.NOMINAL_ACCEL_MV_PER_G,
            tr.ACCEL_TOLERANCE,
            tr.accelerometer_serial(r.physical_channel),
        )
        / r.sensitivity_mv_per_g
        for r in rig.responses
    ]
    eta_a = 100 * float(np.expm1(np.mean(np.log(acc))))
    return eta_h, eta_a


def _circular_is_the_chain_against_the_cell(res: dict, cell_pct: float) -> float:
    """Standing on the cell, DIM's mass error is ``s_c η_c + (1 − s_c) η_h − η_a`` (cell,
    hammer and accelerometers reading ``1 + η`` of the truth; ``s_c`` the check's cell
    sensitivity), ``η_c`` the cell's scale error through its new matrix; the verdict follows
    the tolerance."""
    eta_h, eta_a = _chain_errors_pct()
    s_c = res["circular_cell_sensitivity"]
    assert s_c > 1.0  # standing on the cell: the check sees the cell, amplified
    expected = s_c * cell_pct + (1 - s_c) * eta_h - eta_a
    assert abs(res["circular_mass_error_pct"] - expected) < 0.3, (res, expected)
    ok = abs(res["circular_mass_error_pct"]) <= res["circular_tolerance_pct"]
    assert res["circular_verdict"] == ("ok" if ok else "fail")
    # the reported chain share (k = 2) covers what the chain put in
    assert abs((1 - s_c) * eta_h - eta_a) <= res["circular_chain_uncertainty_pct"]
    return expected


@pytest.mark.slow
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
    _circular_is_the_chain_against_the_cell(res, 0.0)  # dead weights: the cell's true scale
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


def test_acquire_with_incomplete_inputs_keeps_the_rest_and_says_why(tmp_path, capsys, monkeypatch):
    """Issue 22: inputs whose averages were all rejected (faults) have no FRF; the command writes
    the complete inputs' FRFs and ends with that reason, naming the inputs by point and direction,
    instead of failing on "inputs of the setup and of the FRFs differ". The session is replaced
    by one whose inputs 2 and 5 had every hit rejected (the path through the devices is the
    first test's)."""
    from dataclasses import replace

    import dimacq.services.acquisition.rig as rig_mod
    from dimacq.simulators.lab.scenarios import build_scenario

    built = build_scenario("calibration-mass-bungee", 0)
    lost = {1, 4}

    def session(rig, setup, cfg, *, on_average, on_progress, **_kw):
        frf = built.model_frf(noise=0.0)
        record = {"force": np.zeros((1, 64)), "outputs": np.zeros((frf.H.shape[1], 64))}
        for j in range(len(setup.excitations)):
            ok = j not in lost
            on_average(j, j, ok, [] if ok else ["load cell 0 samples lost (12)"], record)
        keep = [j for j in range(frf.H.shape[2]) if j not in lost]
        meta = {**frf.meta, "incomplete_inputs": [setup.excitations[j].name for j in sorted(lost)]}
        return replace(
            frf, H=frf.H[:, :, keep], inputs=tuple(frf.inputs[j] for j in keep), meta=meta
        )

    monkeypatch.setattr(rig_mod, "run_impact_test", session)
    uff = tmp_path / "part.uff"
    rc = main(
        ["acquire", "calibration-mass-bungee", "--seed", "0", "--averages-per-input", "1",
         "--frf", str(uff), "--json", str(tmp_path / "acq.json"), "-q"]
    )  # fmt: skip
    assert rc == 2
    err = capsys.readouterr().err
    names = [built.setup.excitations[j].name for j in sorted(lost)]
    assert "acquisition incomplete: 2 of 24 inputs" in err
    assert all(n in err for n in names) and "samples lost" in err
    assert "holds the FRFs of the 22 complete inputs" in err
    setup, frf = read_uff_test(uff)  # what was acquired is kept
    assert frf.H.shape[2] == 22 and len(setup.excitations) == 22
    summary = json.loads((tmp_path / "acq.json").read_text())
    assert summary["incomplete_inputs"] == names


def _averages(folder: Path, acq_id: int) -> list[dict]:
    """The averages acquisition ``acq_id`` of the data folder ``folder`` keeps (its array
    files, as the service writes them): their attributes and records, in number order."""
    from dimacq.persistence import ArrayStore

    store = ArrayStore(folder / "arrays")
    out = []
    for p in sorted((folder / "arrays" / "acquisitions" / f"{acq_id:06d}").glob("avg-*.h5")):
        arrays, attrs = store.read(p.relative_to(folder / "arrays").as_posix())
        out.append({**attrs, "record": {k: np.asarray(v) for k, v in arrays.items()}})
    return out


@pytest.mark.slow
def test_acquire_interrupted_resumes_striking_only_the_missing_averages(
    tmp_path, capsys, monkeypatch, no_leaks
):
    """An acquisition with --data stopped by Ctrl-C once input 11 has begun (the first ten
    complete) is continued with --resume through the service's resume: every input ends with its
    two accepted averages, an input complete when interrupted is not struck again (no new
    average of it), one partly struck gets only its missing ones, and the complete inputs' FRFs
    are those of the averages kept (estimated from their files)."""
    from dimacq.cli.progress import ProgressLine
    from dimacq.model.impact import ImpactSettings
    from dimacq.services.acquisition.impact_result import records_frf
    from dimacq.simulators.lab.scenarios import build_scenario

    raw = tmp_path / "raw"
    args = ["acquire", "calibration-mass-bungee", "--averages-per-input", "2",
            "--record-samples", "1024", "--data", str(raw), "-q"]  # fmt: skip
    update = ProgressLine.update

    def interrupt_after_ten_inputs(self, fraction, message=""):
        update(self, fraction, message)
        if fraction > 20 / 48:  # input 11's first average accepted (2 × 10 of 2 × 24 before)
            raise KeyboardInterrupt

    monkeypatch.setattr(ProgressLine, "update", interrupt_after_ten_inputs)
    with pytest.raises(KeyboardInterrupt):
        main([*args, "--frf", str(tmp_path / "x.uff")])
    monkeypatch.setattr(ProgressLine, "update", update)
    first = _averages(raw, 1)
    kept = [
        [a["record"] for a in first if a["input_index"] == j and a["accepted"]] for j in range(24)
    ]
    assert all(len(k) == 2 for k in kept[:10]) and len(kept[10]) >= 1
    assert sum(map(len, kept)) < 48, "interrupted before the end"
    capsys.readouterr()
    # the folder holds an acquisition: not overwritten without --resume
    assert main([*args, "--frf", str(tmp_path / "x.uff")]) == 2
    assert "--resume" in capsys.readouterr().err
    assert (
        main([*args, "--resume", "--averages-per-input", "3", "--frf", str(tmp_path / "x.uff")])
        == 2
    )
    assert "differs from the interrupted acquisition's 2" in capsys.readouterr().err
    rc = main([*args, "--resume", "--frf", str(tmp_path / "resumed.uff"),
               "--json", str(tmp_path / "acq.json")])  # fmt: skip
    assert rc == 0, capsys.readouterr().err
    summary = json.loads((tmp_path / "acq.json").read_text())
    assert summary["averages_accepted"] == [2] * 24
    new = _averages(raw, 2)
    for j in range(24):  # nothing struck again that was kept: only what was missing
        mine = [a for a in new if a["input_index"] == j]
        assert sum(a["accepted"] for a in mine) == 2 - len(kept[j]), j
        if len(kept[j]) == 2:
            assert not mine, f"input {j} was complete and was struck again"
    assert (raw / "acquisition.h5").exists() and (raw / "acquisition-resumed-1.h5").exists()
    complete = [j for j in range(24) if len(kept[j]) == 2]
    setup = build_scenario("calibration-mass-bungee", 0).setup
    struck = setup.model_copy(update={"excitations": tuple(setup.excitations[j] for j in complete)})
    applied = ImpactSettings.model_validate(
        json.loads((raw / "acquisition.json").read_text())["applied"]
    )
    expected = records_frf([kept[j] for j in complete], first[0]["sample_rate_hz"], applied, struck)
    with np.load(raw / "frf.npz") as z:
        np.testing.assert_array_equal(z["H"][:, :, complete], expected.H)
    _, frf = read_uff_test(tmp_path / "resumed.uff")
    assert frf.H.shape[2] == 24
    # every input complete: nothing left to resume
    assert main([*args, "--resume", "--frf", str(tmp_path / "x.uff")]) == 2
    assert "nothing to strike" in capsys.readouterr().err


@pytest.mark.slow
def test_acquire_killed_resumes_striking_only_the_missing_averages(tmp_path, capsys, no_leaks):
    """``dimacq acquire --data`` killed (SIGKILL: no cleanup at all) once five averages are
    stored is continued with --resume: the service finds its acquisition running when it died
    (interrupted), and only the inputs without their accepted average are struck."""
    import signal
    import subprocess
    import sys
    import time

    raw = tmp_path / "raw"
    args = ["acquire", "calibration-mass-bungee", "--averages-per-input", "1",
            "--record-samples", "1024", "--data", str(raw), "-q"]  # fmt: skip
    cmd = [sys.executable, "-m", "dimacq.cli.main", *args, "--frf", str(tmp_path / "x.uff")]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    folder = raw / "arrays" / "acquisitions" / "000001"
    try:
        deadline = time.monotonic() + 600
        while len(list(folder.glob("avg-*.h5"))) < 5:
            assert proc.poll() is None, proc.stderr.read().decode() if proc.stderr else ""
            assert time.monotonic() < deadline, "no five averages stored in 10 min"
            time.sleep(0.05)
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait()
        if proc.stderr is not None:
            proc.stderr.close()
    first = _averages(raw, 1)
    kept = [sum(a["accepted"] for a in first if a["input_index"] == j) for j in range(24)]
    assert 0 < sum(kept) < 24, kept
    rc = main([*args, "--resume", "--frf", str(tmp_path / "resumed.uff"),
               "--json", str(tmp_path / "acq.json")])  # fmt: skip
    assert rc == 0, capsys.readouterr().err
    assert json.loads((tmp_path / "acq.json").read_text())["averages_accepted"] == [1] * 24
    new = _averages(raw, 2)
    for j in range(24):
        mine = [a for a in new if a["input_index"] == j]
        assert sum(a["accepted"] for a in mine) == 1 - kept[j], j
        if kept[j]:
            assert not mine, f"input {j} had its average and was struck again"
    _, frf = read_uff_test(tmp_path / "resumed.uff")
    assert frf.H.shape[2] == 24
