"""The amplifier simulator's bursts on a slow clock: at least :data:`BURST_PULSES` pulses apart
(their fixed cost is not paid 250 times per wall second at real time), :data:`BURST_S` apart on
a fast one or a clock the host's reads drive."""

from __future__ import annotations

import pytest

from dimacq.simulators.daq.clock import SampleClock
from dimacq.simulators.loadcell.pulses import BURST_PULSES, BURST_S, SyncPulses


class _Pulses(SyncPulses):
    def __init__(self, clock: SampleClock | None, rate_hz: float, time_scale: float) -> None:
        self.clock, self.rate_hz, self.time_scale, self._world_internal = (
            clock,
            rate_hz,
            time_scale,
            0,
        )
        self._init_pulses(128)


@pytest.mark.parametrize(("scale", "expected_s"), [(1.0, 128 / 2048), (4.0, 128 / 8192)])
def test_a_slow_clock_bursts_at_least_burst_pulses_apart(scale: float, expected_s: float) -> None:
    clock = SampleClock()
    clock.start(0, 2048.0, wall_scale=scale)
    sim = _Pulses(clock, 2048.0, 1.0)
    assert clock.pulses_per_wall_s() == 2048.0 * scale
    assert sim._burst_s() == pytest.approx(expected_s) and BURST_PULSES == 128
    clock.stop()
    assert clock.pulses_per_wall_s() is None and sim._burst_s() == BURST_S


def test_a_fast_clock_the_host_clock_and_the_internal_clock() -> None:
    clock = SampleClock()
    clock.start(0, 2048.0, wall_scale=40.0)
    assert _Pulses(clock, 2048.0, 1.0)._burst_s() == BURST_S  # 1.6 ms of pulses: BURST_S
    clock.start(0, 2048.0)  # clocked by the host's reads: no pace of its own
    assert _Pulses(clock, 2048.0, 1.0)._burst_s() == BURST_S
    internal = _Pulses(None, 2048.0, 2.0)
    internal._external = False  # its own oscillator at 2x
    assert internal._burst_s() == pytest.approx(128 / 4096)
