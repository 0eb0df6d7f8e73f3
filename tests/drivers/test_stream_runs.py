"""``false_runs``: the gaps the load cell drivers report, one event per contiguous run."""

from __future__ import annotations

import numpy as np

from dimacq.drivers.stream import false_runs


def _by_loop(valid: np.ndarray) -> list[tuple[int, int]]:
    out: list[tuple[int, int]] = []
    for i, v in enumerate(valid):
        if not v:
            if out and out[-1][1] == i - 1:
                out[-1] = (out[-1][0], i)
            else:
                out.append((i, i))
    return out


def test_runs_match_a_plain_loop() -> None:
    rng = np.random.default_rng(3)
    for n in (0, 1, 2, 7, 50):
        for _ in range(20):
            valid = rng.random(n) > 0.3
            assert false_runs(valid) == _by_loop(valid), valid
    assert false_runs(np.array([True, False, False, True, False])) == [(1, 2), (4, 4)]
