"""The simulated Net F/T answers the manual's frames on python-can's ``virtual`` bus: the
driver reads the loads its own calibration makes of the bridges, in the counts per unit it
holds; BIAS zeros them."""

from __future__ import annotations

import os
import uuid

import can
import numpy as np
import pytest
from numpy.typing import NDArray

from dimacq.drivers.netft import protocol as p
from dimacq.drivers.netft.can_driver import NetFtCan, bus_filters
from dimacq.simulators.netft.can_sensor import NetFtCanSim


class ConstantBridges:
    """Twelve bridge channels holding ``g``."""

    sample_rate_hz = 2048.0
    channel_names = tuple(f"LC1 g{k + 1:02d}" for k in range(12))
    channel_units = ("mV/V",) * 12

    def __init__(self, g: NDArray[np.float64]) -> None:
        self.g = g

    def read(self, channels: NDArray[np.intp], start: int, n: int) -> NDArray[np.float64]:
        return np.repeat(self.g[channels][:, None], n, axis=1)


def test_driver_reads_the_sensor_in_its_units() -> None:
    rng = np.random.default_rng(1)
    C = rng.normal(size=(6, 12)) * 100.0  # N per mV/V
    src = ConstantBridges(rng.normal(size=12) * 0.1)
    cal = p.CalibrationInfo(2, 3, 1_000_000, 500_000)
    channel = f"netft-test-{os.getpid()}-{uuid.uuid4().hex[:6]}"
    with NetFtCanSim(channel, src, range(12), C, cal, base=0x100) as sim:
        bus = can.Bus(interface="virtual", channel=channel, can_filters=bus_filters(0x100))
        try:
            drv = NetFtCan(bus, base=0x100, calibration=cal, timeout_s=2.0)
            counts, status, _ = drv.read_once()
            loads = C @ src.g
            np.testing.assert_allclose(counts, np.rint(loads * np.array([1e6] * 3 + [5e5] * 3)))
            assert status == 0
            np.testing.assert_allclose(cal.matrix() @ counts, loads, atol=2e-6)
            drv.bias()
            counts, _, _ = drv.read_once()
            np.testing.assert_array_equal(counts, 0)
            assert sim.injected == {}
        finally:
            bus.shutdown()


class Ramp:
    """Every bridge reads its world sample's number: a held value's age is seen at once."""

    sample_rate_hz = 1024.0
    channel_names = tuple(f"LC1 g{k + 1:02d}" for k in range(12))
    channel_units = ("mV/V",) * 12

    def read(self, channels: NDArray[np.intp], start: int, n: int) -> NDArray[np.float64]:
        k = np.arange(start, start + n, dtype=float)
        return np.repeat(k[None, :], len(channels), axis=0)


def test_answers_are_held_from_its_own_7khz_clock() -> None:
    """Requests on the DAQ's pulses (1024 S/s) answer the set its free-running 7 kHz clock last
    sampled: 0..1024/7000 of a DAQ sample old, on average half that (the driver's mean delay),
    spread as a uniform age (the driver's T/√12)."""
    from dimacq.simulators.daq.clock import SampleClock

    C = np.zeros((6, 12))
    C[np.arange(6), np.arange(6)] = 1.0  # loads = the first six bridges
    cal = p.CalibrationInfo(2, 3, 1_000, 1_000)
    channel = f"netft-held-{os.getpid()}-{uuid.uuid4().hex[:6]}"
    clock = SampleClock()
    with NetFtCanSim(channel, Ramp(), range(12), C, cal, base=0x100, clock=clock) as sim:
        bus = can.Bus(interface="virtual", channel=channel, can_filters=bus_filters(0x100))
        try:
            drv = NetFtCan(bus, base=0x100, calibration=cal, timeout_s=5.0, band_hz=100.0)
            drv.set_rate(1024)
            drv.start()
            clock.start(50, 1024.0)
            clock.advance(400)
            block = drv.read_until(400, timeout_s=20.0)
            clock.stop()
            drv.stop()
        finally:
            bus.shutdown()
    assert block.valid.all()
    k = 50 + np.arange(400)
    lag = k - (block.forces[0] + sim.bias_g[0])  # DAQ samples
    assert np.all(lag >= -1e-3) and np.all(lag <= 1024 / 7000 + 1e-3)
    assert np.mean(lag) == pytest.approx(drv.timing.mean_delay_s * 1024, abs=0.01)
    assert np.std(lag) == pytest.approx(drv.timing.spread_s * 1024, rel=0.1)
