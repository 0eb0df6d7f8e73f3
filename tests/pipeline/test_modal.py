"""The modal-model correction's numerics (:mod:`dimacq.pipeline.modal`) against closed forms:
poles of a sum of known pole terms, the projection's split, and the rigid part of the forward
model's flexible FRFs recovered (the independent answer: the body's own properties)."""

from __future__ import annotations

import numpy as np
import pytest

from dimacq.errors import DataError
from dimacq.model.frf import FrfData
from dimacq.pipeline.dim import assemble, solve_system
from dimacq.pipeline.modal import elastic_shapes, lscf_poles, project_out
from dimacq.services.solve.modal_correction import corrected, modal_fit
from dimacq.simulators.lab.scenarios import build_scenario


def _pole(f_hz: float, zeta: float) -> complex:
    wn = 2 * np.pi * f_hz
    return complex(-zeta * wn, wn * np.sqrt(1 - zeta**2))


@pytest.mark.slow
def test_lscf_finds_the_poles_of_a_known_pole_residue_sum() -> None:
    """``H = Σ s² [A/(s − λ) + A*/(s − λ*)] + c`` for three modes (12, 19, 33 Hz; 1–3 %
    damping) on 30 pairs with random complex residues, 0.2 % noise: each pole within 0.2 % in
    frequency and 0.003 in damping ratio, and no other pole in the span."""
    rng = np.random.default_rng(3)
    f = np.arange(1, 481) * 0.125
    s = 2j * np.pi * f
    truth = [(12.0, 0.01), (19.0, 0.02), (33.0, 0.03)]
    H = np.zeros((f.size, 30), complex) + rng.normal(size=30)
    for fr, ze in truth:
        lam = _pole(fr, ze)
        A = (rng.normal(size=30) + 1j * rng.normal(size=30)) * 1e-3
        H += (s**2)[:, None] * (A / (s - lam)[:, None] + A.conj() / (s - np.conj(lam))[:, None])
    rms = np.sqrt(np.mean(np.abs(H) ** 2, axis=0))
    H += 0.002 * rms * (rng.normal(size=H.shape) + 1j * rng.normal(size=H.shape)) / np.sqrt(2)
    poles = lscf_poles(f, H)
    assert len(poles) == 3, [(p.frequency_hz, p.damping_ratio) for p in poles]
    for p, (fr, ze) in zip(poles, truth, strict=True):
        assert abs(p.frequency_hz / fr - 1) < 2e-3
        assert abs(p.damping_ratio - ze) < 3e-3


def test_lscf_refuses_too_few_lines() -> None:
    with pytest.raises(DataError, match="too few for a modal fit"):
        lscf_poles(np.arange(1.0, 10.0), np.ones((9, 2), complex))


def test_projection_splits_rigid_and_elastic_motion_exactly() -> None:
    """``a = Ψ K + C η`` with C partly inside the rigid-body span: the projection returns Ψ K
    (the condensation alone would not: C's in-span part would pass as rigid motion)."""
    rng = np.random.default_rng(1)
    psi = rng.normal(size=(24, 6))
    C = (psi @ rng.normal(size=(6, 2)) + rng.normal(size=(24, 2))).astype(complex)
    K = rng.normal(size=(5, 6, 4)) + 1j * rng.normal(size=(5, 6, 4))
    eta = rng.normal(size=(5, 2, 4)) + 1j * rng.normal(size=(5, 2, 4))
    a = np.einsum("ck,lkj->lcj", psi, K) + np.einsum("ce,lej->lcj", C, eta)
    rigid, corr = project_out(a, psi, C)
    np.testing.assert_allclose(rigid, np.einsum("ck,lkj->lcj", psi, K), atol=1e-10)
    np.testing.assert_allclose(corr, a - rigid, atol=1e-12)


