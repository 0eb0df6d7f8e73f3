"""The sliding sample window the acquisition session keeps per device (DAQ, each load cell)."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

__all__ = ["SampleWindow"]


class SampleWindow:
    """Samples ``first .. end - 1`` for the DAQ or one load cell, trimmed as records are cut.

    Storage is a preallocated array used as a sliding window: :meth:`append` writes after the
    last sample (growing the capacity by doubling when full, after moving the live samples to
    the front), :meth:`trim` only moves the start. With the live span bounded (the trigger wait
    trims to the pre-trigger history after every block) appending a block costs O(block), not
    O(samples held): no copy of the history per block.
    """

    def __init__(self, n_rows: int, capacity: int = 4096) -> None:
        self.first = 0
        self._a = 0  # storage column of sample ``first``
        self._n = 0  # samples held
        self._data = np.zeros((n_rows, capacity))
        self._valid = np.zeros(capacity, dtype=bool)
        self._over = np.zeros((n_rows, capacity), dtype=bool)
        self.drift: list[tuple[int, int]] = []
        #: device errors (an amplifier's EMCY, its NMT state leaving OPERATIONAL): [a, b) and why
        self.errors: list[tuple[int, int, str]] = []

    @property
    def end(self) -> int:
        return self.first + self._n

    @property
    def n_samples(self) -> int:
        return self._n

    @property
    def data(self) -> NDArray[np.float64]:
        """The held samples, shape (n_rows, n_samples) (a view)."""
        return self._data[:, self._a : self._a + self._n]

    def append(
        self, data: NDArray[np.float64], valid: NDArray[np.bool_], over: NDArray[np.bool_]
    ) -> None:
        m = valid.size
        cap = self._valid.size
        if self._a + self._n + m > cap:
            live = slice(self._a, self._a + self._n)
            new_cap = max(cap, 2 * (self._n + m))
            if new_cap > cap:
                d = np.zeros((self._data.shape[0], new_cap))
                v = np.zeros(new_cap, dtype=bool)
                o = np.zeros((self._data.shape[0], new_cap), dtype=bool)
            else:
                d, v, o = self._data, self._valid, self._over
            # move the live samples to the front (overlapping copy is safe left-ward)
            d[:, : self._n] = self._data[:, live]
            v[: self._n] = self._valid[live]
            o[:, : self._n] = self._over[:, live]
            self._data, self._valid, self._over = d, v, o
            self._a = 0
        b = self._a + self._n
        self._data[:, b : b + m] = data
        self._valid[b : b + m] = valid
        self._over[:, b : b + m] = over
        self._n += m

    def window(
        self, s0: int, n: int
    ) -> tuple[NDArray[np.float64], NDArray[np.bool_], NDArray[np.bool_]]:
        """Copies of samples ``s0 .. s0 + n - 1`` (clipped to what is held)."""
        a = self._a + max(0, s0 - self.first)
        b = min(self._a + self._n, self._a + s0 - self.first + n)
        return self._data[:, a:b].copy(), self._valid[a:b].copy(), self._over[:, a:b].copy()

    def trim(self, keep_from: int) -> None:
        k = min(self._n, max(0, keep_from - self.first))
        if k:
            self._a += k
            self._n -= k
            self.first += k
