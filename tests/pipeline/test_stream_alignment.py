"""The stream alignment's numerics against closed forms: the 4-point Lagrange cubic on a
sinusoid, the lower-envelope clock fit on arrivals with known clock and latencies, the phase
an alignment error costs."""

from __future__ import annotations

import numpy as np
import pytest

from dimacq.pipeline.stream_alignment import (
    fit_delay,
    fit_lower_envelope,
    fit_pooled_delay,
    lagrange4,
    mass_line_basis,
    phase_error_deg,
)


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


def _arrivals_with_a_burst() -> tuple[np.ndarray, np.ndarray, float, float]:
    """RDT datagrams (40 records at 7000 Hz) over 40 s of a sensor 20 ppm fast, a latency floor
    of 50 µs plus exponential waits, and from 12 s to 30 s of the sensor a sender that falls
    behind: its queue grows to 1.2 s at 24 s and drains by 30 s (what a starved sender thread
    or a congested switch does). Returns ``s, t`` and the true line's offset and slope."""
    rng = np.random.default_rng(7)
    s = np.arange(0.0, 40.0, 40 / 7000)
    slope, offset = 1.0 + 20e-6, 500.0
    queue = np.interp(s, [12.0, 24.0, 30.0], [0.0, 1.2, 0.0], left=0.0, right=0.0)
    t = offset + slope * s + 50e-6 + rng.exponential(150e-6, s.size) + queue
    return s, np.maximum.accumulate(t), offset, slope


def test_lower_envelope_does_not_follow_a_burst_of_held_datagrams() -> None:
    """The clock fit as the driver uses it, refitted on the arrivals so far and extrapolated to
    the newest one: while datagrams are held back for seconds, the uncapped linear programme's
    edge over the windows' mean climbs into the queue (its slope clipped at 200 ppm), and the
    newest samples were put up to 2.5 ms off; the capped one rests on the windows before the
    burst (and after it, once they come) and stays within the floor's scatter and the slope
    that span allows."""
    s, t, offset, slope = _arrivals_with_a_burst()
    worst = 0.0
    for now in np.arange(4.0, 40.0, 0.5):
        m = t - offset <= now
        fit = fit_lower_envelope(s[m], t[m], nominal_slope=1.0, window_s=0.2, min_windows=15)
        assert abs(fit.slope - slope) <= 10e-6, (now, fit.slope - slope)
        # the line at the newest sensor time against the true line plus the 50 µs floor
        s_now = s[m][-1]
        err = (fit.offset_s + fit.slope * s_now) - (offset + slope * s_now + 50e-6)
        worst = max(worst, abs(err))
    assert worst < 150e-6, worst
    # the burst's windows are held, not scattered: the envelope's scatter is the quiet floor's
    assert fit.scatter_s < 150e-6


def test_phase_error() -> None:
    assert phase_error_deg(1e-4, 100.0) == pytest.approx(3.6)
    assert phase_error_deg(-1e-3, 50.0) == pytest.approx(18.0)


def _mass_line(f: np.ndarray, rng: np.random.Generator, n_frfs: int) -> np.ndarray:
    """FRFs of equation (2): ``Σ c_n (ω0 / iω)^n`` with random real ``c_n`` per FRF."""
    return mass_line_basis(f) @ rng.standard_normal((3, n_frfs))


def test_fit_delay_recovers_a_known_delay_exactly() -> None:
    rng = np.random.default_rng(11)
    f = np.arange(20.0, 655.0, 0.5)
    H = _mass_line(f, rng, 6)
    for tau in (-1.7e-3, 0.0, 312.5e-6, 2.9e-3):
        got = fit_delay(
            f, H * np.exp(-2j * np.pi * f * tau)[:, None], np.ones(f.size), search_s=3e-3
        )
        assert got.delay_s == pytest.approx(tau, abs=1e-9)
        assert got.sigma_s < 1e-9 and got.spread_s < 1e-9 and got.misfit < 1e-6
        assert (got.n_lines, got.n_frfs) == (f.size, 6)


