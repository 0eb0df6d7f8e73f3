"""FRF estimation against closed forms and scipy's independent spectral estimators."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
import scipy.signal

from dimacq.errors import DataError, SetupError
from dimacq.pipeline.frf_estimation import (
    double_hit_mask,
    estimate_frf,
    exponential_window,
    exponential_window_damping_correction,
    force_window,
    welch_segments,
)

FS = 1024.0


def periodic_through(b, a, x, n_periods=8):
    """Steady-state periodic response of the digital filter (b, a) to periodic records x."""
    rep = np.concatenate([x] * n_periods, axis=-1)
    return scipy.signal.lfilter(b, a, rep, axis=-1)[..., -x.shape[-1] :]


def test_noise_free_identity_gives_unit_frf_and_coherence():
    rng = np.random.default_rng(1)
    x = rng.standard_normal((4, 1, 256))
    y = np.concatenate([x, 2 * x, -x], axis=1)
    est = estimate_frf(x, y, FS)
    assert est.H.shape == (129, 3, 1)
    expected = np.broadcast_to(np.array([1.0, 2.0, -1.0]) + 0j, (129, 3))
    np.testing.assert_allclose(est.H[:, :, 0], expected, atol=1e-12)
    np.testing.assert_allclose(est.coherence, 1.0, atol=1e-12)
    np.testing.assert_allclose(est.frequencies_hz[1], FS / 256)


def test_h1_equals_digital_filter_response_exactly_for_periodic_data():
    # Discrete SDOF resonator (closed form via freqz is the independent answer).
    b, a = scipy.signal.iirpeak(100.0, Q=20, fs=FS)
    rng = np.random.default_rng(2)
    x = rng.standard_normal((5, 1, 512))
    y = periodic_through(b, a, x)
    est = estimate_frf(x, y, FS)
    _, h_true = scipy.signal.freqz(b, a, worN=est.frequencies_hz, fs=FS)
    scale = np.abs(h_true).max()
    np.testing.assert_allclose(est.H[:, 0, 0], h_true, rtol=0, atol=1e-10 * scale)
    for kind in ("H2", "Hv"):
        h = estimate_frf(x, y, FS, estimator=kind).H[1:-1, 0, 0]
        np.testing.assert_allclose(h, h_true[1:-1], rtol=0, atol=1e-9 * scale)


def sdof_accelerance(f_hz, m, fn_hz, zeta):
    w = 2 * np.pi * f_hz
    wn = 2 * np.pi * fn_hz
    return -(w**2) / (m * (wn**2 - w**2 + 2j * zeta * wn * w))


def sdof_impact(m, fn_hz, zeta, n, fs, pulse_s=0.002, pre=16):
    """Force pulse (half sine) and the exact acceleration of a continuous SDOF (lsim, FOH)."""
    wn = 2 * np.pi * fn_hz
    t = np.arange(n) / fs
    f = np.where(
        (t >= pre / fs) & (t < pre / fs + pulse_s), np.sin(np.pi * (t - pre / fs) / pulse_s), 0.0
    )
    # x'' = (f - c x' - k x)/m ; output acceleration = C x + D f
    A = np.array([[0.0, 1.0], [-(wn**2), -2 * zeta * wn]])
    B = np.array([[0.0], [1.0 / m]])
    C = np.array([[-(wn**2), -2 * zeta * wn]])
    D = np.array([[1.0 / m]])
    _, acc, _ = scipy.signal.lsim((A, B, C, D), f, t, interp=True)
    return f, acc


def test_impact_h1_matches_continuous_sdof_closed_form():
    m, fn, zeta, n, fs = 2.0, 40.0, 0.05, 4096, 2048.0
    f, acc = sdof_impact(m, fn, zeta, n, fs)
    est = estimate_frf(f[None, None], acc[None, None], fs)
    band = (est.frequencies_hz > 5) & (est.frequencies_hz < 200)
    h_true = sdof_accelerance(est.frequencies_hz[band], m, fn, zeta)
    err = np.abs(est.H[band, 0, 0] / h_true - 1)
    # The residual is the sampling of a continuous system (first-order-hold input, aliasing).
    assert err.max() < 3e-3


def test_exponential_window_adds_known_damping_and_correction_removes_it():
    m, fn, zeta, n, fs = 1.0, 30.0, 0.002, 4096, 2048.0
    f, acc = sdof_impact(m, fn, zeta, n, fs, pre=0)
    tau = 0.1
    w = exponential_window(n, fs, tau)
    est = estimate_frf(f[None, None], acc[None, None], fs, input_window=w, output_window=w)
    # Windowing input and output alike gives H evaluated at s = i w + 1/tau (closed form).
    fl = est.frequencies_hz
    band = (fl > 5) & (fl < 200)
    s = 2j * np.pi * fl[band] + 1 / tau
    wn = 2 * np.pi * fn
    h_shifted = s**2 / (m * (s**2 + 2 * zeta * wn * s + wn**2))
    assert np.max(np.abs(est.H[band, 0, 0] / h_shifted - 1)) < 3e-3
    # Its poles: sigma' = sigma + 1/tau, i.e. an apparent zeta' = zeta + 1/(tau wn) (small zeta).
    poles = np.roots([1, 2 * zeta * wn, wn**2]) - 1 / tau
    zeta_apparent = -poles[0].real / abs(poles[0])
    fn_apparent = abs(poles[0]) / (2 * np.pi)
    np.testing.assert_allclose(zeta_apparent, zeta + 1 / (tau * wn), rtol=2e-3)
    zeta_c, fn_c = exponential_window_damping_correction(zeta_apparent, fn_apparent, tau)
    np.testing.assert_allclose([zeta_c, fn_c], [zeta, fn], rtol=1e-9)


def test_force_window_shape():
    w = force_window(100, 20, taper_samples=4)
    assert np.all(w[:20] == 1) and np.all(w[24:] == 0)
    assert np.all(np.diff(w[19:25]) < 0)
    with pytest.raises(SetupError):
        force_window(100, 120)


def test_multiple_input_h1_recovers_both_paths_exactly():
    rng = np.random.default_rng(3)
    b1, a1 = scipy.signal.butter(2, 0.2)
    b2, a2 = scipy.signal.cheby1(3, 1, 0.3)
    x = rng.standard_normal((8, 2, 256))
    y0 = periodic_through(b1, a1, x[:, 0]) + 0.5 * periodic_through(b2, a2, x[:, 1])
    y1 = periodic_through(b2, a2, x[:, 0]) - periodic_through(b1, a1, x[:, 1])
    y = np.stack([y0, y1], axis=1)
    est = estimate_frf(x, y, FS)
    fl = est.frequencies_hz
    _, h1 = scipy.signal.freqz(b1, a1, worN=fl, fs=FS)
    _, h2 = scipy.signal.freqz(b2, a2, worN=fl, fs=FS)
    expected = np.stack([np.stack([h1, 0.5 * h2], -1), np.stack([h2, -h1], -1)], 1)
    np.testing.assert_allclose(est.H, expected, atol=1e-10)
    # (the Nyquist line is excluded: both filters have a zero there, so G_yy = 0)
    np.testing.assert_allclose(est.coherence[:-1], 1.0, atol=1e-9)
    # Ordinary coherence of one input is < 1 because the other input also drives the output.
    assert np.median(est.ordinary_coherence[:, 0, 0]) < 0.99
    assert np.all(est.input_condition >= 1)
    hv = estimate_frf(x, y, FS, estimator="Hv")
    np.testing.assert_allclose(hv.H, expected, atol=1e-8)


def test_h1_bias_with_input_noise_follows_closed_form_and_h2_is_unbiased():
    rng = np.random.default_rng(4)
    n_avg, n = 400, 128
    x = rng.standard_normal((n_avg, 1, n))
    y = 3.0 * x  # H = 3
    noise_rms = 0.5
    xm = x + noise_rms * rng.standard_normal(x.shape)
    h1 = estimate_frf(xm, y, FS).H[1:-1, 0, 0]
    h2 = estimate_frf(xm, y, FS, estimator="H2").H[1:-1, 0, 0]
    expected_h1 = 3.0 / (1 + noise_rms**2)  # E[H1] = H G_xx / (G_xx + G_nn)
    assert abs(np.mean(h1.real) / expected_h1 - 1) < 0.01
    assert abs(np.mean(h2.real) / 3.0 - 1) < 0.01


def test_hv_single_input_equals_classic_formula():
    rng = np.random.default_rng(5)
    x = rng.standard_normal((20, 1, 64))
    y = 2 * x + 0.3 * rng.standard_normal((20, 2, 64))
    xm = x + 0.3 * rng.standard_normal(x.shape)
    est = estimate_frf(xm, y, FS, estimator="Hv")
    X = np.fft.rfft(xm, axis=-1)[:, 0]
    Y = np.fft.rfft(y, axis=-1)
    gff = np.sum(np.abs(X) ** 2, 0)
    for o in range(2):
        gyy = np.sum(np.abs(Y[:, o]) ** 2, 0)
        gfy = np.sum(X.conj() * Y[:, o], 0)
        hv = (gyy - gff + np.sqrt((gff - gyy) ** 2 + 4 * np.abs(gfy) ** 2)) / (2 * gfy.conj())
        np.testing.assert_allclose(est.H[:, o, 0], hv, rtol=1e-9)


def test_welch_matches_scipy_csd_over_welch():
    rng = np.random.default_rng(6)
    x = rng.standard_normal(8192)
    b, a = scipy.signal.butter(4, 0.25)
    y = scipy.signal.lfilter(b, a, x) + 0.1 * rng.standard_normal(x.size)
    nper = 512
    win = scipy.signal.get_window("hann", nper)
    xs = welch_segments(x[None], nper)
    ys = welch_segments(y[None], nper)
    assert xs.shape == (8192 // 256 - 1, 1, nper)
    est = estimate_frf(xs, ys, FS, input_window=win, output_window=win)
    _, pxy = scipy.signal.csd(x, y, fs=FS, nperseg=nper, window="hann", detrend=False)
    _, pxx = scipy.signal.welch(x, fs=FS, nperseg=nper, window="hann", detrend=False)
    np.testing.assert_allclose(est.H[:, 0, 0], pxy / pxx, rtol=1e-9)
    _, coh = scipy.signal.coherence(x, y, fs=FS, nperseg=nper, window="hann", detrend=False)
    np.testing.assert_allclose(est.coherence[:, 0], coh, rtol=1e-8)


def test_double_hit_detected():
    n = 512
    t = np.arange(n)
    single = np.exp(-(((t - 50) / 3.0) ** 2))
    double = single + 0.5 * np.exp(-(((t - 90) / 3.0) ** 2))
    noise = 0.01 * np.random.default_rng(7).standard_normal(n)
    mask = double_hit_mask(np.stack([single + noise, double + noise]))
    assert mask.tolist() == [False, True]


def test_bad_input_refused():
    with pytest.raises(DataError, match="n_averages"):
        estimate_frf(np.zeros((2, 1, 64)), np.zeros((3, 1, 64)), FS)
    with pytest.raises(SetupError, match="H2"):
        estimate_frf(np.ones((4, 2, 64)), np.ones((4, 1, 64)), FS, estimator="H2")
    bad = np.zeros((1, 1, 64))
    bad[0, 0, 3] = np.nan
    with pytest.raises(DataError, match="NaN"):
        estimate_frf(bad, bad, FS)
    with pytest.raises(DataError, match="averages"):
        estimate_frf(np.ones((1, 2, 64)), np.ones((1, 1, 64)), FS)


def test_too_few_averages_give_no_coherence_rather_than_one():
    """Issue 10: one average gave coherence 1 identically, whatever the noise."""
    rng = np.random.default_rng(7)
    x = rng.standard_normal((1, 1, 256))
    y = x + 3.0 * rng.standard_normal((1, 1, 256))  # SNR 1/9: the true coherence is 0.1
    one = estimate_frf(x, y, FS)
    # what the old code returned: |Y F̄|² / (|Y|² |F|²) = 1 by Cauchy–Schwarz with one average
    fx, fy = np.fft.rfft(x[0, 0]), np.fft.rfft(y[0, 0])
    np.testing.assert_allclose(np.abs(fy * fx.conj()) ** 2 / (np.abs(fy) ** 2 * np.abs(fx) ** 2), 1)
    assert np.isnan(one.coherence).all() and np.isnan(one.ordinary_coherence).all()
    # two inputs, two averages: the multiple coherence is 1 identically too → NaN
    x2 = rng.standard_normal((2, 2, 256))
    y2 = x2.sum(axis=1, keepdims=True) + rng.standard_normal((2, 1, 256))
    two = estimate_frf(x2, y2, FS)
    assert np.isnan(two.coherence).all() and np.isfinite(two.ordinary_coherence[1:]).all()
    # 64 averages: the coherence is the physics, about 1 / (1 + 9) (independent: SNR)
    xs = rng.standard_normal((64, 1, 256))
    many = estimate_frf(xs, xs + 3.0 * rng.standard_normal((64, 1, 256)), FS)
    assert np.median(many.coherence[1:-1]) == pytest.approx(0.1, abs=0.03)


def _per_line_reference(x, y, wx, wy):
    """H1, H2, ordinary and multiple coherence line by line from the definitions (module
    docstring), with Python loops: the reference of the blocked, vectorised estimator."""
    fx = np.fft.rfft(x * wx, axis=-1)
    fy = np.fft.rfft(y * wy, axis=-1)
    n_lines, n_out, n_in = fx.shape[-1], fy.shape[1], fx.shape[1]
    h1 = np.empty((n_lines, n_out, n_in), complex)
    h2 = np.full((n_lines, n_out, 1), np.nan + 0j)
    ordinary = np.empty((n_lines, n_out, n_in))
    multiple = np.empty((n_lines, n_out))
    for k in range(n_lines):
        F, Y = fx[:, :, k].T, fy[:, :, k].T  # (n_in, n_avg), (n_out, n_avg)
        gff = F @ F.conj().T
        gyf = Y @ F.conj().T
        gyy = np.sum(np.abs(Y) ** 2, axis=1)
        h1[k] = gyf @ np.linalg.inv(gff)
        if n_in == 1:
            h2[k, :, 0] = gyy / gyf[:, 0].conj()
        ordinary[k] = np.abs(gyf) ** 2 / np.outer(gyy, np.real(np.diag(gff)))
        multiple[k] = np.real(np.sum(h1[k] * gyf.conj(), axis=1)) / gyy
    return h1, h2, ordinary, multiple


@pytest.mark.parametrize("n_in", [1, 2])
def test_blocked_estimator_equals_the_per_line_definitions(
    n_in: int, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Outputs in blocks of 3 (7 outputs: a short last block), windows applied block by block."""
    import dimacq.pipeline.frf_estimation as fe

    n_avg, n_out, n_s = 6, 7, 128
    monkeypatch.setattr(fe, "_BLOCK_BYTES", 3 * n_avg * (n_s // 2 + 1) * 16)
    rng = np.random.default_rng(27)
    x = rng.standard_normal((n_avg, n_in, n_s))
    y = rng.standard_normal((n_avg, n_out, n_s)) + x.sum(axis=1, keepdims=True)
    wx = force_window(n_s, 40, taper_samples=8) * exponential_window(n_s, FS, 0.05)
    wy = exponential_window(n_s, FS, 0.05)
    h1, h2, ordinary, multiple = _per_line_reference(x, y, wx, wy)
    est = estimate_frf(x, y, FS, input_window=wx, output_window=wy)
    np.testing.assert_allclose(est.H, h1, rtol=1e-12, atol=0)
    fx, fy = np.fft.rfft(x * wx, axis=-1), np.fft.rfft(y * wy, axis=-1)
    np.testing.assert_allclose(est.g_yy, np.sum(np.abs(fy) ** 2, axis=0).T, rtol=1e-12, atol=0)
    g_ff = np.einsum("ajl,ail->lji", fx, fx.conj())
    np.testing.assert_allclose(est.g_ff, g_ff, rtol=1e-12, atol=1e-12 * np.abs(g_ff).max())
    np.testing.assert_allclose(est.ordinary_coherence, ordinary, rtol=1e-12, atol=0)
    np.testing.assert_allclose(est.coherence, np.clip(multiple, 0, 1), rtol=1e-12, atol=1e-15)
    if n_in == 1:
        h = estimate_frf(x, y, FS, estimator="H2", input_window=wx, output_window=wy).H
        np.testing.assert_allclose(h, h2, rtol=1e-12, atol=0)


def test_default_blocks_at_the_benchmark_record_length_equal_plain_numpy() -> None:
    """8192 samples, 10 averages: outputs in blocks of 4 (the last one short), against numpy's
    FFT and whole-array sums: H1 = Σ Y F̄ / Σ|F|², H2 = Σ|Y|² / Σ F Ȳ, γ² = |Σ Y F̄|² /
    (Σ|Y|² Σ|F|²)."""
    rng = np.random.default_rng(8192)
    x = rng.standard_normal((10, 1, 8192))
    y = 0.5 * rng.standard_normal((10, 10, 8192)) + np.cumsum(x, axis=-1) * 1e-2
    fx, fy = np.fft.rfft(x, axis=-1), np.fft.rfft(y, axis=-1)
    g_yf = np.einsum("aol,al->lo", fy, fx[:, 0].conj())
    g_ff = np.sum(np.abs(fx[:, 0]) ** 2, axis=0)[:, None]
    g_yy = np.sum(np.abs(fy) ** 2, axis=0).T
    h1 = estimate_frf(x, y, FS)
    np.testing.assert_allclose(h1.H[:, :, 0], g_yf / g_ff, rtol=1e-12, atol=0)
    np.testing.assert_allclose(h1.coherence, np.abs(g_yf) ** 2 / (g_yy * g_ff), rtol=1e-12)
    h2 = estimate_frf(x, y, FS, estimator="H2", workers=2)
    np.testing.assert_allclose(h2.H[:, :, 0], g_yy / g_yf.conj(), rtol=1e-12, atol=0)


def test_nan_found_in_either_record_set_and_in_a_window() -> None:
    x = np.ones((3, 1, 64))
    y = np.ones((3, 4, 64))
    bad_x, bad_y = x.copy(), y.copy()
    bad_x[1, 0, 5] = np.nan
    bad_y[2, 3, 63] = np.inf
    with pytest.raises(DataError, match="inputs contains NaN"):
        estimate_frf(bad_x, y, FS)
    with pytest.raises(DataError, match="outputs contains NaN"):
        estimate_frf(x, bad_y, FS)
    w = np.ones(64)
    w[3] = np.nan
    with pytest.raises(DataError, match="output_window holds NaN"):
        estimate_frf(x, y, FS, output_window=w)


def test_fft_threads_give_the_same_frfs_and_zero_threads_is_refused() -> None:
    rng = np.random.default_rng(5)
    x = rng.standard_normal((4, 1, 256))
    y = rng.standard_normal((4, 3, 256)) + x
    one = estimate_frf(x, y, FS)
    two = estimate_frf(x, y, FS, workers=2)
    np.testing.assert_allclose(two.H, one.H, rtol=1e-13, atol=0)
    # against numpy's FFT directly: H1 = Σ Y F̄ / Σ |F|²
    f = np.fft.rfft(x, axis=-1)
    h = (
        np.einsum("aol,ail->loi", np.fft.rfft(y, axis=-1), f.conj())
        / np.sum(np.abs(f[:, 0]) ** 2, axis=0)[:, None, None]
    )
    np.testing.assert_allclose(one.H, h, rtol=1e-12, atol=0)
    with pytest.raises(SetupError, match="workers = 0; give 1 or more"):
        estimate_frf(x, y, FS, workers=0)


def test_compiled_block_sums_equal_numpy_and_keep_a_nan_to_its_output() -> None:
    """The one-pass sums (``_spectral_kernel``) against numpy's: ``G_yf = Σ_a Y F̄``,
    ``G_yy = Σ_a |Y|²``, ``|G_yf|²``, two inputs; a NaN in one spectrum value reaches that
    output's sums on that line only (the estimator's finite check relies on it)."""
    from dimacq.pipeline._spectral_kernel import block_sums

    rng = np.random.default_rng(404)
    n_avg, n_out, n_in, n_l = 5, 3, 2, 33
    y = rng.standard_normal((n_avg, n_out, n_l)) + 1j * rng.standard_normal((n_avg, n_out, n_l))
    fc = rng.standard_normal((n_avg, n_in, n_l)) + 1j * rng.standard_normal((n_avg, n_in, n_l))
    y[2, 1, 7] = np.nan
    g = np.empty((n_out, n_in, n_l), complex)
    a2 = np.empty((n_out, n_in, n_l))
    yy = np.empty((n_out, n_l))
    block_sums(y, fc, g, a2, yy)
    g_ref = np.einsum("aol,ail->oil", y, fc)
    np.testing.assert_allclose(g, g_ref, rtol=1e-14, atol=1e-14)
    np.testing.assert_allclose(a2, np.abs(g_ref) ** 2, rtol=1e-14, atol=1e-14)
    np.testing.assert_allclose(yy, np.sum(np.abs(y) ** 2, axis=0), rtol=1e-14)
    assert np.isnan(yy[1, 7]) and np.isnan(g[1, :, 7]).all() and np.isnan(a2[1, :, 7]).all()
    assert np.isfinite(np.delete(yy.ravel(), 1 * n_l + 7)).all()


def test_numpy_block_sums_equal_the_compiled_ones_bit_for_bit() -> None:
    """numpy's sums (``_numpy_block_sums``: each product and sum rounded on its own, averages in
    order) give the compiled kernel's bits, not merely its values to rounding: a process gives
    the same FRFs whichever it uses. Two inputs, NaN and infinity kept to their line, and the
    contiguous views the estimator passes."""
    from dimacq.pipeline._spectral_kernel import block_sums
    from dimacq.pipeline.frf_estimation import _numpy_block_sums

    rng = np.random.default_rng(405)
    for n_avg, n_out, n_in, n_l in ((5, 3, 2, 33), (1, 7, 1, 1025), (10, 2, 3, 5)):
        y = rng.standard_normal((n_avg, n_out, n_l)) + 1j * rng.standard_normal((n_avg, n_out, n_l))
        fc = rng.standard_normal((n_avg, n_in, n_l)) * 1e3 + 1j * rng.standard_normal(
            (n_avg, n_in, n_l)
        )
        y[0, n_out - 1, n_l // 2] = np.nan
        fc[n_avg - 1, 0, 1] = np.inf
        out = []
        for sums in (block_sums, _numpy_block_sums):
            g = np.full((n_out, n_in, n_l), 7.0 + 7.0j)  # overwritten, not added to
            a2 = np.full((n_out, n_in, n_l), 7.0)
            yy = np.full((n_out, n_l), 7.0)
            sums(y, fc, g, a2, yy)
            out.append((g, a2, yy))
        for compiled, numpy_ in zip(*out, strict=True):
            np.testing.assert_array_equal(numpy_, compiled)
        np.testing.assert_allclose(
            out[1][0][: n_out - 1, :, 2:],
            np.einsum("aol,ail->oil", y, fc)[: n_out - 1, :, 2:],
            rtol=1e-13,
            atol=1e-13,
        )


def test_a_process_loads_numba_only_past_its_budget_of_sums() -> None:
    """An impact test's FRFs are summed by numpy (numba not loaded: about 100 MB); past
    ``NUMPY_SUMS_BUDGET`` products the compiled sums are loaded; the FRFs are the same bits."""
    code = """
import sys
import numpy as np
from dimacq.pipeline import frf_estimation as fe
rng = np.random.default_rng(3)
x = rng.standard_normal((5, 1, 4096))
y = rng.standard_normal((5, 30, 4096)) + x
a = fe.estimate_frf(x, y, 1024.0, estimator="Hv")
b = fe.estimate_frf(x, y, 1024.0)
print("numba" in sys.modules)
fe.NUMPY_SUMS_BUDGET = fe._SumsChoice.numpy_products
c = fe.estimate_frf(x, y, 1024.0)
print("numba" in sys.modules, fe._SumsChoice.numpy_products)
print(np.array_equal(b.H, c.H) and np.array_equal(b.coherence, c.coherence)
      and np.array_equal(b.g_yy, c.g_yy))
"""
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True
    ).stdout.split()
    assert out == ["False", "True", str(2 * 5 * 30 * 2049), "True"]


def test_results_own_their_memory_across_calls_and_threads() -> None:
    """Results are fresh arrays, not views of work memory: a later call of another size, or calls
    from several threads at once (the compiled sums release the GIL), leave earlier results
    unchanged and equal to a lone call's."""
    from concurrent.futures import ThreadPoolExecutor

    rng = np.random.default_rng(9)
    sets = [
        (rng.standard_normal((a, 1, n)), rng.standard_normal((a, o, n)))
        for a, o, n in ((4, 9, 512), (2, 3, 128), (6, 17, 1024))
    ]
    w = {n: exponential_window(n, FS, 0.2) for n in (128, 512, 1024)}

    def run(k: int) -> tuple[np.ndarray, np.ndarray]:
        x, y = sets[k]
        n = x.shape[-1]
        est = estimate_frf(x, y, FS, input_window=w[n], output_window=w[n])
        return est.H, est.coherence

    lone = [tuple(a.copy() for a in run(k)) for k in range(3)]
    first = run(0)
    run(2)
    run(1)
    np.testing.assert_array_equal(first[0], lone[0][0])
    np.testing.assert_array_equal(first[1], lone[0][1])
    with ThreadPoolExecutor(3) as pool:
        got = list(pool.map(run, [0, 1, 2, 2, 1, 0] * 3))
    for k, (h, c) in zip([0, 1, 2, 2, 1, 0] * 3, got, strict=True):
        np.testing.assert_array_equal(h, lone[k][0])
        np.testing.assert_array_equal(c, lone[k][1])
