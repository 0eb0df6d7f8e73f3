"""Orientation repair (against the true directions of the forward model) and band selection."""

from __future__ import annotations

import numpy as np
import pytest
from _selection_support import forward_case, make_case

from dimacq.pipeline.dim import solve
from dimacq.pipeline.selection._common import response_geometry
from dimacq.pipeline.selection.band import cmif, suggest_band
from dimacq.pipeline.selection.orientation import apply_orientation, estimate_orientation_frf


def _angles(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.degrees(np.arccos(np.clip(np.sum(a * b, axis=1), -1, 1)))


@pytest.mark.slow
@pytest.mark.parametrize("seed", [2000, 2001])
def test_repair_brings_three_degree_errors_below_0_3(seed: int) -> None:
    c = forward_case(seed, triax_error_deg=3.0)
    rep, geo = estimate_orientation_frf(c.frf, c.nominal)
    true_dirs = response_geometry(c.frf, c.true).directions
    before = _angles(geo.directions, true_dirs)
    after = _angles(rep.corrected_directions, true_dirs)
    assert before.max() > 1.0
    assert after.max() < 0.3
    assert np.all(rep.error_after < rep.error_before)
    assert not rep.applied
    # applied to the setup, the solution improves
    fixed = apply_orientation(c.nominal, rep, geo)
    np.testing.assert_allclose(
        response_geometry(c.frf, fixed).directions, rep.corrected_directions, atol=1e-12
    )
    m0 = abs(solve(c.frf, c.nominal).mass_kg - c.truth.mass_kg)
    m1 = abs(solve(c.frf, fixed).mass_kg - c.truth.mass_kg)
    assert m1 < m0


def test_repair_of_exact_data_is_null() -> None:
    c = forward_case(5, noise=0.0)
    rep, _ = estimate_orientation_frf(c.frf, c.nominal)
    assert rep.angles_deg.max() < 1e-6


def test_cmif_is_the_singular_values() -> None:
    rng = np.random.default_rng(1)
    H = rng.normal(size=(3, 5, 4)) + 1j * rng.normal(size=(3, 5, 4))
    s = cmif(H)
    for k in range(3):
        np.testing.assert_allclose(s[k], np.linalg.svd(H[k], compute_uv=False))


def test_band_between_suspension_and_deformation_modes() -> None:
    c = make_case(
        0,
        noise=0.01,
        triax_error_deg=0.5,
        suspension_hz=4.0,
        elastic_hz=400.0,
        freqs_hz=np.linspace(1.0, 600.0, 400),
    )
    b = suggest_band(c.frf, c.setup)
    lo, hi = b.band_hz
    # unmeasured suspension (≤ 5.6 Hz) biases the mass by about (f_s/f)², the 400 Hz mode adds
    # non-rigid motion growing like 1/((400/f)² − 1): the band must keep clear of both
    assert lo > 30.0 and hi < 300.0 and hi - lo > 20.0
    assert any(3.0 < f < 7.0 for f in b.suspension_peaks_hz)
    assert any(380.0 < f < 420.0 for f in b.deformation_peaks_hz)
    assert "suspension" in b.reason and "deformation mode at" in b.reason
    m = solve(c.frf, c.setup, band_hz=b.band_hz).mass_kg
    m_all = solve(c.frf, c.setup).mass_kg
    assert abs(m - 18.175) < 0.5 * abs(m_all - 18.175)
