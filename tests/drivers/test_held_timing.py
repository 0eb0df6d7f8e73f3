"""The held value's timing model against closed forms and a second method (Monte Carlo)."""

from __future__ import annotations

import numpy as np
import pytest

from dimacq.drivers.held_timing import HeldSampleTiming
from dimacq.errors import SetupError


def test_phase_spread_is_the_uniform_ages_std() -> None:
    """Ages uniform over [0, T): about their mean T/2 their std is T/√12, a phase std of
    360 f T / √12 degrees (closed form), and the draws agree."""
    t = HeldSampleTiming(7000.0)
    T = 1 / 7000
    assert t.mean_delay_s == pytest.approx(T / 2)
    assert t.spread_s == pytest.approx(T / np.sqrt(12))
    assert float(t.phase_std_deg(655.0)) == pytest.approx(360 * 655 * T / np.sqrt(12))
    assert float(t.phase_std_deg(655.0)) == pytest.approx(9.724, abs=1e-3)
    age = np.random.default_rng(0).uniform(0, T, 400_000)
    assert np.std(360 * 655 * (age - T / 2)) == pytest.approx(float(t.phase_std_deg(655)), rel=5e-3)
    assert t.highest_band_hz(2.0) == pytest.approx(2.0 * np.sqrt(12) * 7000 / 360)


@pytest.mark.parametrize("n", [1, 7])
def test_response_is_the_mean_of_the_held_values_phasor(n: int) -> None:
    """R(f) = E[e^{−jωτ}] for a moving average of n own samples, each held 0..T old: the
    closed form against the mean over drawn ages."""
    t = HeldSampleTiming(5000.0, n)
    T = t.period_s
    f = np.array([10.0, 200.0, 655.0, 1500.0])
    age = np.random.default_rng(1).uniform(0, T, 200_000)
    k = np.arange(n)
    mc = np.mean(
        np.exp(-2j * np.pi * f[:, None, None] * (age[None, :, None] + k[None, None, :] * T)),
        axis=(1, 2),
    )
    np.testing.assert_allclose(t.response(f), mc, atol=3e-3)
    assert t.filter_delay_s == pytest.approx((n - 1) * T / 2)
    # its phase is the mean delay's
    np.testing.assert_allclose(
        np.angle(t.response(f[:2])), -2 * np.pi * f[:2] * t.mean_delay_s, atol=1e-9
    )


def test_refused_above_the_budget_in_one_line() -> None:
    t = HeldSampleTiming(7000.0, label="Net F/T")
    assert t.check(100.0, 2.0, where="x") < 2.0
    with pytest.raises(SetupError) as err:
        t.check(655.0, 2.0, where="Net F/T at 2048 S/s")
    msg = str(err.value)
    assert "\n" not in msg and "9.7 deg" in msg and "up to 135 Hz" in msg
    assert "daq-channels" in msg
