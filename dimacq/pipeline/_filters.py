"""Moving median and moving mean along one axis, edges extended with the nearest value; the
median along a short axis.

``scipy.ndimage.median_filter(x, size=(w, 1, …), mode="nearest")`` and
``scipy.ndimage.uniform_filter1d(x, w, axis=0, mode="nearest")`` to the bit, without importing
``scipy.ndimage`` (a quarter of a second of ``dimacq solve``'s start-up):

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

__all__ = ["median_along", "median_filter_nearest", "uniform_filter_nearest"]


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
    # Each line's windows along the last axis of a contiguous copy (the other axes first), in
    # blocks of lines: np.partition copies the windows it selects from, n·w values at once (22 MB
    # for the band search's 2048 lines × 10 estimates × 137); a block's copy stays in the cache.
    # The same selection gives the same numbers.
    ext_t = np.ascontiguousarray(np.moveaxis(ext, 0, -1))  # (…, n + w − 1)
    win = np.lib.stride_tricks.sliding_window_view(ext_t, w, axis=-1)  # (…, n, w)
    n = win.shape[-2]
    out_t = np.empty(win.shape[:-1])
    step = max(1, (1 << 18) // max(1, w * int(np.prod(win.shape[:-2]))))
    for i in range(0, n, step):
        out_t[..., i : i + step] = np.partition(win[..., i : i + step, :], w // 2, axis=-1)[
            ..., w // 2
        ]
    out: NDArray[np.float64] = np.ascontiguousarray(np.moveaxis(out_t, -1, 0))
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


def median_along(x: NDArray[np.floating], axis: int) -> NDArray[np.float64]:
    """``np.median(x, axis=axis)`` by sorting that axis: the same numbers, faster on a short axis.

    ``np.median`` partitions a copy with the axis moved last, one selection per slice: on
    (1290, 24, 24) FRF powers over the 24 channels that is 12 ms, a sort of the same slices
    (numpy's vectorised sort) 2.5 ms. The middle value (odd length) or the mean of the middle
    two (even: ``(a + b) / 2``, the sum and division ``np.mean`` makes of them) of the sorted
    slice are the values the partition selects, so the result is the same to the bit, except
    for the sign of a zero that ties with a ``-0.0``; a slice holding NaN gives NaN, as
    ``np.median`` does.
    """
    s = np.sort(np.moveaxis(np.asarray(x, dtype=np.float64), axis, -1), axis=-1)
    n = s.shape[-1]
    if n == 0:
        return np.median(s, axis=-1)  # numpy's own warning and NaN
    out: NDArray[np.float64] = (
        s[..., n // 2].copy() if n % 2 else (s[..., n // 2 - 1] + s[..., n // 2]) / 2.0
    )
    nan = np.isnan(s[..., -1])  # NaN sorts last
    if nan.any():
        out[nan] = np.nan
    return out
