"""The shared sample-counter stream buffer (drivers/stream.py)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest

from dimacq.drivers.stream import CounterStream
from dimacq.errors import SetupError


@dataclass(frozen=True)
class Ev:
    first_sample: int
    n_samples: int


def samples(counters):
    c = np.asarray(counters, dtype=np.int64)
    return c, np.column_stack([c, -c]).astype(float), (c % 3 == 0).astype(np.uint8)


def test_counters_with_holes_read_as_nan_and_not_valid():
    st: CounterStream[Ev] = CounterStream(2)
    st.put_counters(*samples([0, 1, 2, 5, 6, 9]))
    assert (st.end, st.buffered) == (10, 10)
    got = st.take(8)
    assert got.first == 0 and got.valid.tolist() == [1, 1, 1, 0, 0, 1, 1, 0]
    np.testing.assert_array_equal(got.data[[0, 1, 2, 5, 6], 0], [0, 1, 2, 5, 6])
    assert np.isnan(got.data[[3, 4, 7]]).all()
    assert got.flags.tolist() == [1, 0, 0, 0, 0, 0, 1, 0]
    rest = st.take(10)
    assert rest.first == 8 and rest.valid.tolist() == [False, True] and rest.data[1, 1] == -9


def test_runs_split_across_reads_and_late_samples_dropped():
    st: CounterStream[Ev] = CounterStream(1, flag_shape=(1,), flag_dtype=np.bool_)
    first_run = np.arange(6.0)[:, None]
    st.put(0, first_run, np.zeros((6, 1), bool))
    whole = st.take(4)  # one run covers the block: a view, no copy
    assert whole.valid.all() and np.shares_memory(whole.data, first_run)
    st.put(1, np.full((2, 1), 99.0), np.ones((2, 1), bool))  # already read: dropped
    st.put(6, np.arange(6.0, 9.0)[:, None], np.ones((3, 1), bool))
    got = st.take(9)
    np.testing.assert_array_equal(got.data[:, 0], [4, 5, 6, 7, 8])
    assert got.flags[:, 0].tolist() == [False, False, True, True, True]
    with pytest.raises(SetupError, match="not after the next unread sample 9"):
        st.take(9)


def test_events_go_with_every_block_they_overlap():
    st: CounterStream[Ev] = CounterStream(1)
    for e in (Ev(2, 1), Ev(3, 4), Ev(12, 0)):
        st.record(e)
    assert st.pop_events(0, 5) == (Ev(2, 1), Ev(3, 4))
    assert st.pop_events(5, 10) == (Ev(3, 4),)  # reaches into the second block
    assert st.pop_events(10, 20) == (Ev(12, 0),)
    assert st.pop_events(20, 30) == ()
