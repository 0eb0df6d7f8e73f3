"""The stream alignment's numerics against closed forms: the 4-point Lagrange cubic on a
sinusoid, the lower-envelope clock fit on arrivals with known clock and latencies, the phase
an alignment error costs."""

from __future__ import annotations

import numpy as np
import pytest

from dimacq.pipeline.stream_alignment import fit_lower_envelope, lagrange4, phase_error_deg


def test_lagrange4_reproduces_a_sinusoid_and_leaves_holes_as_nan() -> None:
    nu = 0.03  # cycles per sample
    n = np.arange(200)
    y = np.stack([np.sin(2 * np.pi * nu * n), np.cos(2 * np.pi * nu * n)], axis=1)
    u = np.linspace(1.0, 196.9, 777)
    got = lagrange4(y, u)
    want = np.stack([np.sin(2 * np.pi * nu * u), np.cos(2 * np.pi * nu * u)], axis=1)
    assert np.abs(got - want).max() < 1e-4  # O((2πν)^4 / 24)
    # on the samples themselves: exact
    np.testing.assert_allclose(lagrange4(y, n[1:-2].astype(float)), y[1:-2], atol=1e-12)
    y[100, 0] = np.nan
    # sample 100 is in the support (i − 1 .. i + 2) of every u in [98, 101]
    bad = lagrange4(y, np.array([97.5, 98.5, 99.5, 100.5, 101.5, 102.5]))
    assert np.isnan(bad[:, 0]).tolist() == [False, True, True, True, True, False]
    assert np.isfinite(bad[:, 1]).all()  # the other channel keeps its samples
    assert np.isnan(lagrange4(y, np.array([0.5, 198.5]))).all()  # no sample on one side


def test_lower_envelope_finds_the_clock_under_random_latency() -> None:
    rng = np.random.default_rng(5)
    s = np.arange(0, 20.0, 0.002)  # sensor seconds of 10 000 datagrams
    slope, offset = 1.0 + 37e-6, 1234.5  # a crystal 37 ppm fast of the host's, its zero
    latency = 30e-6 + rng.exponential(300e-6, s.size)  # floor 30 µs
    t = offset + slope * s + latency
    fit = fit_lower_envelope(s, t, nominal_slope=1.0, window_s=0.2)
    assert fit.n_windows >= 90
    assert fit.slope == pytest.approx(slope, abs=2e-6)
    # the envelope is the floor: offset + 30 µs, within a few µs
    assert fit.offset_s - offset == pytest.approx(30e-6, abs=10e-6)
    assert fit.scatter_s < 10e-6
    # too short a span for a slope: the nominal one and the lowest point
    short = fit_lower_envelope(s[:200], t[:200], nominal_slope=1.0, window_s=0.2)
    assert short.slope == 1.0 and short.n_windows < 8
    assert short.offset_s == pytest.approx(np.min(t[:200] - s[:200]))


def test_phase_error() -> None:
    assert phase_error_deg(1e-4, 100.0) == pytest.approx(3.6)
    assert phase_error_deg(-1e-3, 50.0) == pytest.approx(18.0)
