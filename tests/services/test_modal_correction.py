"""The modal correction as a step of the analysis (issue 25, part 1): ``auto`` leaves rigid cases
exactly as they were, corrects an elastically contaminated one and says why; on/off."""

from __future__ import annotations

import json
from dataclasses import replace
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


@pytest.mark.slow
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


def _same_report(a: dict[str, object], b: dict[str, object]) -> bool:
    """Two reports (``to_json``) number for number, the output-error fit's wall time aside."""

    def dropped(d: dict[str, object]) -> str:
        d = json.loads(json.dumps(d))
        oe = d.get("output_error")
        if isinstance(oe, dict):
            oe.pop("elapsed_s", None)
        return json.dumps(d, sort_keys=True)

    return dropped(a) == dropped(b)


def test_auto_makes_the_plain_output_error_estimate_only_when_its_answer_is_reported(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """``auto`` decides on the plain analysis's rigid-body checks, which do not depend on its
    output-error estimate: when the correction is applied, the only output-error fit is the
    corrected solve's (the plain one, the costly part, is never made)."""
    from dimacq.services.solve import analysis

    bands: list[tuple[float, float]] = []
    real = analysis.output_error_step

    def counted(data, *args, **kw):  # type: ignore[no-untyped-def]
        bands.append((float(data.frequencies_hz[0]), float(data.frequencies_hz[-1])))
        return real(data, *args, **kw)

    monkeypatch.setattr(analysis, "output_error_step", counted)
    b = build_scenario("x38-flexible-34", 0)
    rep = analyse(b.model_frf(noise=0.005), b.setup, AnalysisOptions(geometry_samples=40))
    assert rep.modal_correction is not None and rep.modal_correction.applied
    assert rep.result.extras["output_error"]["used"]
    assert bands == [tuple(rep.result.band_hz)]


def test_a_corrected_solve_that_fails_reports_the_plain_answer_as_it_is(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """When the corrected solve fails its checks and the plain one does not, the report is the
    plain analysis's, number for number (its output-error estimate made then), with the note."""
    from dimacq.services.solve import modal_correction as mc

    real = mc.corrected

    def spoiled(frf, fit, setup, n_iter=2):  # type: ignore[no-untyped-def]
        data, correction = real(frf, fit, setup, n_iter)
        return data.replace(H=-data.H), correction  # every sign flipped: a negative mass

    monkeypatch.setattr(mc, "corrected", spoiled)
    b = build_scenario("x38-flexible-34", 0)
    frf = b.model_frf(noise=0.005)
    opt = AnalysisOptions(geometry_samples=40)
    auto = analyse(frf, b.setup, opt)
    note = auto.modal_correction
    assert note is not None and not note.applied
    assert "the corrected solve fails its checks: solved as measured" in note.reason
    off = analyse(frf, b.setup, replace(opt, modal_correction="off"))
    assert off.verdict != "fail"
    as_json = auto.to_json()
    as_json.pop("modal_correction")
    assert _same_report(as_json, off.to_json())


def test_a_refused_correction_reports_the_plain_answer_as_it_is() -> None:
    """No band qualifies on a flexible cube, but no modal fit either: the plain answer, number
    for number, with the reason."""
    b = build_scenario("cube-2", 0)
    frf = b.model_frf(noise=0.01)
    auto = analyse(frf, b.setup)
    note = auto.modal_correction
    assert note is not None and not note.applied and "solved as measured" in note.reason
    off = analyse(frf, b.setup, AnalysisOptions(modal_correction="off"))
    as_json = auto.to_json()
    as_json.pop("modal_correction")
    assert _same_report(as_json, off.to_json())
