"""Moving median and moving mean along one axis, edges extended with the nearest value.

``scipy.ndimage.median_filter(x, size=(w, 1, …), mode="nearest")`` and
``scipy.ndimage.uniform_filter1d(x, w, axis=0, mode="nearest")`` to the bit, without importing
``scipy.ndimage`` (a quarter of a second of ``dimacq solve``'s start-up, issue #27):

* the median filter is a rank filter: output ``i`` is the ``w // 2``-th smallest (0-based) of the
  window ``x[i − w//2 … i − w//2 + w − 1]`` (indices clipped to the array: "nearest"); a
  selection, so any exact method gives the same number;
* the uniform filter is ndimage's running sum over the extended line ``x'``:
  ``s₀ = x₀' + … + x'_{w−1}`` added in order, ``sᵢ = sᵢ₋₁ + (x'_{i+w−1} − x'_{i−1})``, output
  ``sᵢ / w``; the running sum is ``np.cumsum`` (``add.accumulate``, sequential): the same
  additions in the same order (checked bit for bit against scipy 1.17 in the tests).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

__all__ = ["median_filter_nearest", "uniform_filter_nearest"]


def _extended(x: NDArray[np.floating], w: int) -> NDArray[np.float64]:
    """``x`` (along axis 0) with ``w // 2`` copies of the first and ``w − 1 − w // 2`` of the
    last value: index ``i`` of the result is index ``i − w // 2`` of ``x``, clipped."""
    n = x.shape[0]
    idx = np.clip(np.arange(-(w // 2), n + w - 1 - w // 2), 0, n - 1)
    return np.asarray(x, dtype=np.float64)[idx]


def median_filter_nearest(x: NDArray[np.floating], size: int) -> NDArray[np.float64]:
    """Moving ``size``-point median along axis 0 (rank ``size // 2``), shape of ``x``."""
    w = int(size)
    if w < 1:
        raise ValueError(f"median filter size {size}: give 1 or more lines")
    ext = _extended(x, w)
    win = np.lib.stride_tricks.sliding_window_view(ext, w, axis=0)  # (n, …, w)
    out: NDArray[np.float64] = np.partition(win, w // 2, axis=-1)[..., w // 2]
    return out


def uniform_filter_nearest(x: NDArray[np.floating], size: int) -> NDArray[np.float64]:
    """Moving ``size``-point mean along axis 0 (ndimage's running sum), shape of ``x``."""
    w = int(size)
    if w < 1:
        raise ValueError(f"uniform filter size {size}: give 1 or more lines")
    ext = _extended(x, w)
    n = x.shape[0]
    t0 = ext[0].copy()
    for k in range(1, w):  # in order, as ndimage adds them
        t0 += ext[k]
    steps = np.empty((n,) + ext.shape[1:])
    steps[0] = t0
    steps[1:] = ext[w : w + n - 1] - ext[: n - 1]
    out: NDArray[np.float64] = np.cumsum(steps, axis=0) / w
    return out
