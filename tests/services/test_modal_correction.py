"""The modal correction as a step of the analysis (issue 25, part 1): ``auto`` leaves rigid cases
exactly as they were, corrects an elastically contaminated one and says why; on/off."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from dimacq.cli.commands.solve import load_test
from dimacq.errors import SetupError
from dimacq.model.properties import principal_moments
from dimacq.services.solve.analysis import AnalysisOptions, analyse
from dimacq.simulators.lab.scenarios import build_scenario

ROOT = Path(__file__).resolve().parents[2]
#: A lighter analysis for the tests (the correction's logic is the same).
FAST = {"geometry_samples": 40, "refine_geometry": False, "unbiased": False}


def test_default_is_unchanged_on_the_bundled_rigid_example() -> None:
    setup, frf = load_test(
        ROOT / "config/examples/six_triax_setup.toml", ROOT / "config/examples/six_triax_frf.uff"
    )
    auto = analyse(frf, setup, AnalysisOptions(**FAST))
    off = analyse(frf, setup, AnalysisOptions(modal_correction="off", **FAST))
    np.testing.assert_array_equal(auto.result.parameters, off.result.parameters)
    assert auto.result.band_hz == off.result.band_hz
    assert auto.verdict == off.verdict
    assert auto.to_json().keys() == off.to_json().keys()
    assert "modal_correction" not in auto.to_json()


def test_default_is_unchanged_on_a_rigid_scenario_with_noise() -> None:
    b = build_scenario("calibration-mass-bungee", 1)
    frf = b.model_frf(noise=0.01)
    auto = analyse(frf, b.setup, AnalysisOptions(**FAST))
    off = analyse(frf, b.setup, AnalysisOptions(modal_correction="off", **FAST))
    np.testing.assert_array_equal(auto.result.parameters, off.result.parameters)
    assert auto.modal_correction is None


def test_auto_corrects_a_flexible_vehicle_and_says_why() -> None:
    """Hull modes at 17/24/31 Hz (3.6–6.5× the top suspension mode), 0.5 % noise: the plain
    analysis's band is contaminated; ``auto`` takes the three modes out, solves across them and
    lands within the issue's limits (0.3 % mass, 10 mm CG, 1 % principal moments)."""
    b = build_scenario("x38-flexible-17", 2)
    frf = b.model_frf(noise=0.005)
    rep = analyse(frf, b.setup, AnalysisOptions(**FAST))
    mc = rep.modal_correction
    assert mc is not None and mc.applied, mc
    out = rep.to_json()["modal_correction"]
    assert "applied" in out["reason"]
    assert len(out["modes_removed_hz"]) == 3
    np.testing.assert_allclose(
        out["modes_removed_hz"], b.model.natural_frequencies_hz()[-3:], rtol=0.01
    )
    assert out["correction_size"]["max"] > 0.01
    assert len(out["correction_size"]["relative"]) == len(out["correction_size"]["frequencies_hz"])
    assert "modal_fit" in rep.uncertainty.components
    assert any(r.check == "modal_correction" for r in rep.verdict_reasons)
    assert rep.result.band_hz[1] > 20.0  # the band now reaches across the modes
    t = b.truth
    p = rep.result.properties
    assert abs(p.mass_kg / t.mass_kg - 1) < 0.003
    assert np.linalg.norm(p.cg_m - t.cg_m) < 0.010
    w, _ = principal_moments(p.inertia_cg_kgm2)
    wt, _ = principal_moments(t.inertia_cg_kgm2)
    assert np.max(np.abs(w / wt - 1)) < 0.01
    off = analyse(frf, b.setup, AnalysisOptions(modal_correction="off", **FAST))
    assert np.linalg.norm(off.result.properties.cg_m - t.cg_m) > np.linalg.norm(p.cg_m - t.cg_m)


def test_modal_correction_option_is_checked() -> None:
    b = build_scenario("calibration-mass-bungee", 0)
    with pytest.raises(SetupError, match="modal_correction = 'maybe'; give auto, on or off"):
        analyse(b.model_frf(), b.setup, AnalysisOptions(modal_correction="maybe"))