def test_elastic_shape_is_the_residue_minus_its_rigid_share() -> None:
    rng = np.random.default_rng(2)
    psi = rng.normal(size=(18, 6))
    shape = rng.normal(size=18)
    U = rng.normal(size=(1, 6, 5)) + 1j * rng.normal(size=(1, 6, 5))
    part = rng.normal(size=5) + 1j * rng.normal(size=5)
    A = (np.einsum("ck,rkj->rcj", psi, U) + shape[None, :, None] * part[None, None, :]).astype(
        complex
    )
    c = elastic_shapes(A, U, psi)[:, 0]
    cos = abs(np.vdot(c, shape)) / (np.linalg.norm(c) * np.linalg.norm(shape))
    assert cos > 1 - 1e-10


@pytest.mark.slow
def test_correction_recovers_the_rigid_part_of_a_flexible_vehicle() -> None:
    """X-38-like vehicle on air-ride supports (suspension up to 4.8 Hz) with hull bending,
    torsion and lateral modes at 17/24/31 Hz (modal mass one fifth of the vehicle's, 2 %),
    model FRFs without noise: the poles found are the model's eigenvalues (closed form), and
    the DIM on the corrected FRFs over 6–58 Hz — across all three modes — returns the body's
    properties (uncorrected, that band gives the mass −59 %)."""
    b = build_scenario("x38-flexible-17", 0)
    frf = b.model_frf()
    fit = modal_fit(frf, b.setup)
    fn = b.model.natural_frequencies_hz()
    el = [p.frequency_hz for p in fit.poles if p.elastic]
    np.testing.assert_allclose(el, fn[-3:], rtol=2e-3)
    assert all(not p.elastic for p in fit.poles if p.frequency_hz < 6.0)
    data, corr = corrected(frf, fit, b.setup)
    res = solve_system(assemble(data.band(6.0, 58.0), b.setup))
    t = b.truth
    assert abs(res.properties.mass_kg / t.mass_kg - 1) < 1e-4
    assert np.linalg.norm(res.properties.cg_m - t.cg_m) < 1e-3
    np.testing.assert_allclose(
        res.properties.inertia_cg_kgm2, t.inertia_cg_kgm2, atol=0.002 * 6.4e4
    )
    raw = solve_system(assemble(frf.band(6.0, 58.0), b.setup))
    assert abs(raw.properties.mass_kg / t.mass_kg - 1) > 0.2  # the contamination is real
    assert np.all(corr[:, [i for i, k in enumerate(frf.output_kinds) if k == "reaction"]] == 0)


def _rising_noise(f: np.ndarray, f_c: float, floor: float) -> np.ndarray:
    """Relative noise of an impact test's FRFs: ``floor`` where the hammer drives the test, rising
    as ``(f/f_c)⁴`` above (the force spectrum's roll-off, 40 dB a decade)."""
    return floor * (1 + (f / f_c) ** 4)


def _with_noise(H: np.ndarray, rel: np.ndarray, seed: int) -> np.ndarray:
    """``H`` (n_lines, n_pairs) plus complex white noise whose RMS over the pairs is ``rel`` times
    ``H``'s, per line."""
    rng = np.random.default_rng(seed)
    mag = np.sqrt(np.mean(np.abs(H) ** 2, axis=1))
    e = (rng.standard_normal(H.shape) + 1j * rng.standard_normal(H.shape)) / np.sqrt(2)
    return H + (rel * mag)[:, None] * e


def _impact_noise(frf: FrfData, rel: np.ndarray, seed: int) -> FrfData:
    """``frf`` with :func:`_with_noise` on its accelerances and on its reactions, each kind
    relative to its own RMS per line."""
    H = frf.H.copy()
    for k, kind in enumerate(("acceleration", "reaction")):
        rows = [i for i, x in enumerate(frf.output_kinds) if x == kind]
        sub = H[:, rows].reshape(H.shape[0], -1)
        H[:, rows] = _with_noise(sub, rel, seed + k).reshape(H.shape[0], len(rows), -1)
    return frf.replace(H=H)


