"""The FRF records' common frequency axis: the first record off it is named."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest


def test_common_axis_names_the_first_record_off_the_axis() -> None:
    """The stacked comparison reports what the per-record np.allclose loop reported."""
    from dimacq.errors import DataError
    from dimacq.io.uff import _common_axis, _Record

    f = np.linspace(1.0, 100.0, 100)

    def rec(k: int, axis: np.ndarray) -> _Record:
        return _Record(k, k, 1, 50, 1, "acceleration", axis, np.zeros(axis.size, complex))

    good = [rec(k, f * (1 + 1e-10 * k)) for k in range(1, 5)]  # within rtol 1e-9
    assert _common_axis(good, Path("t.uff")) is good[0].frequencies_hz
    off = good[:2] + [rec(7, f + 0.5), rec(8, f[:-1]), rec(9, f + 1.0)]
    with pytest.raises(DataError, match=r"58 record #7 \(7\+X/50\+X\) has 100 lines 1.5"):
        _common_axis(off, Path("t.uff"))
    short_first = good[:2] + [rec(8, f[:-1]), rec(9, f + 1.0)]
    with pytest.raises(DataError, match=r"58 record #8 .* has 99 lines"):
        _common_axis(short_first, Path("t.uff"))
