"""Two simulated Net F/T sensors and two CiA 404 nodes on one CAN channel, opened once through
the bus registry: every driver reads its own device, and the channel closes with its last user."""

from __future__ import annotations

import itertools
import os
from pathlib import Path
from typing import Any

import can
import numpy as np
import pytest
from _acq_support import no_leaks

from dimacq.backends.can_bus import CanBusRegistry
from dimacq.drivers.cia404.driver import CanChannel, Cia404Amplifier
from dimacq.drivers.netft import protocol as p
from dimacq.drivers.netft.can_driver import NetFtCan, bus_filters
from dimacq.errors import SetupError
from dimacq.simulators.cia404.node import Cia404NodeSim, SyncProducerSim
from dimacq.simulators.daq.clock import SampleClock
from dimacq.simulators.netft.can_sensor import NetFtCanSim

__all__ = ["no_leaks"]

EDS = Path(__file__).resolve().parents[2] / "config" / "canopen" / "cia404-generic.eds"
_n = itertools.count()


class Bridges:
    """Channel ``c`` holds ``1e-3 (c + 1)`` (constant: a held value of any age is exact)."""

    sample_rate_hz = 1000.0
    channel_names = tuple(f"g{c}" for c in range(48))
    channel_units = ("mV/V",) * 48

    def read(self, channels: Any, start: int, n: int) -> np.ndarray:
        return np.repeat(1e-3 * (np.asarray(channels, float)[:, None] + 1), n, axis=1)

    def excite(self, input_index: int, at_sample: int) -> None:
        pass


def test_two_net_fts_and_two_cia404_nodes_on_one_channel(no_leaks: None) -> None:
    name = f"shared-{os.getpid()}-{next(_n)}"
    reg = CanBusRegistry()
    src = Bridges()
    clock = SampleClock()
    cal = p.CalibrationInfo(2, 3, 1_000_000, 1_000_000)
    C = np.random.default_rng(3).normal(size=(6, 12)) * 100.0
    closers: list[Any] = []
    try:
        for base, first in ((0x100, 0), (0x110, 12)):
            sim = NetFtCanSim(name, src, range(first, first + 12), C, cal, base=base, clock=clock)
            closers.append(sim.close)
        nodes = [
            Cia404NodeSim(name, EDS, src, range(first, first + 12), node_id=nid, serial_number=nid)
            for nid, first in ((3, 24), (4, 36))
        ]
        closers.extend(n.close for n in nodes)
        prod = SyncProducerSim(name, clock, nodes)
        closers.append(prod.close)

        def opener() -> Any:
            return can.Bus(interface="virtual", channel=name)

        fts = []
        for base in (0x100, 0x110):
            h = reg.acquire("virtual", name, opener, can_filters=bus_filters(base))
            closers.append(h.shutdown)
            d = NetFtCan(h, base=base, calibration=cal, timeout_s=5.0, band_hz=100.0)
            closers.append(d.close)
            fts.append(d)
        ch = CanChannel(
            reg.acquire("virtual", name, opener),
            bitrate=1_000_000,
            max_load=2.0,
            where="test",
            enforce=False,
        )
        closers.append(ch.close)
        amps = []
        for nid in (3, 4):
            a = Cia404Amplifier(ch, node_id=nid, eds=EDS, timeout_s=5.0, gauge_unit="mV/V")
            closers.append(a.close)
            amps.append(a)
        assert reg.users("virtual", name) == 3  # one bus, three handles
        with pytest.raises(SetupError, match="already open with"):
            reg.acquire("virtual", name, opener, options="bitrate 500000")
        for d, first in zip(fts, (0, 12), strict=True):
            d.identify()
            counts, _, _ = d.read_once()  # its own calibration, in N and N·m
            g = 1e-3 * (np.arange(first, first + 12) + 1)
            np.testing.assert_allclose(cal.matrix() @ counts, C @ g, atol=2e-6)
        for a in amps:
            a.identify()
        devices = [*fts, *amps]
        for d in devices:
            d.set_rate(1000)
            d.start()
        clock.start(100, 1000.0)
        clock.advance(200)
        blocks = [d.read_until(200, timeout_s=20.0) for d in devices]
        clock.stop()
        for d in devices:
            d.stop()
        for d, first, b in zip(devices, (0, 12, 24, 36), blocks, strict=True):
            g = 1e-3 * (np.arange(first, first + 12) + 1)
            assert b.first_sample == 0 and b.n_samples == 200 and b.valid.all(), d.name
            if isinstance(d, NetFtCan):  # BIAS at its start: the constant load reads zero
                np.testing.assert_allclose(b.forces, 0.0, atol=2e-6)
            else:  # the inputs' process values
                np.testing.assert_allclose(b.gauges_v[:, -1], g, rtol=1e-6)
            assert d.verify_count(200) is None
    finally:
        for c in reversed(closers):
            c()
    assert reg.users("virtual", name) == 0