def test_fit_delay_against_reference_frfs_whatever_their_shape() -> None:
    """Equation (1): loads that are real combinations of references on the other clock (any
    complex FRFs: resonances, swing, leakage) and a real constant, delayed: recovered exactly."""
    rng = np.random.default_rng(14)
    f = np.arange(1.0, 655.0, 0.5)
    X = rng.standard_normal((f.size, 5)) + 1j * rng.standard_normal((f.size, 5))
    X[:, 0] /= 1 - (f / 40.0) ** 2 + 0.02j * f / 40.0  # a resonance in one reference
    W = X @ rng.standard_normal((5, 6)) + rng.standard_normal(6)[None, :]
    refs = np.concatenate([X, np.ones((f.size, 1))], axis=1)
    tau = -845.3e-6
    got = fit_delay(
        f,
        W * np.exp(-2j * np.pi * f * tau)[:, None],
        np.ones(f.size),
        search_s=2e-3,
        regressors=refs,
    )
    assert got.delay_s == pytest.approx(tau, abs=1e-9) and got.uncertainty_s < 1e-9
    # the mass-line basis cannot describe them: its fit disagrees between the halves
    assert fit_delay(f, W, np.ones(f.size), search_s=2e-3).uncertainty_s > 1e-5


def test_fit_delay_between_two_readings_of_one_cell_whatever_their_calibrations() -> None:
    """Two readings of the same six bridges (two amplifiers, each with its own calibration
    matrix's certificate error) differ by a real 6×6 matrix ``C``: ``got = C ref e^{−iωτ}``
    is equation (1) with the other reading's loads as references, so ``τ`` comes out exactly;
    the least-squares slope of one load's phase ratio does not (a 0.2 % mixing turns a load's
    phase by degrees near its own anti-resonances, and a small load's everywhere)."""
    rng = np.random.default_rng(23)
    f = np.arange(50.0, 655.0, 1.0)
    modes = np.array([137.0, 212.0, 301.0, 455.0, 590.0])
    q = 1.0 / (1 - (f[:, None] / modes) ** 2 + 0.04j * f[:, None] / modes)  # (lines, modes)
    ref = q @ rng.standard_normal((modes.size, 6)) * np.array([1, 1, 1, 0.01, 0.01, 0.01])
    C = np.eye(6) + 0.002 * rng.standard_normal((6, 6))
    tau = 3.7e-6
    got = (ref @ C.T) * np.exp(-2j * np.pi * f * tau)[:, None]
    X = np.concatenate([ref, np.ones((f.size, 1))], axis=1)
    fit = fit_delay(f, got / np.abs(got).max(axis=0), np.ones(f.size), search_s=1e-3, regressors=X)
    assert fit.delay_s == pytest.approx(tau, abs=1e-9) and fit.uncertainty_s < 1e-9
    # one load at a time: the phase ratio's slope, −Σ f φ / (2π Σ f²), s
    phi = np.angle(got / ref)
    per_load = -np.sum(f[:, None] * phi, axis=0) / (2 * np.pi * np.sum(f**2))
    assert np.abs(per_load - tau).max() > 1e-6  # off by microseconds


def test_fit_delay_uncertainty_matches_its_scatter_under_noise() -> None:
    """``σ_τ`` from the cost's curvature against the scatter of 40 noisy fits (closed form of
    the noise: complex Gaussian of known variance per line, weights its inverse)."""
    rng = np.random.default_rng(12)
    f = np.arange(20.0, 400.0, 1.0)
    H0 = _mass_line(f, rng, 4) * np.exp(-2j * np.pi * f * 250e-6)[:, None]
    sd = 0.02 * np.abs(H0).mean(axis=1)
    z = []
    for _ in range(40):
        e = (rng.standard_normal(H0.shape) + 1j * rng.standard_normal(H0.shape)) / np.sqrt(2)
        got = fit_delay(f, H0 + sd[:, None] * e, 1 / sd**2, search_s=1e-3)
        z.append((got.delay_s - 250e-6) / got.sigma_s)
    z = np.asarray(z)
    assert abs(z.mean()) < 0.6 and 0.6 < z.std() < 1.5


