"""The |H| envelope and mean coherence of an FRF set (dimacq.pipeline.frf_summary) against plain
loops over the lines."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from dimacq.pipeline.frf_summary import magnitude_envelope


def _loops(f, h, coh, points):  # type: ignore[no-untyped-def]
    n = f.size
    g = min(points, n)
    bounds = [round(k * n / g) for k in range(g + 1)]
    mx, mn, fc = [], [], []
    for a, b in itertools.pairwise(bounds):
        mags = [
            [[abs(h[l, o, i]) for i in range(h.shape[2])] for o in range(h.shape[1])]
            for l in range(a, b)
        ]
        mx.append(np.max(mags, axis=0))
        mn.append(np.min(mags, axis=0))
        fc.append((f[a] + f[b - 1]) / 2)
    mean = np.full(h.shape[1:], np.nan)
    for o in range(h.shape[1]):
        for i in range(h.shape[2]):
            vals = [coh[l, o, i] for l in range(n) if np.isfinite(coh[l, o, i])]
            if vals:
                mean[o, i] = sum(vals) / len(vals)
    return np.array(fc), np.array(mx), np.array(mn), mean


@pytest.mark.parametrize(("n", "points"), [(2048, 512), (300, 70), (37, 10), (5, 9), (1, 1)])
def test_envelope_matches_loops(n: int, points: int) -> None:
    rng = np.random.default_rng(n + points)
    f = np.sort(rng.uniform(1, 500, n))
    h = rng.normal(size=(n, 3, 2)) + 1j * rng.normal(size=(n, 3, 2))
    coh = rng.uniform(0, 1, (n, 3, 2))
    coh[rng.uniform(size=coh.shape) < 0.2] = np.nan
    coh[:, 2, 1] = np.nan  # a pair with no coherence at all
    env = magnitude_envelope(f, h, coh, points)
    fc, mx, mn, mean = _loops(f, h, coh, points)
    assert env.magnitude_max.shape == (min(n, points), 3, 2)
    np.testing.assert_allclose(env.frequencies_hz, fc, rtol=1e-15)
    np.testing.assert_allclose(env.magnitude_max, mx, rtol=1e-15)
    np.testing.assert_allclose(env.magnitude_min, mn, rtol=1e-15)
    assert env.coherence_mean is not None
    np.testing.assert_allclose(env.coherence_mean, mean, rtol=1e-12, equal_nan=True)
    assert np.isnan(env.coherence_mean[2, 1])
    # a resonance peak of one line survives the reduction
    h2 = h.copy()
    h2[n // 3, 1, 0] = 1e6
    assert magnitude_envelope(f, h2, None, points).magnitude_max[:, 1, 0].max() == 1e6


def test_envelope_refuses_bad_arguments() -> None:
    f = np.arange(4.0)
    with pytest.raises(ValueError, match="points 0"):
        magnitude_envelope(f, np.zeros((4, 1, 1), complex), None, 0)
    with pytest.raises(ValueError, match="H has 3 lines"):
        magnitude_envelope(f, np.zeros((3, 1, 1), complex), None, 5)
    empty = magnitude_envelope(f[:0], np.zeros((0, 2, 1), complex), None, 5)
    assert empty.magnitude_max.shape == (0, 2, 1) and empty.lines_per_point == 0
