"""The lab's services: the figure of a stored solution draws what was stored; uploads as bytes
or streams; the service and API modules stay small."""

from __future__ import annotations

import io
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from _api_support import make_settings

from dimacq.io.uff import dump_uff
from dimacq.pipeline import dim
from dimacq.services.lab import Lab
from dimacq.services.lab.solving import SolveOptions
from dimacq.simulators.lab.forward import calibration_mass

ROOT = Path(__file__).resolve().parents[2]


# The spectrum is the per-line equation-error solve with the stored selection, known values and
# length unit; the output-error estimate and its geometry refinement (16 fits, 40-60 s of CPU on
# these noise-free FRFs) change only the stored headline, which the tests read back as stored.
EQUATION_ERROR = {"unbiased": False, "refine_geometry": False}


@pytest.fixture
def lab(tmp_path: Path):
    lab = Lab(make_settings(tmp_path), open_devices=False)
    yield lab
    lab.close()


@pytest.mark.slow
def test_solution_spectrum_uses_the_stored_selection(lab: Lab) -> None:
    """One input's force is mis-scaled by 1.3; the jackknife drops it. The figure's per-line
    estimates are those of the inputs the stored solution kept: the true mass on every line
    (noise-free FRFs), not the biased per-line mass of all inputs (what a re-solve without the
    stored options draws)."""
    model = calibration_mass(0, support="bungee")
    frf = model.frf(np.linspace(10.0, 120.0, 56))
    H = frf.H.copy()
    H[:, :, 3] *= 1.3
    bad = replace(frf, H=H)
    sid = lab.store.save_setup(model.setup)
    fid = lab.store.save_frf(bad, sid)
    options = SolveOptions(
        band_hz=(20.0, 100.0), select_responses=False, geometry_uncertainty=False, **EQUATION_ERROR
    )
    sol = lab.analysis.solve(fid, options)
    assert sol is not None
    assert sol.result["excluded_inputs"] == [{"node": 104, "direction": 1}]
    spec = lab.analysis.solution_spectrum(sol.id)
    assert spec is not None
    assert spec.band_hz == (20.0, 100.0)
    assert spec.headline[0] == pytest.approx(sol.result["mass_kg"], rel=1e-12)
    np.testing.assert_allclose(spec.headline[1:4], sol.result["cg_m"], rtol=1e-12)
    truth = model.properties.mass_kg
    np.testing.assert_allclose(spec.per_line[:, 0], truth, rtol=1e-9)
    every_input = dim.solve(bad, model.setup).per_line[:, 0]
    assert np.max(np.abs(every_input / truth - 1)) > 0.01
    png = lab.analysis.solution_figure(sol.id, "png")
    svg = lab.analysis.solution_figure(sol.id, "svg")
    assert png is not None and png[:4] == b"\x89PNG"
    assert svg is not None and b"<svg" in svg[:1000]
    assert lab.analysis.solution_figure(sol.id + 1) is None


def test_solution_spectrum_keeps_the_stored_known_values(lab: Lab) -> None:
    model = calibration_mass(0, support="bungee")
    frf = model.frf(np.linspace(10.0, 120.0, 56))
    sid = lab.store.save_setup(model.setup)
    fid = lab.store.save_frf(frf, sid)
    plain = SolveOptions(
        known={"m": 20.0},
        length_unit="cm",
        select_responses=False,
        select_inputs=False,
        auto_band=False,
        geometry_uncertainty=False,
        **EQUATION_ERROR,
    )
    sol = lab.analysis.solve(fid, plain)
    assert sol is not None and sol.options["known"] == {"m": 20.0}
    spec = lab.analysis.solution_spectrum(sol.id)
    assert spec is not None
    np.testing.assert_array_equal(spec.per_line[:, 0], 20.0)
    direct = dim.solve(frf, model.setup, known={"m": 20.0}, length_unit="cm")
    np.testing.assert_allclose(spec.per_line, direct.per_line, rtol=1e-12, atol=1e-15)


def test_uploads_as_bytes_or_streams(lab: Lab) -> None:
    model = calibration_mass(0, support="bungee")
    frf = model.frf(np.linspace(10.0, 120.0, 8))
    whole = dump_uff(frf, model.setup)
    got = lab.store.import_setup(io.BytesIO(whole), "uff", name="from a stream")
    assert got.frf_id is not None
    sid = got.setup_id
    for data in (dump_uff(frf), io.BytesIO(dump_uff(frf))):
        fid = lab.store.import_frf(data, sid)
        stored = lab.store.frf(fid)
        assert stored is not None
        np.testing.assert_array_equal(stored[0].H, frf.H)


def test_service_and_api_modules_stay_small() -> None:
    big = {
        str(p.relative_to(ROOT)): n
        for folder in ("dimacq/services", "dimacq/api")
        for p in (ROOT / folder).rglob("*.py")
        if (n := len(p.read_text(encoding="utf-8").splitlines())) > 700
    }
    assert not big, f"split these modules (over 700 lines): {big}"


def test_a_hit_view_is_kept_as_arrays_and_given_as_strict_json() -> None:
    """The live review keeps a hit's traces as numpy arrays (not 10⁴ Python floats in lists that
    every full garbage collection walks) and gives them as JSON (NaN → null); a long-finished
    acquisition forgets them."""
    from dimacq.services.lab.acquisition_views import LiveReview, hit_view

    n = 256
    force = np.zeros((1, n))
    force[0, 10] = 100.0
    outputs = np.vstack([np.sin(np.arange(n) / 5.0), 3 * np.cos(np.arange(n) / 7.0)])
    outputs[1, 20] = np.nan  # a lost sample
    view = hit_view({"force": force, "outputs": outputs}, 1024.0, 2)
    assert isinstance(view["force_n"], np.ndarray) and view["response"] == 1
    assert not np.shares_memory(view["response_ms2"], outputs)
    live = LiveReview(review=False, n_inputs=1, last_view={**view, "number": 1})
    got = live.current_hit()
    assert got is not None and got["pending"] is False and got["number"] == 1
    assert isinstance(got["force_n"], list) and got["response_ms2"][20] is None
    assert got["force_n"][10] == 100.0 and len(got["frequencies_hz"]) == n // 2 + 1
    live.drop_views()
    assert live.current_hit() is None
    lives = {i: LiveReview(review=False, n_inputs=1, last_view=dict(view)) for i in range(20)}
    LiveReview.keep_newest_views(lives, keep=16)
    assert [i for i, v in lives.items() if v.current_hit() is None] == [0, 1, 2, 3]
