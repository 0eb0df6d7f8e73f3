"""The line-to-line noise estimate of :mod:`dimacq.pipeline.line_noise` against known noise."""

from __future__ import annotations

import numpy as np
import pytest

from dimacq.pipeline.line_noise import (
    difference_gain,
    line_difference,
    line_sigma,
    scatter_sigma,
    scatter_variance,
)


@pytest.mark.parametrize("order", [1, 2, 3, 4])
def test_difference_is_numpys_and_removes_a_polynomial(order: int) -> None:
    rng = np.random.default_rng(order)
    x = rng.normal(size=(40, 3))
    np.testing.assert_allclose(
        line_difference(x, order), (-1) ** order * np.diff(x, n=order, axis=0), atol=1e-12
    )
    lines = np.arange(50.0)
    poly = np.polyval(rng.normal(size=order), lines)  # degree order − 1
    np.testing.assert_allclose(line_difference(poly, order), 0.0, atol=1e-8 * np.abs(poly).max())
    # white noise: the variance of its differences is C(2k, k) σ² (sum of squared binomials)
    assert difference_gain(order) == sum(
        int(np.round(c)) ** 2 for c in np.abs(line_difference(np.eye(order + 1), order)[0])
    )


@pytest.mark.parametrize("order", [1, 2, 3])
def test_sigma_of_white_noise_on_a_smooth_curve(order: int) -> None:
    rng = np.random.default_rng(10 + order)
    n, sigma = 20000, 0.03
    f = np.linspace(1.0, 2.0, n)
    smooth = (1.0 + 0.2 * f**2)[:, None]  # a mass line's curvature, small per line
    real = smooth + sigma * rng.normal(size=(n, 2))
    cplx = smooth + sigma / np.sqrt(2) * (rng.normal(size=(n, 2)) + 1j * rng.normal(size=(n, 2)))
    np.testing.assert_allclose(scatter_sigma(real, order), sigma, rtol=0.03)
    np.testing.assert_allclose(scatter_sigma(cplx, order), sigma, rtol=0.03)
    power = np.abs(line_difference(cplx, order)) ** 2
    np.testing.assert_allclose(scatter_variance(power, order), scatter_sigma(cplx, order) ** 2)


def test_line_sigma_is_centred_and_matches_the_rms() -> None:
    rng = np.random.default_rng(3)
    x = rng.normal(size=(30, 500)) * 0.1
    for order in (1, 2, 3):
        s = line_sigma(x, order)
        assert s.shape == (30,)
        d = line_difference(x, order)
        core = np.sqrt(np.mean(d**2, axis=1) / difference_gain(order))
        before = order - order // 2
        np.testing.assert_array_equal(s[before : before + core.size], core)
        np.testing.assert_allclose(np.median(s), 0.1, rtol=0.05)


def test_order_zero_is_refused() -> None:
    with pytest.raises(ValueError, match="give 1 or more"):
        line_difference(np.ones(5), 0)
    with pytest.raises(ValueError, match="give the series"):
        scatter_sigma(None, 1)