def test_fit_delay_uncertainty_counts_lines_that_share_their_noise() -> None:
    """The same fits with the noise smoothed over 4 adjacent lines (a moving average: its
    equivalent noise bandwidth is 4 lines, as a window's smooths an FRF's noise): ``σ_τ``
    taken per line is ~2 times too small against the scatter of 40 fits; with
    ``line_bandwidth=4`` it matches."""
    rng = np.random.default_rng(13)
    f = np.arange(20.0, 400.0, 1.0)
    H0 = _mass_line(f, rng, 4) * np.exp(-2j * np.pi * f * 250e-6)[:, None]
    sd = 0.02 * np.abs(H0).mean(axis=1)
    k = np.ones(4) / 2.0  # unit variance after the moving sum of 4
    z1, z4 = [], []
    for _ in range(40):
        e = rng.standard_normal((f.size + 3, 4)) + 1j * rng.standard_normal((f.size + 3, 4))
        e = np.stack([np.convolve(e[:, m], k, mode="valid") for m in range(4)], axis=1)
        data = H0 + sd[:, None] * e / np.sqrt(2)
        for z, b in ((z1, 1.0), (z4, 4.0)):
            got = fit_delay(f, data, 1 / sd**2, search_s=1e-3, line_bandwidth=b)
            z.append((got.delay_s - 250e-6) / got.sigma_s)
    assert np.std(z1) > 1.5  # per line: too sure
    assert 0.6 < np.std(z4) < 1.5 and abs(np.mean(z4)) < 0.6


def test_fit_delay_flags_a_model_that_does_not_hold_and_data_without_delay_information() -> None:
    rng = np.random.default_rng(13)
    f = np.arange(20.0, 655.0, 0.5)
    H = _mass_line(f, rng, 6)
    # a lightly damped mode at 60 Hz that the basis lacks: (2) fails in the lower half only,
    # the halves disagree
    res = 5.0 / (1 - (f / 60.0) ** 2 + 0.04j * f / 60.0)
    got = fit_delay(
        f,
        (H + res[:, None]) * np.exp(-2j * np.pi * f * 1e-4)[:, None],
        np.ones(f.size),
        search_s=2e-3,
    )
    assert got.uncertainty_s > 20e-6 and got.misfit > 0.01
    # noise only: no delay can be told
    noise = rng.standard_normal(H.shape) + 1j * rng.standard_normal(H.shape)
    got = fit_delay(f, noise, np.ones(f.size), search_s=2e-3)
    assert got.uncertainty_s > 50e-6
    with pytest.raises(ValueError, match=r"give \(n_lines, ...\) arrays for the lines given"):
        fit_delay(f, H[:-1], np.ones(f.size), search_s=1e-3)
    with pytest.raises(ValueError, match="at least 5 lines"):
        fit_delay(f[:4], H[:4], np.ones(4), search_s=1e-3)


def _pooled_run(
    rng: np.random.Generator, f: np.ndarray, taus: np.ndarray, noise: float
) -> tuple[list[np.ndarray], list[np.ndarray], list[np.ndarray | None]]:
    """One run: input ``i``'s 4 FRFs of equation (1) against its own 3 references, delayed by
    ``taus[i]``, with complex noise of ``noise`` × their mean size per line."""
    H, w, X = [], [], []
    for tau in taus:
        refs = rng.standard_normal((f.size, 3)) + 1j * rng.standard_normal((f.size, 3))
        refs = np.concatenate([refs, np.ones((f.size, 1))], axis=1)
        W = refs @ rng.standard_normal((4, 4)) * np.exp(-2j * np.pi * f * tau)[:, None]
        sd = noise * np.abs(W).mean()
        e = rng.standard_normal(W.shape) + 1j * rng.standard_normal(W.shape)
        H.append(W + sd * e / np.sqrt(2))
        w.append(np.ones(f.size))
        X.append(refs)
    return H, w, X


