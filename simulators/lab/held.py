"""A device's own free-running sampling of the lab's world: held (and averaged) values.

A device that samples on its own clock at ``f_a`` (phase ``φ`` at power-on, in its samples)
takes its sample ``m`` at world position ``y_m = (m + φ) · fs / f_a`` (``fs`` the world's
rate). Asked at world position ``x`` (a request, a SYNC) it gives what it last produced: sample
``m = ⌊x · f_a / fs − φ⌋``, or the mean of its last ``N`` samples (a moving-average filter,
``N = 1``: none). The world exists as samples at ``fs``; between them it is interpolated
band-limited (the 16-tap Kaiser-windowed sinc of the RDT simulator).
"""

from __future__ import annotations

from contextlib import AbstractContextManager

import numpy as np
from numpy.typing import NDArray

from dimacq.simulators.lab.source import SampleSource
from dimacq.simulators.netft.udp_sensor import _TAPS, _sinc_weights

__all__ = ["held_sample", "read_between"]


def held_sample(
    x: NDArray[np.float64], per_world: float, phase: float
) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """``(y, m)``: the world position of the last own sample at or before each ``x`` and its
    number (``per_world = f_a / fs``)."""
    m = np.floor(np.asarray(x, dtype=float) * per_world - phase).astype(np.int64)
    return np.asarray((m + phase) / per_world, dtype=np.float64), m


def read_between(
    source: SampleSource,
    channels: NDArray[np.intp],
    y: NDArray[np.float64],
    lock: AbstractContextManager[object],
) -> NDArray[np.float64]:
    """The channels at world positions ``y`` (band-limited), shape (n_channels, len(y))."""
    y = np.asarray(y, dtype=float).ravel()
    idx = np.floor(y).astype(np.int64)[:, None] + _TAPS[None, :]
    lo = max(0, int(idx.min()))
    with lock:
        g = source.read(channels, lo, int(idx.max()) + 1 - lo)
    w = _sinc_weights(y[:, None] - idx)
    return np.einsum("gnk,nk->gn", g[:, np.clip(idx - lo, 0, g.shape[1] - 1)], w)
