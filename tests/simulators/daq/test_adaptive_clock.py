"""The adaptive time-lapse of the simulated DAQ clock, on a wall clock the test moves."""

from __future__ import annotations

import pytest

from dimacq.simulators.daq import clock as clock_mod
from dimacq.simulators.daq.clock import MIN_SCALE, RECOVER_AFTER_S, SampleClock


class _Wall:
    def __init__(self) -> None:
        self.t = 100.0

    def __call__(self) -> float:
        return self.t


@pytest.fixture
def wall(monkeypatch: pytest.MonkeyPatch) -> _Wall:
    w = _Wall()
    monkeypatch.setattr(clock_mod.time, "monotonic", w)
    return w


def test_fixed_clock_ignores_limits(wall: _Wall) -> None:
    c = SampleClock()
    c.start(10, 1000.0, wall_scale=4.0)
    c.hold_at("daq", 100)
    wall.t += 1.0
    assert c.count() == 4000  # not adaptive: a real DAQ's clock runs on
    assert c.position_at(wall.t) == 10 + 4000
    assert c.stop() == 4000
    r = c.run_report()
    assert r is not None and r.factors == (4.0,) and r.waits == 0 and not r.adaptive
    assert r.simulated_s == pytest.approx(4.0) and r.effective_scale == pytest.approx(4.0)


def test_adaptive_clock_waits_slows_and_recovers(wall: _Wall) -> None:
    c = SampleClock()
    c.start(0, 1000.0, wall_scale=8.0, adaptive=True)
    c.hold_at("daq", 2000)
    wall.t += 1.0  # 8000 pulses of wall time, room for 2000: the clock waits there, at 4x
    assert c.count() == 2000 and c.pulses_per_wall_s() == 4000.0
    wall.t += 0.5  # within SLOW_EVERY_S: still held, not slowed again
    assert c.count() == 2000 and c.pulses_per_wall_s() == 4000.0
    c.hold_at("daq", 10_000)
    wall.t += 0.5
    assert c.count() == 4000
    # the lab's position follows the segments: at the wall time of the last change, 2000
    assert c.position_at(101.5) == pytest.approx(2000.0)
    c.hold_at("daq", None)
    wall.t += RECOVER_AFTER_S  # no wait for as long: faster again, at most the start factor
    n = c.count()
    assert n == 4000 + int(RECOVER_AFTER_S * 4000) and c.pulses_per_wall_s() == 6000.0
    wall.t += RECOVER_AFTER_S
    c.count()
    assert c.pulses_per_wall_s() == 8000.0
    c.stop()
    r = c.run_report()
    assert r is not None and r.factors == (8.0, 4.0, 6.0, 8.0) and r.waits == 2 and r.adaptive


def test_adaptive_clock_slows_to_its_floor(wall: _Wall) -> None:
    c = SampleClock()
    c.start(0, 1000.0, wall_scale=2.0, adaptive=True)
    c.hold_at("a", 10)
    c.hold_at("b", 5)  # the lowest limit holds
    for _ in range(10):
        wall.t += 1.5
        assert c.count() == 5
    assert c.pulses_per_wall_s() == MIN_SCALE * 1000.0
    c.stop()
    c.start(5, 1000.0, wall_scale=2.0, adaptive=True)  # a new run forgets the limits
    wall.t += 1.0
    assert c.count() == 2000
