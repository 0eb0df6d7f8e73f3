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

__all__ = ["held_sample", "read_between"]


#: the band-limited interpolator: taps i − 7 .. i + 8 around the world's sample i, Kaiser β
INTERP_TAPS = np.arange(-7, 9)
_BETA = 8.0


def sinc_weights(d: np.ndarray) -> np.ndarray:
    """Weights of the world's samples at distances ``d = x − (i + k)`` (shape (n, 16)): a
    Kaiser-windowed sinc ``sinc(d) I0(β √(1 − (d/8.5)²)) / I0(β)``, each row normalised to a
    sum of 1 (exact at DC)."""
    win = np.i0(_BETA * np.sqrt(np.clip(1.0 - (d / 8.5) ** 2, 0.0, None))) / np.i0(_BETA)
    w = np.sinc(d) * win
    return w / w.sum(axis=1, keepdims=True)


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
    idx = np.floor(y).astype(np.int64)[:, None] + INTERP_TAPS[None, :]
    lo = max(0, int(idx.min()))
    with lock:
        g = source.read(channels, lo, int(idx.max()) + 1 - lo)
    w = sinc_weights(y[:, None] - idx)
    return np.einsum("gnk,nk->gn", g[:, np.clip(idx - lo, 0, g.shape[1] - 1)], w)
