"""Issue 23's must-show for the USB-1808X: ``DIMACQ_DAQ=mcc-usb-simulated dimacq demo`` runs the
whole simulated test through the MCC driver and its pyusb simulator (five units, 37 inputs, one
master clock) within 0.5 % mass, 1 mm CG, 0.5 % principal moments, and names the backend.

Without step 0 (``--no-chain-calibration``: the rig file's recorded chain calibration applies):
step 0 is a second impact test, of the reference block, through the same driver, and its factor
would absorb a common scale error of the MCC path (a wrong range, gain or calibration
coefficient) that this test exists to see; the demo's step 0 is tested through the default DAQ
(tests/cli/test_serve_demo.py). 35 s -> 13 s of CPU."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from dimacq.cli.main import main


@pytest.mark.slow
def test_demo_through_the_usb_1808x(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.setenv("DIMACQ_DAQ", "mcc-usb-simulated")
    out = tmp_path / "demo.json"
    args = ["demo", "--json", str(out), "--averages", "3", "--data-dir", str(tmp_path)]
    assert main([*args, "--no-chain-calibration"]) == 0
    text = capsys.readouterr().out
    assert "daq = 'mcc-usb-simulated'" in text and "USB-1808X" in text
    p = json.loads(out.read_text())
    t = p["truth"]
    assert abs(p["mass_kg"] / t["mass_kg"] - 1) < 0.005, p["mass_kg"]
    assert np.linalg.norm(np.subtract(p["cg_m"], t["cg_m"])) < 1e-3
    np.testing.assert_allclose(p["principal_moments_kgm2"], t["principal_moments_kgm2"], rtol=0.005)
    assert "chain_calibration" not in p["demo"]  # no step 0: the MCC path's own scale is seen
    assert p["demo"]["acquisition"].startswith(
        "impact test through the simulated Measurement Computing USB-1808X units"
    )
