"""Random noise of a quantity sampled on evenly spaced lines, from its line-to-line scatter.

Differences along the lines remove what is smooth. The ``k``-th difference

    Δᵏx_ℓ = Σ_{i=0…k} (−1)ⁱ C(k, i) x_{ℓ+i}

annihilates every polynomial of degree below ``k`` in ``ℓ``. For noise ``e_ℓ`` independent from line
to line with variance ``σ²`` (for complex values the total variance ``E|e|²``) it leaves

    Var(Δᵏe) = σ² Σ_i C(k, i)² = C(2k, k) σ²    (Vandermonde: 2, 6, 20 for k = 1, 2, 3)

(:func:`difference_gain`), so ``σ`` follows from the scatter of the differences:

- a real series (:func:`scatter_sigma`): ``σ = 1.4826 MAD(Δᵏx) / √C(2k, k)``, the median absolute
  deviation about the median scaled to a normal variable's standard deviation (``1/Φ⁻¹(3/4)``);
  robust to the few lines a mode or an outlier moves;
- a complex series with circular noise (:func:`scatter_sigma`): ``|Δᵏx|²`` is exponential with
  mean ``C(2k, k) σ²`` and median ``ln 2 · C(2k, k) σ²``, so
  ``σ = √(median|Δᵏx|² / (C(2k, k) ln 2))`` (:func:`scatter_variance` gives ``σ²``);
- per line over many series (:func:`line_sigma`): ``σ_ℓ = RMS_series(Δᵏx_ℓ) / √C(2k, k)``, the
  ``L − k`` differences centred on the ``L`` lines by repeating the end ones.

Callers choose the order ``k`` by what their data must lose, and the orders differ for that reason:

- ``k = 1``: the band search's per-line DIM estimates (:mod:`dimacq.pipeline.selection.band`).
  On a rigid-body band they are one constant plus noise; the first difference removes it and,
  of all orders, scatters the noise least (gain 2), so a short run of lines still gives a level.
  The same for a load cell's gauge readings in time
  (:func:`dimacq.pipeline.loadcell_calibration.settled_mean`), where a creep or a step must
  not be removed: they are what that test looks for.
- ``k = 2``: the modal correction's relative FRF noise per line
  (:func:`dimacq.pipeline.modal.frf_noise`), over the whole span and through its resonances:
  a local straight line is removed, each line's level from the lines next to it.
- ``k = 3``: the output-error fit's FRF and reaction noise
  (:mod:`dimacq.pipeline.output_error.noise`). Its band is the mass line between the support modes and the first elastic mode, where an
  accelerance curves as ``A + B/ω² + C ω²`` (the modes' residual terms); the third difference
  removes that local quadratic, which a lower order would count as noise, inflating ``σ`` and with
  it the fit's weights and its χ² test.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import NDArray

__all__ = [
    "difference_gain",
    "line_difference",
    "line_sigma",
    "scatter_sigma",
    "scatter_variance",
]

FloatArray = NDArray[np.float64]

#: ``1/Φ⁻¹(3/4)``: the median absolute deviation of a normal variable times this is its σ.
MAD_TO_SIGMA = 1.4826


def difference_gain(order: int) -> int:
    """``C(2k, k)``: the variance of the ``k``-th difference of white noise in units of ``σ²``."""
    if order < 1:
        raise ValueError(f"difference order {order}: give 1 or more")
    return math.comb(2 * order, order)


def line_difference(x: NDArray[Any], order: int) -> NDArray[Any]:
    """``Δᵏx_ℓ = Σ_{i=0…k} (−1)ⁱ C(k, i) x_{ℓ+i}`` along axis 0 (module docstring).

    Parameters
    ----------
    x : ndarray, shape (n_lines, ...), real or complex
    order : int
        ``k`` (1 or more).

    Returns
    -------
    ndarray, shape (n_lines − k, ...)
    """
    difference_gain(order)  # checks the order
    x = np.asarray(x)
    n = x.shape[0] - order
    out = x[:n]
    for i in range(1, order + 1):  # in order of i, the sum written left to right
        out = out + (-1) ** i * math.comb(order, i) * x[i : i + n]
    return out


def scatter_sigma(
    x: NDArray[Any] | None, order: int, *, power: FloatArray | None = None
) -> FloatArray:
    """Noise standard deviation of each series along axis 0, from its ``order``-th differences.

    Real ``x``: ``σ = 1.4826 MAD(Δᵏx) / √C(2k, k)``. Complex ``x`` (circular noise, ``σ²`` the
    total variance): ``σ = √(median|Δᵏx|² / (C(2k, k) ln 2))`` (module docstring).

    Parameters
    ----------
    x : ndarray, shape (n_lines, ...), real or complex; or None when ``power`` is given
    order : int
        ``k``: 1 removes a constant, 2 a straight line, 3 a quadratic.
    power : ndarray, shape (n_lines − k, ...), optional
        ``|Δᵏx|²`` of complex ``x`` if already formed.

    Returns
    -------
    ndarray, shape (...)
        Same unit as ``x``.
    """
    gain = difference_gain(order)
    if power is None:
        if x is None:
            raise ValueError("scatter_sigma: give the series x or the power of its differences")
        d = line_difference(x, order)
        if not np.iscomplexobj(d):
            mad = np.median(np.abs(d - np.median(d, axis=0)), axis=0)
            return np.asarray(MAD_TO_SIGMA * mad / np.sqrt(gain), float)
        power = np.asarray(np.abs(d) ** 2, float)
    return np.asarray(np.sqrt(scatter_variance(power, order)), float)


def scatter_variance(power: FloatArray, order: int) -> FloatArray:
    """Total variance ``σ²`` of circular complex noise from the powers ``|Δᵏx|²`` of its
    ``order``-th differences along axis 0: ``median|Δᵏx|² / (C(2k, k) ln 2)`` (module docstring).

    Parameters
    ----------
    power : ndarray, shape (n_lines − k, ...)
    order : int

    Returns
    -------
    ndarray, shape (...)
    """
    return np.asarray(np.median(power, axis=0) / (difference_gain(order) * np.log(2)), float)


def line_sigma(x: NDArray[Any], order: int) -> FloatArray:
    """Noise standard deviation per line over many series: ``RMS_series(Δᵏx_ℓ) / √C(2k, k)``.

    Parameters
    ----------
    x : ndarray, shape (n_lines, n_series), real or complex, ``n_lines > order``
    order : int

    Returns
    -------
    ndarray, shape (n_lines,)
        The ``n_lines − k`` differences' levels, the first repeated ``k − k // 2`` times before
        and the last ``k // 2`` times after, so that each stands on the lines it spans.
    """
    d = line_difference(np.asarray(x).reshape(np.shape(x)[0], -1), order)
    s = np.sqrt(np.mean(np.abs(d) ** 2, axis=1) / difference_gain(order))
    before, after = order - order // 2, order // 2
    return np.concatenate([np.repeat(s[:1], before), s, np.repeat(s[-1:], after)])
