"""``dimacq serve`` (a real process on loopback) and ``dimacq demo`` (the whole simulated test
through the HTTP API) against the scenario's truth."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import httpx
import numpy as np

from dimacq.api.server import free_port
from dimacq.cli.main import main


def test_serve_binds_loopback_and_needs_the_token(tmp_path: Path) -> None:
    port = free_port()
    env = {**os.environ, "DIMACQ_TOKEN": "", "DIMACQ_DIGITIZER_URL": f"simdigitizer://serve{port}"}
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "dimacq.cli.main",
            "serve",
            "--port",
            str(port),
            "--data-dir",
            str(tmp_path),
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        env=env,
        text=True,
    )
    try:
        deadline = time.monotonic() + 30
        while True:
            try:
                r = httpx.get(f"http://127.0.0.1:{port}/api/status", timeout=1)
                break
            except httpx.TransportError:
                assert proc.poll() is None, proc.stderr.read() if proc.stderr else ""
                assert time.monotonic() < deadline, "dimacq serve did not start"
                time.sleep(0.1)
        assert r.status_code == 200 and r.json()["devices"]["digitizer"]["connected"]
        token = (tmp_path / "token").read_text().strip()
        assert oct((tmp_path / "token").stat().st_mode & 0o777) == "0o600"
        assert (
            httpx.post(f"http://127.0.0.1:{port}/api/devices/digitizer/connect").status_code == 401
        )
        ok = httpx.post(
            f"http://127.0.0.1:{port}/api/devices/digitizer/connect",
            headers={"Authorization": f"Bearer {token}"},
        )
        assert ok.status_code == 200 and ok.json()["connected"]
        assert (tmp_path / "dimacq.sqlite").exists()
    finally:
        proc.send_signal(signal.SIGINT)
        out, _err = proc.communicate(timeout=20)
    assert "http://127.0.0.1:" in out and token in out


def test_demo_recovers_the_truth(tmp_path: Path, capsys) -> None:
    out = tmp_path / "demo.json"
    assert main(["demo", "--json", str(out), "--averages", "3"]) == 0
    text = capsys.readouterr().out
    assert "DIM result vs truth" in text and "[5/5]" in text
    p = json.loads(out.read_text())
    for key in (
        "mass_kg",
        "cg_m",
        "inertia_cg_kgm2",
        "principal_moments_kgm2",
        "band_hz",
        "rank",
        "condition_number",
        "diagnostics",
        "truth",
        "elapsed_s",
    ):
        assert key in p
    t = p["truth"]
    props = {
        "mass_kg",
        "cg_m",
        "inertia_p_kgm2",
        "inertia_cg_kgm2",
        "principal_moments_kgm2",
        "principal_axes",
        "reference_point_m",
        "product_sign_convention",
    }
    assert props <= set(t) and props <= set(p)  # the truth uses the solve JSON's keys
    # Honest simulation: the service reads the rig file's certificates, not the transducers'
    # true sensitivities. Every FRF is then scaled by (true/certificate) of the hammer and of
    # each accelerometer, so mass and inertia carry that scale (the CG, a ratio, does not).
    scale = _calibration_scale()
    assert abs(scale - 1) > 0.002  # the simulated transducers are not their certificates
    assert abs(p["mass_kg"] / (scale * t["mass_kg"]) - 1) < 0.003, (p["mass_kg"], scale)
    assert np.linalg.norm(np.subtract(p["cg_m"], t["cg_m"])) < 1e-3
    np.testing.assert_allclose(
        p["principal_moments_kgm2"], scale * np.asarray(t["principal_moments_kgm2"]), rtol=0.005
    )
    assert p["demo"]["points_digitized"] == 6 + 8 * 24 + 24 * 4
    assert p["demo"]["orientation_error_rms_deg"] < 0.1
    assert p["elapsed_s"] < 120
    assert p["demo"]["acquisition"].startswith("impact test through the simulated DAQ")


def _calibration_scale() -> float:
    """``(true/certificate of the hammer) × mean(certificate/true of the accelerometers)``: the
    factor a rig file's calibration errors put on the measured mass (first order)."""
    from dimacq.config import load_settings
    from dimacq.io.rig_file import load_rig_file
    from dimacq.simulators.lab import transducers as tr

    rf = load_rig_file(load_settings().rig_path)
    (h,) = rf.hammers
    hammer = tr.true_sensitivity(
        tr.NOMINAL_HAMMER_MV_PER_N, tr.HAMMER_TOLERANCE, tr.hammer_serial(h.physical_channel)
    )
    accel = [
        r.sensitivity_mv_per_g
        / tr.true_sensitivity(
            tr.NOMINAL_ACCEL_MV_PER_G,
            tr.ACCEL_TOLERANCE,
            tr.accelerometer_serial(r.physical_channel),
        )
        for r in rf.responses
    ]
    return float(hammer / h.sensitivity_mv_per_n * np.mean(accel))
