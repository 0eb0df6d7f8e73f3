"""The strain-gauge bridge model against its closed forms (module docstring of bridge.py)."""

from __future__ import annotations

import numpy as np
import pytest

from dimacq.simulators.lab.bridge import BridgeState, StrainGaugeCell, strain_gauge_cell
from dimacq.simulators.lab.forward import calibration_mass
from dimacq.simulators.lab.timedomain import VirtualLab, static_support_loads

R = np.array([500.0, 500.0, 1000.0, 50.0, 50.0, 50.0])


def quiet_cell(**kw: float) -> StrainGaugeCell:
    base = strain_gauge_cell(501)
    args: dict[str, object] = dict(
        rated_load=R, creep=0.0, swing=0.0, noise_uv=0.0, nonlinearity=0.0, hysteresis=0.0
    )
    args.update(kw)
    return StrainGaugeCell(base.sensitivity_mvv, **args)  # type: ignore[arg-type]


def reading_load(cell: StrainGaugeCell, state: BridgeState, t: float) -> np.ndarray:
    """Load seen through the exact inverse ``S⁺`` after removing the zero terms."""
    r = state.readings(np.array([t])) - cell.zero(np.array([t]))
    return np.linalg.pinv(cell.sensitivity_mvv) @ r[:, 0]


def test_nonlinearity_is_n_of_full_scale_at_rated_load_and_even() -> None:
    cell = quiet_cell(nonlinearity=np.full(6, 5e-4))
    st = BridgeState(cell)
    for sign in (1.0, -1.0):
        st.place(sign * R, 10.0)
        err = reading_load(cell, st, 11.0) - sign * R
        np.testing.assert_allclose(err / R, 5e-4, rtol=1e-9)


def test_hysteresis_is_h_between_branches_at_half_scale_and_respects_the_dead_band() -> None:
    h = 3e-4
    cell = quiet_cell(hysteresis=np.full(6, h))
    st = BridgeState(cell)
    st.place(0.5 * R, 1.0)
    up = reading_load(cell, st, 1.5)
    st.place(R, 2.0)
    st.place(0.5 * R, 3.0)
    down = reading_load(cell, st, 3.5)
    np.testing.assert_allclose((down - up) / R, h, rtol=1e-9)
    # a change inside the dead band (0.5 % FS) keeps the unloading branch
    st.place(0.503 * R, 4.0)
    assert np.all(st.sigma == 1.0)


def test_creep_reaches_c_of_the_step_and_the_swing_dies_out() -> None:
    cell = quiet_cell(creep=3e-4, creep_tau_s=8.0, swing=0.02)
    st = BridgeState(cell)
    st.place(R, 0.0)
    np.testing.assert_allclose(reading_load(cell, st, 1000.0) / R - 1, 3e-4, rtol=1e-6)
    early = reading_load(cell, st, 24.0) / R - 1  # three time constants; the swing is gone
    np.testing.assert_allclose(early, 3e-4 * (1 - np.exp(-3)), rtol=1e-4)


def test_noise_is_input_noise_over_excitation_and_zero_drifts_with_temperature() -> None:
    cell = quiet_cell(noise_uv=0.5, excitation_v=5.0, temperature_ramp_k_per_s=0.01)
    assert cell.noise_mvv == pytest.approx(1e-4)
    st = BridgeState(cell)
    rng = np.random.default_rng(0)
    r = st.readings(np.zeros(20000), rng=rng)
    assert np.std(r, axis=1) == pytest.approx(np.full(12, 1e-4), rel=0.03)
    dz = cell.zero(np.array([100.0])) - cell.zero(np.array([0.0]))
    np.testing.assert_allclose(dz[:, 0], cell.zero_tc_mvv_per_k * 1.0, rtol=1e-12)


def test_dc_lab_carries_the_weight_of_the_hanging_mass() -> None:
    """Statics of one support: the cell carries ``m g`` up and the moment of the weight about
    its origin (independent closed form, cell frame)."""
    model = calibration_mass(0)
    (s,) = model.supports
    F = static_support_loads(model, 9.80665)[0]
    m, c = model.properties.mass_kg, np.asarray(model.properties.cg_m)
    w = np.array([0.0, 0.0, -m * 9.80665])
    Rm = np.asarray(s.rotation)
    f_on_body = -w  # the support holds the body
    m_on_body = np.cross(c - np.asarray(s.position_m), -w)  # about the cell origin
    np.testing.assert_allclose(F[:3], Rm.T @ f_on_body, atol=1e-6 * m * 9.81)
    np.testing.assert_allclose(F[3:], Rm.T @ m_on_body, atol=1e-6 * m * 9.81)
    cell = strain_gauge_cell(s.node, noise_uv=0.0)
    lab = VirtualLab(model, bridges={s.node: cell})
    assert lab.channel_units[lab.channel_index("LC501 g01")] == "mV/V"
    g = lab.read(np.array([lab.channel_index(f"LC501 g{i:02d}") for i in range(1, 13)]), 0, 64)
    st = BridgeState(cell)
    st.place(F, -1e9, settle=True)
    np.testing.assert_allclose(g, st.readings(np.arange(64) / lab.sample_rate_hz), atol=1e-12)
