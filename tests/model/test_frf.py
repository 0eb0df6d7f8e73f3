"""FRF data model and unit conversions against closed forms."""

from __future__ import annotations

import numpy as np
import pytest

from dimacq.errors import DataError
from dimacq.model.frf import STANDARD_GRAVITY, Channel, FrfData, to_accelerance


def _frf(H: np.ndarray, f: np.ndarray | None = None) -> FrfData:
    n_lines, n_out, n_in = H.shape
    return FrfData(
        np.arange(1.0, n_lines + 1) if f is None else f,
        H,
        tuple(Channel(i + 1, 1) for i in range(n_out)),
        ("acceleration",) * n_out,
        tuple(Channel(100 + j, 1) for j in range(n_in)),
    )


def test_displacement_and_velocity_of_a_harmonic_become_acceleration() -> None:
    # x(t) = X cos(ωt) → ẍ = −ω² X: a displacement FRF of 1 mm/N at 10 Hz is −ω²·1e-3 (m/s²)/N.
    f = np.array([10.0, 20.0])
    w = 2 * np.pi * f
    H = np.ones((2, 1, 1), dtype=complex)
    a = to_accelerance(H, f, quantity="displacement", unit="mm")
    assert np.allclose(a[:, 0, 0], -(w**2) * 1e-3)
    v = to_accelerance(H, f, quantity="velocity", unit="m")
    assert np.allclose(v[:, 0, 0], 1j * w)
    g = to_accelerance(H, f, quantity="acceleration", unit="g")
    assert np.allclose(g, STANDARD_GRAVITY)
    with pytest.raises(DataError, match="only to acceleration"):
        to_accelerance(H, f, quantity="velocity", unit="g")


def test_nan_is_refused_naming_the_record_and_frequency() -> None:
    H = np.ones((3, 2, 1), dtype=complex)
    H[1, 1, 0] = np.nan
    with pytest.raises(DataError, match=r"2\+X/100\+X has NaN or inf at 2 Hz"):
        _frf(H)


def test_shape_and_axis_mismatches_are_refused() -> None:
    with pytest.raises(DataError, match="n_lines=2"):
        _frf(np.ones((3, 1, 1), dtype=complex), f=np.array([1.0, 2.0]))
    with pytest.raises(DataError, match="strictly increasing"):
        _frf(np.ones((2, 1, 1), dtype=complex), f=np.array([2.0, 1.0]))


def test_band_select_and_scale() -> None:
    H = np.arange(24, dtype=complex).reshape(4, 3, 2)
    frf = _frf(H)
    b = frf.band(2.0, 3.0)
    assert np.array_equal(b.frequencies_hz, [2.0, 3.0]) and np.array_equal(b.H, H[1:3])
    s = frf.select(outputs=np.array([2, 0]), inputs=np.array([1]))
    assert s.outputs == (Channel(3, 1), Channel(1, 1)) and np.array_equal(
        s.H, H[:, [2, 0]][:, :, [1]]
    )
    assert np.allclose(frf.scaled(2.0).H, 2 * H)
    with pytest.raises(DataError, match="holds no line"):
        frf.band(10.0, 20.0)
