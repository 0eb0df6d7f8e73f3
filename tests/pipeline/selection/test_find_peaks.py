"""The band search's own peak finder against ``scipy.signal.find_peaks`` (the independent answer)."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.signal

from dimacq.pipeline.selection.band import find_peaks


@pytest.mark.slow
@pytest.mark.parametrize("seed", range(4))
def test_find_peaks_returns_what_scipy_returns(seed: int) -> None:
    """Flat tops (values rounded to thirds), infinities and NaN, short and long records."""
    rng = np.random.default_rng(seed)
    for t in range(600):
        n = int(rng.integers(0, 80)) if t % 50 else 2048
        x = np.round(rng.normal(size=n) * 3) / 3
        if n and t % 5 == 0:
            x[rng.integers(0, n)] = np.inf
        if n and t % 7 == 0:
            x[rng.integers(0, n)] = np.nan
        if n and t % 11 == 0:
            x[rng.integers(0, n)] = -np.inf
        for p in (0.0, 0.3, np.log10(2.0), 1.5):
            want = scipy.signal.find_peaks(x, prominence=p)[0]
            np.testing.assert_array_equal(find_peaks(x, p), want, err_msg=f"{x.tolist()}, {p}")


def test_cmif_like_curve_keeps_only_prominent_resonances() -> None:
    f = np.linspace(1.0, 100.0, 991)
    curve = np.log10(
        1 / np.abs(1 - (f / 20) ** 2 + 0.04j * f / 20) + 1 / np.abs(1 - (f / 70) ** 2 + 0.1j)
    )
    curve += 1e-3 * np.sin(f)  # ripple far below the prominence
    peaks = find_peaks(curve, 0.3)
    assert [round(float(f[p])) for p in peaks] == [20, 70]