@pytest.mark.slow
def test_pooled_delay_recovers_one_delay_and_its_jackknife_matches_the_scatter() -> None:
    """Inputs sharing one delay: recovered exactly without noise, every leave-one-out refit on
    it. Over 40 runs of 8 inputs whose delays differ at random (5 µs, what no input's own σ
    shows) the jackknife standard error matches the scatter of ``τ̂`` about the truth, while
    the noise's ``σ_τ`` (from the joint cost) is several times too small; with noise alone
    (no per-input spread) the two agree with the scatter."""
    rng = np.random.default_rng(21)
    f = np.arange(50.0, 655.0, 5.0)
    H, w, X = _pooled_run(rng, f, np.full(5, 123.4e-6), 0.0)
    got = fit_pooled_delay(f, H, w, search_s=1e-3, regressors=X)
    assert got.delay_s == pytest.approx(123.4e-6, abs=1e-9) and got.n_inputs == 5
    np.testing.assert_allclose(got.loo_delays_s, 123.4e-6, atol=1e-8)
    assert got.jackknife_s < 1e-8 and got.sigma_s < 1e-9
    for spread, noise in ((5e-6, 0.01), (0.0, 0.3)):
        err, se, sig = [], [], []
        for _ in range(40):
            taus = 100e-6 + spread * rng.standard_normal(8)
            H, w, X = _pooled_run(rng, f, taus, noise)
            got = fit_pooled_delay(f, H, w, search_s=1e-3, regressors=X)
            err.append(got.delay_s - 100e-6)
            se.append(got.jackknife_s)
            sig.append(got.sigma_s)
        scatter = float(np.sqrt(np.mean(np.square(err))))
        assert 0.7 < float(np.sqrt(np.mean(np.square(se)))) / scatter < 1.4
        if spread:
            assert float(np.mean(sig)) < 0.3 * scatter  # the noise alone: far too sure
        else:
            assert 0.7 < float(np.mean(sig)) / scatter < 1.4
    # offsets that are the inputs' true differences are taken (the data fit better with them),
    # offsets that are not are left; a drift over the run shows in the halves
    taus = 100e-6 + np.array([0.0, 20e-6, -30e-6, 10e-6, 5e-6, -15e-6])
    H, w, X = _pooled_run(rng, f, taus, 0.01)
    known = fit_pooled_delay(f, H, w, search_s=1e-3, regressors=X, offsets_s=taus - 100e-6)
    assert known.offsets_used and known.delay_s == pytest.approx(100e-6, abs=0.5e-6)
    H, w, X = _pooled_run(rng, f, np.full(6, 100e-6), 0.01)
    wrong = fit_pooled_delay(f, H, w, search_s=1e-3, regressors=X, offsets_s=taus - 100e-6)
    assert not wrong.offsets_used and wrong.delay_s == pytest.approx(100e-6, abs=0.5e-6)
    assert wrong.drift_s < 0.5e-6
    H, w, X = _pooled_run(rng, f, np.linspace(90e-6, 110e-6, 8), 0.01)
    drifting = fit_pooled_delay(f, H, w, search_s=1e-3, regressors=X)
    assert drifting.halves_s is not None
    # the halves' means 11.4 µs apart: a drift of 6.6 µs, the inputs' own RMS about their
    # mean 6.5 µs (to the noise of the halves' fits)
    spread = float(np.std(np.linspace(90e-6, 110e-6, 8)))
    assert drifting.drift_s == pytest.approx(spread, rel=0.15)
    with pytest.raises(ValueError, match="one of each per input"):
        fit_pooled_delay(f, H, w[:1], search_s=1e-3, regressors=X)


def test_the_inputs_scatter_is_the_rms_of_their_pseudo_values_without_a_jump() -> None:
    """For a mean of inputs ``x_i`` the leave-one-out means are ``(k x̄ − x_i)/(k − 1)``, so
    the pseudo-values ``k τ̂ − (k − 1) τ̂_(i)`` are the ``x_i`` themselves: the scatter is their
    RMS about the mean — four inputs 50.7 .. 107.6 µs give 21.3 µs, where the jackknife's
    standard error of the mean is about half of that; one input that jumped by 1 ms does not
    count for the others' scatter."""
    from dimacq.pipeline.stream_alignment import PooledDelayFit

    def fit(x: np.ndarray) -> PooledDelayFit:
        k, m = x.size, x.mean()
        loo = (k * m - x) / (k - 1)
        return PooledDelayFit(m, 0.0, 0.0, loo, x, 0.0)

    x = np.array([50.7, 107.6, 75.4, 93.5]) * 1e-6
    assert fit(x).scatter_s == pytest.approx(np.sqrt(np.mean((x - x.mean()) ** 2)), rel=1e-9)
    assert fit(x).scatter_s == pytest.approx(21.3e-6, abs=0.1e-6)
    jumped = np.array([300.0, 300.1, 299.9, 300.0, 1300.0]) * 1e-6
    assert fit(jumped).scatter_s < 210e-6  # the four about the five's mean (500 µs), not ±400
    four = np.array([300.0, 300.1, 299.9, 300.0]) * 1e-6
    assert fit(four).scatter_s < 0.1e-6
    assert PooledDelayFit(x[0], 0.0, 0.0, x[:1], x[:1], 0.0).scatter_s == 0.0
