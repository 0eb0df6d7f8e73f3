"""Load cell calibration numerics against a known gauge sensitivity and independent loads."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from dimacq.errors import SetupError, SolverError
from dimacq.model.properties import (
    THESIS_CALIBRATION_MASS,
    THESIS_CALIBRATION_MASS_INERTIA_ORIGIN_KGM2,
)
from dimacq.pipeline.loadcell_calibration import (
    dead_weight_loads,
    inertial_calibration,
    inertial_loads,
    static_calibration,
)

# Thesis calibration mass (method §9), about the GCS origin P.
M_KG = THESIS_CALIBRATION_MASS.mass_kg
C_M = THESIS_CALIBRATION_MASS.cg_m
I_P = THESIS_CALIBRATION_MASS_INERTIA_ORIGIN_KGM2


def skew(v):
    return np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])


def mass_matrix():
    return THESIS_CALIBRATION_MASS.mass_matrix(np.zeros(3))


CELL_POS = np.array([0.01, -0.02, -0.20])
CELL_ROT = Rotation.from_euler("z", 45, degrees=True).as_matrix()


def sensitivity(seed=0):
    """A 12x6 gauge sensitivity (V per N and per N·m) of a 4-spoke cell, well conditioned."""
    rng = np.random.default_rng(seed)
    return rng.standard_normal((12, 6)) * np.array([1e-3] * 3 + [1e-2] * 3)


def synthetic(n_lines=50, n_inputs=24, noise=0.0, seed=1):
    rng = np.random.default_rng(seed)
    a_p = rng.standard_normal((n_lines, 6, n_inputs)) + 1j * rng.standard_normal(
        (n_lines, 6, n_inputs)
    )
    # Independent loads: Newton-Euler on the mass, then moved into the cell frame by hand.
    f_on_mass = M_KG * (a_p[:, :3] - np.einsum("ij,ljk->lik", skew(C_M), a_p[:, 3:]))
    m_p = M_KG * np.einsum("ij,ljk->lik", skew(C_M), a_p[:, :3]) + np.einsum(
        "ij,ljk->lik", I_P, a_p[:, 3:]
    )
    m_cell = m_p - np.cross(CELL_POS, f_on_mass, axisa=0, axisb=1, axisc=1).transpose(0, 1, 2)
    f_l = np.einsum("ji,ljk->lik", CELL_ROT, f_on_mass)
    m_l = np.einsum("ji,ljk->lik", CELL_ROT, m_cell)
    F_L = np.concatenate([f_l, m_l], axis=1)
    S = sensitivity()
    g = np.einsum("ij,ljk->lik", S, F_L)
    g = g + noise * np.abs(g).mean() * (
        rng.standard_normal(g.shape) + 1j * rng.standard_normal(g.shape)
    )
    return a_p, F_L, g, S


def test_inertial_loads_match_newton_euler_in_the_cell_frame():
    a_p, F_L, _, _ = synthetic(n_lines=3, n_inputs=4)
    got = inertial_loads(a_p, mass_matrix(), CELL_POS, CELL_ROT, np.zeros(3))
    np.testing.assert_allclose(got, F_L, rtol=1e-12, atol=1e-12 * np.abs(F_L).max())


def test_noise_free_inertial_calibration_recovers_the_pseudo_inverse():
    a_p, _, g, S = synthetic()
    fit = inertial_calibration(g, a_p, mass_matrix(), CELL_POS, CELL_ROT, np.zeros(3))
    C_true = np.linalg.pinv(S)
    err = np.linalg.norm(fit.matrix - C_true) / np.linalg.norm(C_true)
    assert err < 1e-10
    assert fit.residual_rel < 1e-10 and fit.rank_used == 6
    assert fit.noise_separation < 1e-10 and fit.condition < 1e3
    np.testing.assert_allclose(fit.matrix @ S, np.eye(6), atol=1e-9)


def test_noisy_inertial_calibration_within_half_a_percent():
    a_p, _, g, S = synthetic(noise=1e-3)
    fit = inertial_calibration(g, a_p, mass_matrix(), CELL_POS, CELL_ROT, np.zeros(3))
    C_true = np.linalg.pinv(S)
    err = np.linalg.norm(fit.matrix - C_true) / np.linalg.norm(C_true)
    assert err < 5e-3
    assert 1e-4 < fit.residual_rel < 1e-2
    assert 0 < fit.noise_separation < 0.1


def test_wrong_sign_or_degenerate_excitation_is_visible():
    a_p, _, g, S = synthetic(n_lines=5, n_inputs=3)
    flipped = inertial_calibration(
        g, a_p, mass_matrix(), CELL_POS, CELL_ROT, np.zeros(3), sign=-1.0
    )
    np.testing.assert_allclose(flipped.matrix, -np.linalg.pinv(S), rtol=1e-8, atol=1e-10)
    a1 = np.zeros_like(a_p)
    a1[:, 0] = a_p[:, 0]  # only x translation excited
    with pytest.raises(SolverError, match="six components"):
        inertial_calibration(g, a1, mass_matrix(), CELL_POS, CELL_ROT, np.zeros(3))


def test_static_dead_weight_calibration_and_piezo_refusal():
    rng = np.random.default_rng(5)
    S = sensitivity(2)
    n = 30
    masses = rng.uniform(1, 20, n)
    pos = rng.uniform(-0.1, 0.1, (n, 3))
    dirs = Rotation.random(n, random_state=3).apply([0, 0, -1])  # the cell turned per case
    loads = dead_weight_loads(masses, pos, dirs)
    # independent check of one load case
    f0 = masses[0] * 9.80665 * dirs[0]
    np.testing.assert_allclose(loads[:, 0], np.r_[f0, np.cross(pos[0], f0)])
    tare = rng.standard_normal(12) * 0.01
    readings = (S @ loads).T + tare
    fit = static_calibration(readings, tare, loads, gauge_coupling="DC")
    np.testing.assert_allclose(fit.matrix, np.linalg.pinv(S), rtol=1e-8, atol=1e-8)
    assert fit.method == "static"
    with pytest.raises(SetupError, match=r"AC-coupled.*inertial"):
        static_calibration(readings, tare, loads, gauge_coupling="AC")


# ---------------------------------------------------------------------------------------------
# Static (dead-weight) calibration: plan, settled readings, zero correction, certificate
# ---------------------------------------------------------------------------------------------
RATED = np.array([500.0, 500.0, 1000.0, 50.0, 50.0, 50.0])


def _gauge_matrix() -> np.ndarray:
    rng = np.random.default_rng(3)
    S = np.zeros((12, 6))
    for spoke in range(4):
        c, s = np.cos(spoke * np.pi / 2), np.sin(spoke * np.pi / 2)
        S[3 * spoke] = [c, s, 0, 0, 0, 2]
        S[3 * spoke + 1] = [0, 0, 1, 2 * s, -2 * c, 0]
        S[3 * spoke + 2] = [-s, c, 0.3, 0, 0, -1]
    S = S * 1e-3 + rng.normal(scale=1e-4, size=(12, 6))
    S[:, 3:] *= 10
    return S


def test_standard_plan_spans_every_axis_both_ways_up_and_down() -> None:
    from dimacq.pipeline.loadcell_calibration import check_load_plan, standard_load_plan

    plan = standard_load_plan(RATED)
    F = plan.loads() / RATED[:, None]
    assert check_load_plan(plan) == []
    assert np.all(F.max(axis=1) > 0.95) and np.all(F.min(axis=1) < -0.95)
    assert np.all(np.abs(F) <= 1 + 1e-12)  # nothing beyond its rated load
    # every loaded case has its negative in the plan (mirrored orientation)
    cols = {tuple(np.round(c, 9)) for c in F.T}
    assert all(tuple(np.round(-c, 9)) in cols for c in F.T)


def test_plan_that_never_loads_mz_is_refused_naming_mz() -> None:
    from dimacq.pipeline.loadcell_calibration import LoadPlan, check_load_plan, standard_load_plan

    plan = standard_load_plan(RATED)
    # drop the series whose hanger points give Mz (gravity along x or y, hanger off-centre)
    keep = tuple(c for c in plan.cases if not (c.gravity[2] == 0 and c.point != "centre"))
    with pytest.raises(SetupError, match="Mz"):
        check_load_plan(LoadPlan(keep, RATED))


def test_settled_mean_flags_a_creeping_window_and_accepts_a_steady_one() -> None:
    from dimacq.pipeline.loadcell_calibration import settled_mean

    rng = np.random.default_rng(0)
    noise = 1e-5 * rng.standard_normal((12, 200))
    step = np.full(12, 1.0)
    steady = settled_mean(0.5 + noise, step)
    assert steady.settled
    np.testing.assert_allclose(steady.mean, 0.5, atol=5e-6)
    creeping = settled_mean(0.5 + noise + np.linspace(0, 1e-4, 200)[None, :], step)
    assert not creeping.settled
    np.testing.assert_allclose(creeping.drift, 1e-4, rtol=0.1)


def test_series_zero_correction_removes_tare_and_linear_drift_exactly() -> None:
    from dimacq.pipeline.loadcell_calibration import series_zero_corrected, standard_load_plan

    plan = standard_load_plan(RATED, minimal=True)
    S = _gauge_matrix()
    clean = (S @ plan.loads()).T
    t = 25.0 * np.arange(len(plan.cases))
    tare = np.array([np.full(12, 0.01 * c.series) for c in plan.cases])
    drift = np.outer(t, np.linspace(-1e-7, 1e-7, 12))
    out = series_zero_corrected(clean + tare + drift, t, plan)
    np.testing.assert_allclose(out, clean, atol=1e-12)


def test_static_certificate_recovers_pinv_s_and_the_simulated_imperfections() -> None:
    """Readings from the bridge model's closed form (no wire): the fitted matrix is S⁺ and the
    certificate reports the nonlinearity n and hysteresis h given to the model."""
    from dimacq.pipeline.loadcell_calibration import standard_load_plan, static_certificate
    from dimacq.simulators.lab.bridge import BridgeState, StrainGaugeCell

    S = _gauge_matrix()
    plan = standard_load_plan(RATED)
    n, h = 5e-4, 3e-4
    cell = StrainGaugeCell(
        S, rated_load=RATED, nonlinearity=n, hysteresis=h, creep=0.0, swing=0.0, noise_uv=0.0
    )
    st = BridgeState(cell)
    g = []
    for k in range(len(plan.cases)):
        st.place(plan.loads()[:, k], float(k))
        g.append(S @ st.effective(np.array([k + 0.5]))[:, 0])
    from dimacq.pipeline.loadcell_calibration import series_zero_corrected

    gz = series_zero_corrected(np.array(g), np.arange(len(g)) + 0.5, plan)
    cert = static_certificate(gz, plan)
    C_true = np.linalg.pinv(S)
    assert np.linalg.norm(cert.fit.matrix - C_true) / np.linalg.norm(C_true) < 2e-4
    np.testing.assert_allclose(cert.nonlinearity_pct_fs, 100 * n, rtol=0.05)
    np.testing.assert_allclose(cert.hysteresis_pct_fs, 100 * h, rtol=0.02)
    assert cert.verdict == "ok"
    # without imperfections the fit is exact and the figures vanish
    st0 = BridgeState(
        StrainGaugeCell(S, rated_load=RATED, nonlinearity=0.0, hysteresis=0.0, creep=0.0, swing=0.0)
    )
    g0 = []
    for k in range(len(plan.cases)):
        st0.place(plan.loads()[:, k], float(k))
        g0.append(S @ st0.effective(np.array([k + 0.5]))[:, 0])
    cert0 = static_certificate(
        series_zero_corrected(np.array(g0), np.arange(len(g0)) + 0.5, plan), plan
    )
    np.testing.assert_allclose(cert0.fit.matrix, C_true, atol=1e-9 * np.abs(C_true).max())
    assert cert0.nonlinearity_pct_fs.max() < 1e-9 and cert0.hysteresis_pct_fs.max() < 1e-9


def test_static_certificate_refuses_ac_coupled_gauges() -> None:
    from dimacq.pipeline.loadcell_calibration import standard_load_plan, static_certificate

    plan = standard_load_plan(RATED, minimal=True)
    with pytest.raises(SetupError, match="AC-coupled"):
        static_certificate(np.zeros((len(plan.cases), 12)), plan, gauge_coupling="AC")


def test_settled_mean_counts_a_step_in_the_window_as_drift() -> None:
    from dimacq.pipeline.loadcell_calibration import settled_mean

    rng = np.random.default_rng(1)
    g = 0.5 + 1e-5 * rng.standard_normal((12, 40))
    g[:, :3] -= 0.2  # the load arrived three samples into the window
    assert not settled_mean(g, np.full(12, 0.5)).settled
