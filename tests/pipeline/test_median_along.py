"""The median along a short axis of the output-error line weights against numpy's median."""

from __future__ import annotations

import numpy as np
import pytest

from dimacq.pipeline.output_error.noise import median_along


@pytest.mark.parametrize("n", [1, 2, 5, 24])
@pytest.mark.parametrize("axis", [0, 1, 2])
def test_median_along_is_numpys_median(n: int, axis: int) -> None:
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