def test_noise_estimate_and_clean_span_follow_a_rising_noise_floor() -> None:
    """Three modes (25, 38, 52 Hz) on 40 pairs over 0.125–128 Hz, white noise 0.1 % of the FRF up to ~40 Hz and
    rising as (f/40 Hz)⁴ above: the second-difference estimate recovers the noise (median ratio
    within 15 % of 1 away from the peaks), and the clean span ends where the noise is 10× the
    cleanest lines' — the closed form 40 · 9^(1/4) = 69.3 Hz — within 4 %."""
    from dimacq.pipeline.modal import clean_span, frf_noise

    rng = np.random.default_rng(5)
    f = np.arange(1, 1025) * 0.125
    s = 2j * np.pi * f
    H = np.zeros((f.size, 40), complex) + rng.normal(size=40) * 1e-3
    for fr, ze in [(25.0, 0.02), (38.0, 0.02), (52.0, 0.03)]:
        lam = _pole(fr, ze)
        A = (rng.normal(size=40) + 1j * rng.normal(size=40)) * 1e-5
        H += (s**2)[:, None] * (A / (s - lam)[:, None] + A.conj() / (s - np.conj(lam))[:, None])
    truth = _rising_noise(f, 40.0, 1e-3)
    Hn = _with_noise(H, truth, 6)
    eps = frf_noise(Hn)
    away = np.all([np.abs(f - fr) > 3 for fr in (25.0, 38.0, 52.0)], axis=0)
    assert abs(float(np.median(eps[away] / truth[away])) - 1) < 0.15
    _, top, limit = clean_span(eps)
    assert abs(f[top] / (40 * 9**0.25) - 1) < 0.04, (f[top], limit)
    # noise-free FRFs: nothing is cut (the curvature of the peaks stays below the floor's limit)
    assert clean_span(frf_noise(H))[1] == f.size - 1


@pytest.mark.slow
def test_fit_on_an_acquired_like_span_stops_where_the_frfs_do() -> None:
    """The flexible vehicle (hull modes 17/24/31 Hz) measured over 0.125–128 Hz as an impact
    test is: noise 0.2 % of the FRF where the hammer drives the structure, rising as (f/45 Hz)⁴
    above (at 128 Hz 130× the floor). The fit stops below where the noise reaches 10× the floor
    (45 · 9^(1/4) ≈ 78 Hz), its residual holds over a band across the modes, and the DIM on the
    corrected FRFs there returns the body's properties (the independent answer: the truth)
    within the issue's limits."""
    b = build_scenario("x38-flexible-17", 1)
    f = np.arange(1, 1025) * 0.125
    frf = b.model_frf(frequencies_hz=f)
    frf = _impact_noise(frf, _rising_noise(f, 45.0, 0.002), 7)
    fit = modal_fit(frf, b.setup)
    q = fit.quality()
    assert 60.0 < fit.fit_range_hz[1] < 80.0, q
    lo, hi = fit.band_range_hz
    assert fit.fit_range_hz[0] <= lo < 17.0 and 31.0 < hi <= fit.fit_range_hz[1], q
    np.testing.assert_allclose(
        [p.frequency_hz for p in fit.elastic_poles],
        b.model.natural_frequencies_hz()[-3:],
        rtol=0.01,
    )
    data, _ = corrected(frf, fit, b.setup)
    assert data.frequencies_hz[-1] <= hi + 1e-9
    res = solve_system(assemble(data, b.setup))
    t = b.truth
    assert abs(res.properties.mass_kg / t.mass_kg - 1) < 0.003
    assert np.linalg.norm(res.properties.cg_m - t.cg_m) < 0.010


def test_fit_refuses_frfs_clean_on_too_few_lines() -> None:
    """Noise rising from 2 Hz on (a hammer tip far too soft): the FRFs are clean on a few dozen
    lines only, and the fit says so rather than fit noise."""
    from dimacq.pipeline.modal import fit_modal_model

    b = build_scenario("x38-flexible-17", 0)
    f = np.arange(1, 1025) * 0.125
    frf = b.model_frf(frequencies_hz=f)
    H = _impact_noise(frf, _rising_noise(f, 2.0, 0.002), 8).H
    acc = [i for i, k in enumerate(frf.output_kinds) if k == "acceleration"]
    with pytest.raises(DataError, match=r"clean .* on only"):
        fit_modal_model(f, H, tuple(frf.output_kinds), np.zeros((len(acc), 6)))
