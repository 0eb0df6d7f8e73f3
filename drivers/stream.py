"""The sample-counter stream buffer shared by the acquisition drivers (DAQ and load cell).

Both devices label every sample with a counter of the DAQ's sample clock (the DAQ's own sample
counter; the amplifier's count of the DAQ's SYNC pulses), so both streams are buffered the same
way: samples are filed by counter, never by arrival, and a read takes the counter range
``next_sample .. end − 1``. A sample that never arrived reads NaN with ``valid`` False, so a
block is always the full range it was asked for; events (gaps, overloads, drift, timeouts) are
recorded with the counter range they concern and handed out with the first block that overlaps
it (an event that reaches past the block's end is handed out again with the next one).

A driver files what it decoded with :meth:`CounterStream.put` (a contiguous run: the DAQ's
frame) or :meth:`CounterStream.put_counters` (one counter per sample: the amplifier's frames,
possibly with holes), records events with :meth:`CounterStream.record` and builds its block from
:meth:`CounterStream.take` and :meth:`CounterStream.pop_events`.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from typing import Generic, Protocol, TypeVar

import numpy as np
from numpy.typing import NDArray

from dimacq.errors import SetupError

__all__ = ["CounterStream", "StreamEvent", "Taken", "false_runs"]


class StreamEvent(Protocol):
    """What the buffer needs of an event: the counter range it concerns."""

    @property
    def first_sample(self) -> int: ...

    @property
    def n_samples(self) -> int: ...


E = TypeVar("E", bound=StreamEvent)


@dataclass(frozen=True, eq=False)
class _Run:
    first: int
    data: NDArray[np.float64]  # (n, n_channels)
    flags: NDArray[np.generic]  # (n, *flag_shape)

    @property
    def end(self) -> int:
        return self.first + self.data.shape[0]


@dataclass(frozen=True, eq=False)
class Taken:
    """Samples ``first .. first + n − 1``, sample-major.

    Attributes
    ----------
    data : ndarray, shape (n, n_channels)
        NaN where no sample arrived.
    flags : ndarray, shape (n, *flag_shape)
        The per-sample flags filed with the data (zero where no sample arrived).
    valid : ndarray of bool, shape (n,)
        True where the sample arrived.
    """

    first: int
    data: NDArray[np.float64]
    flags: NDArray[np.generic]
    valid: NDArray[np.bool_]


class CounterStream(Generic[E]):
    """Samples filed by sample counter, taken in counter order.

    Parameters
    ----------
    n_channels : int
    flag_shape : tuple of int
        Shape of one sample's flags: ``()`` for a status byte, ``(n_channels,)`` for a
        per-channel overload bit.
    flag_dtype : numpy dtype
    first_sample : int
        Counter of the first sample the reader wants.
    """

    def __init__(
        self,
        n_channels: int,
        *,
        flag_shape: tuple[int, ...] = (),
        flag_dtype: type[np.generic] = np.uint8,
        first_sample: int = 0,
    ) -> None:
        self.n_channels = n_channels
        self.flag_shape = flag_shape
        self.flag_dtype = flag_dtype
        self.next_sample = first_sample
        #: one past the highest counter received (``next_sample`` while nothing is buffered)
        self.end = first_sample
        self._runs: list[_Run] = []
        self._events: list[E] = []

    @property
    def buffered(self) -> int:
        """Samples from ``next_sample`` up to the highest received (holes included)."""
        return self.end - self.next_sample

    # -- filing ------------------------------------------------------------------------------
    def put(self, first: int, data: NDArray[np.float64], flags: NDArray[np.generic]) -> None:
        """File samples ``first .. first + n − 1`` (``data`` shape (n, n_channels)).

        Samples before :attr:`next_sample` (already read) are dropped.
        """
        n = data.shape[0]
        if n == 0 or first + n <= self.next_sample:
            return
        if first < self.next_sample:
            cut = self.next_sample - first
            first, data, flags = self.next_sample, data[cut:], flags[cut:]
        self._runs.append(_Run(first, data, flags))
        self.end = max(self.end, first + data.shape[0])

    def put_counters(
        self, counters: NDArray[np.int64], data: NDArray[np.float64], flags: NDArray[np.generic]
    ) -> None:
        """File samples labelled one by one (``counters`` shape (n,), unwrapped), split into
        contiguous runs."""
        if counters.size == 0:
            return
        breaks = np.flatnonzero(np.diff(counters) != 1) + 1
        bounds = [0, *breaks.tolist(), counters.size]
        for a, b in itertools.pairwise(bounds):
            self.put(int(counters[a]), data[a:b], flags[a:b])

    def record(self, event: E) -> None:
        """Keep ``event`` for the block(s) that overlap its counter range."""
        self._events.append(event)

    # -- reading -----------------------------------------------------------------------------
    def take(self, end: int) -> Taken:
        """Samples ``next_sample .. end − 1`` (NaN and not valid where none arrived); the
        buffer moves on to ``end``."""
        first = self.next_sample
        n = end - first
        if n <= 0:
            raise SetupError(f"end_sample {end} is not after the next unread sample {first}")
        runs, keep = [], []
        for r in self._runs:
            if r.first < end:
                runs.append(r)
            if r.end > end:
                cut = max(end - r.first, 0)
                keep.append(_Run(r.first + cut, r.data[cut:], r.flags[cut:]) if cut else r)
        self._runs = keep
        self.next_sample = end
        self.end = max(self.end, end)
        if len(runs) == 1 and runs[0].first == first and runs[0].end >= end:
            r = runs[0]  # the whole block is one run: no copy
            return Taken(first, r.data[:n], r.flags[:n], np.ones(n, dtype=bool))
        data = np.empty((n, self.n_channels))
        flags = np.zeros((n, *self.flag_shape), dtype=self.flag_dtype)
        valid = np.zeros(n, dtype=bool)
        for r in runs:
            a, b = max(r.first, first), min(r.end, end)
            data[a - first : b - first] = r.data[a - r.first : b - r.first]
            flags[a - first : b - first] = r.flags[a - r.first : b - r.first]
            valid[a - first : b - first] = True
        if not valid.all():
            data[~valid] = np.nan
        return Taken(first, data, flags, valid)

    def pop_events(self, first: int, end: int) -> tuple[E, ...]:
        """Events overlapping ``first .. end − 1``; those that reach past ``end`` are kept."""
        out = tuple(
            e
            for e in self._events
            if e.first_sample < end and e.first_sample + max(e.n_samples, 1) > first
        )
        self._events = [e for e in self._events if e.first_sample + max(e.n_samples, 1) > end]
        return out


def false_runs(valid: np.ndarray) -> list[tuple[int, int]]:
    """Contiguous runs ``(first, last)`` (inclusive indices) of False in ``valid``: the gaps a
    driver reports, one event per run."""
    missing = np.flatnonzero(~np.asarray(valid, dtype=bool))
    if missing.size == 0:
        return []
    breaks = np.flatnonzero(np.diff(missing) > 1)
    starts = np.concatenate([[missing[0]], missing[breaks + 1]])
    stops = np.concatenate([missing[breaks], [missing[-1]]])
    return [(int(a), int(b)) for a, b in zip(starts, stops, strict=True)]
