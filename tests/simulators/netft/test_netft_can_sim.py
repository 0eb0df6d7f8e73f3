"""The simulated Net F/T answers the manual's frames on python-can's ``virtual`` bus: the
driver reads the loads its own calibration makes of the bridges, in the counts per unit it
holds; BIAS zeros them."""

from __future__ import annotations

import os
import uuid

import can
import numpy as np
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
