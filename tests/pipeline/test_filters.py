"""The moving median / mean of :mod:`dimacq.pipeline._filters` against scipy.ndimage, bit for bit."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.ndimage import median_filter, uniform_filter1d

from dimacq.pipeline._filters import median_filter_nearest, uniform_filter_nearest


@pytest.mark.parametrize("n", [1, 2, 7, 50, 2045])
@pytest.mark.parametrize("w", [1, 2, 3, 4, 33, 136])
def test_filters_equal_ndimage_with_nearest_edges(n: int, w: int) -> None:
    rng = np.random.default_rng(n * 1000 + w)
    x = rng.normal(size=(n, 5, 4)) ** 2
    x[rng.integers(0, n, n // 3)] = 1.0  # ties for the median
    np.testing.assert_array_equal(
        median_filter_nearest(x, w), median_filter(x, size=(w, 1, 1), mode="nearest")
    )
    np.testing.assert_array_equal(
        median_filter_nearest(x[:, 0, 0], w), median_filter(x[:, 0, 0], size=w, mode="nearest")
    )
    np.testing.assert_array_equal(
        uniform_filter_nearest(x, w), uniform_filter1d(x, size=w, axis=0, mode="nearest")
    )


def test_a_window_of_zero_lines_is_refused() -> None:
    with pytest.raises(ValueError, match="give 1 or more lines"):
        median_filter_nearest(np.ones(4), 0)


@pytest.mark.parametrize("n", [1, 2, 5, 24])
@pytest.mark.parametrize("axis", [0, 1, 2])
def test_median_along_is_numpys_median(n: int, axis: int) -> None:
    from dimacq.pipeline._filters import median_along

    rng = np.random.default_rng(n + 10 * axis)
    shape = [7, 6, 5]
    shape[axis] = n
    x = rng.normal(size=shape)
    x[x > 1.5] = 0.25  # ties
    x.flat[3] = np.nan  # a slice with NaN gives NaN
    with np.errstate(invalid="ignore"):
        want = np.median(x, axis=axis)
    got = median_along(x, axis)
    assert got.shape == want.shape
    assert np.array_equal(got, want, equal_nan=True)
    assert np.isnan(got).sum() == 1  # the one slice holding the NaN
