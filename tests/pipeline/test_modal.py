"""The modal-model correction's numerics (:mod:`dimacq.pipeline.modal`) against closed forms:
poles of a sum of known pole terms, the projection's split, and the rigid part of the forward
model's flexible FRFs recovered (the independent answer: the body's own properties)."""

from __future__ import annotations

import numpy as np
import pytest

from dimacq.errors import DataError
from dimacq.pipeline.dim import assemble, solve_system
from dimacq.pipeline.modal import elastic_shapes, lscf_poles, project_out
from dimacq.services.modal_correction import corrected, modal_fit
from dimacq.simulators.lab.scenarios import build_scenario


def _pole(f_hz: float, zeta: float) -> complex:
    wn = 2 * np.pi * f_hz
    return complex(-zeta * wn, wn * np.sqrt(1 - zeta**2))


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
