"""The CiA 404 driver against the LocalNode simulator of the generic EDS on a ``virtual`` channel,
with the SYNC producer on a test-driven DAQ clock: the samples are the source's at the DAQ's
pulses (alignment), EMCY and NMT state changes reject their samples, a different device is named
in one line, the bus load is summed over the channel's nodes, the host's SYNC is refused for an
acquisition."""

from __future__ import annotations

import itertools
import os
import struct
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import can
import numpy as np
import pytest
from _acq_support import no_leaks

from dimacq.drivers.cia404.driver import CanChannel, Cia404Amplifier
from dimacq.errors import SetupError
from dimacq.simulators.cia404.node import Cia404Faults, Cia404NodeSim, SyncProducerSim
from dimacq.simulators.daq.clock import SampleClock

__all__ = ["no_leaks"]

EDS = Path(__file__).resolve().parents[3] / "config" / "canopen" / "cia404-generic.eds"
_n = itertools.count()


class Ramp:
    """A source whose sample ``k`` of channel ``c`` is ``1e-3 (c + 1) + 1e-6 k`` (exact to REAL32
    rounding): a shifted sample is seen at once."""

    sample_rate_hz = 1000.0
    channel_names = tuple(f"c{c}" for c in range(12))
    channel_units = ("V",) * 12

    def read(self, channels: Any, start: int, n: int) -> np.ndarray:
        k = np.arange(start, start + n, dtype=float)
        return 1e-3 * (np.asarray(channels, float)[:, None] + 1) + 1e-6 * k[None, :]

    def excite(self, input_index: int, at_sample: int) -> None:
        pass


@pytest.fixture
def rig(no_leaks: None) -> Iterator[Any]:
    """``make(faults=..., identity=..., **driver_kw) -> (driver, node, clock)``; all closed."""
    closers: list[Any] = []

    def make(
        faults: Cia404Faults | None = None,
        identity: dict[Any, int] | None = None,
        hear_sync: bool = False,
        **kw: Any,
    ) -> tuple[Cia404Amplifier, Cia404NodeSim, SampleClock]:
        name = f"cia404-test-{os.getpid()}-{next(_n)}"
        clock = SampleClock()
        node = Cia404NodeSim(
            name,
            EDS,
            Ramp(),
            range(12),
            node_id=3,
            serial_number=77,
            faults=faults,
            identity=identity,
            hear_sync=hear_sync,
        )
        closers.append(node.close)
        prod = SyncProducerSim(name, clock, [node])
        closers.append(prod.close)
        ch = CanChannel(
            can.Bus(interface="virtual", channel=name),
            bitrate=1_000_000,
            max_load=2.0,
            where="test",
        )
        closers.append(ch.close)
        amp = Cia404Amplifier(
            ch, node_id=3, eds=EDS, timeout_s=2.0, heartbeat_ms=50, heartbeat_factor=60, **kw
        )
        closers.append(amp.close)
        return amp, node, clock

    yield make
    for c in reversed(closers):
        c()


def _run(amp: Cia404Amplifier, clock: SampleClock, n: int, epoch: int = 500) -> Any:
    amp.identify()
    amp.set_rate(1000)
    amp.start()
    clock.start(epoch, 1000.0)
    clock.advance(n)
    block = amp.read_until(n, timeout_s=10.0)
    clock.stop()
    return block, amp.stop()


def test_samples_are_the_sources_at_the_daq_pulses(rig: Any) -> None:
    amp, node, clock = rig()
    block, counted = _run(amp, clock, 300)
    assert counted == 300 and amp.verify_count(300) is None
    # the node sends its last moving average of its own ADC's samples (set by the driver: the
    # EDS's fastest 50 kHz, 50 samples at 1000 S/s): the ramp a known mean delay late, off by
    # at most half its own sample period about that (the held value's age)
    t = amp.timing
    assert t is not None and t.rate_hz == 50000 and t.average_n == 50
    late = t.mean_delay_s * Ramp.sample_rate_hz  # DAQ samples: (49 / 2 + 1 / 2) / 50
    assert late == pytest.approx(0.5)
    want = Ramp().read(np.arange(12), 500, 300) - 1e-6 * late
    assert block.valid.all() and block.first_sample == 0
    half_age = 1e-6 * Ramp.sample_rate_hz * t.period_s / 2
    np.testing.assert_allclose(block.gauges_v, want, rtol=0, atol=half_age + 2e-9)
    for _ in range(100):  # NMT is unconfirmed: the node handles stop()'s command in its time
        if node.state == "PRE-OPERATIONAL":
            break
        time.sleep(0.01)
    assert node.state == "PRE-OPERATIONAL"
    assert amp.verify_count(301) is not None  # one SYNC short: drift


def test_int16_process_values_scaled_by_their_decimal_digits(rig: Any) -> None:
    amp, _node, clock = rig(process_value="0x7130")
    assert "0x7130" in amp.identify().firmware
    block, _ = _run(amp, clock, 50)
    want = Ramp().read(np.arange(12), 500, 50) - 0.5e-6  # its mean delay, half a sample
    np.testing.assert_allclose(block.gauges_v, want, atol=0.5e-4 + 1e-8)  # 4 decimal digits
    assert np.all(np.abs(block.gauges_v * 1e4 - np.round(block.gauges_v * 1e4)) < 1e-6)


def test_an_emcy_rejects_the_samples_around_it(rig: Any) -> None:
    amp, _node, clock = rig(faults=Cia404Faults(emcy_at={120: 0x5000}))
    block, _ = _run(amp, clock, 300)
    (ev,) = [e for e in block.events if e.kind == "device_error"]
    assert "EMCY 0x5000" in ev.message and ev.first_sample == 120
    assert not block.valid[120:122].any() and block.valid[:120].all() and block.valid[122:].all()


def test_a_node_leaving_operational_is_a_device_error(rig: Any) -> None:
    amp, _node, clock = rig(faults=Cia404Faults(nmt_at={100: 0x80}))
    amp.identify()
    amp.set_rate(1000)
    amp.start()
    clock.start(0, 1000.0)
    clock.advance(200)
    # the first 100 samples come whatever the machine's load (a generous wait on state) ...
    first = amp.read_until(100, timeout_s=60.0)
    with pytest.raises(Exception, match="sample 199 not received"):
        amp.read_until(200, timeout_s=1.0)  # ... then the node sends nothing after SYNC 100
    clock.stop()
    amp.stop()
    rest = amp.read_until(200, timeout_s=1.0)
    msgs = [e.message for b in (first, rest) for e in b.events if e.kind == "device_error"]
    assert any("NMT state PRE-OPERATIONAL (was OPERATIONAL)" in m for m in msgs), msgs
    assert first.first_sample == 0 and first.n_samples == 100 and first.valid.all()
    assert rest.first_sample == 100 and rest.n_samples == 100 and not rest.valid.any()


def test_another_device_on_that_node_id_is_named_in_one_line(rig: Any) -> None:
    amp, _node, _clock = rig(identity={(0x1018, 2): 0x1234})
    with pytest.raises(SetupError) as err:
        amp.identify()
    msg = str(err.value)
    assert "\n" not in msg and "product 0x00001234" in msg and "loadcell_cia404_eds" in msg


def test_host_sync_is_refused_for_an_acquisition(rig: Any) -> None:
    amp, _node, _clock = rig(sync="host")
    amp.identify()
    amp.set_rate(1000)
    with pytest.raises(SetupError, match=r"cannot be aligned .* loadcell_cia404_sync = 'daq'"):
        amp.start(external_clock=True)


def test_the_bus_load_is_summed_over_the_channels_nodes() -> None:
    ch = CanChannel(
        can.Bus(interface="virtual", channel=f"cia404-load-{os.getpid()}"),
        bitrate=1_000_000,
        max_load=0.7,
        where="channel x",
    )
    try:
        ch.register(1, (8, 8, 8, 8, 8, 8))  # 12 REAL32
        assert ch.check_load(800) == pytest.approx(865 * 800 / 1e6)
        ch.register(2, (8, 8, 8))  # 12 INTEGER16
        with pytest.raises(SetupError) as err:
            ch.check_load(800)  # (55 + 9 x 135) x 800 = 1.016 Mbit/s
        msg = str(err.value)
        assert "\n" not in msg and "2 node(s), 9 TPDO frames + SYNC = 1270 bits" in msg
        assert "102 % of 1000000 bit/s" in msg and "<= 551 S/s" in msg
        with pytest.raises(SetupError, match="two load cells on CANopen node 2"):
            ch.register(2, (8,))
    finally:
        ch.close()


@pytest.mark.slow
def test_host_sync_readings_on_the_nodes_own_time(rig: Any) -> None:
    """``external_clock=False``: the driver's periodic SYNC (``canopen``'s producer), which the
    node answers at once; samples start with the lowest TPDO (the host hears not its own SYNC)."""
    amp, _node, _clock = rig(sync="host", hear_sync=True)
    amp.identify()
    amp.set_rate(200)
    amp.start(external_clock=False)
    block = amp.read_until(40, timeout_s=10.0)
    counted = amp.stop()
    assert counted >= 40 and block.valid.all()
    # the node's own ADC at the EDS's 10 kHz, no filter: the ramp held up to 0.1 sample late
    want = Ramp().read(np.arange(12), 0, 40)
    lag = want - block.gauges_v
    assert np.all(lag >= -2e-9) and np.all(lag <= 1e-6 * 0.1 + 2e-9)


@pytest.mark.parametrize(
    ("identity", "match"),
    [
        ({(0x6131, 1): 0x00260000}, r"input 1 gives its process value in unit code 0x00260000 \(V"),
        ({(0x6110, 2): 0x0005}, r"input 2 sensor type 0x0005 \(0x6110\)"),
        ({(0x6126, 3): 2.0}, r"input 3 scaling factor 2 \(0x6126\)"),
        ({(0x6127, 4): 0.5}, r"input 4 scaling offset 0.5 \(0x6127\)"),
    ],
)
def test_unit_sensor_type_and_scaling_are_checked(rig: Any, identity: Any, match: str) -> None:
    """The calibration is in mV/V through the EDS's sensor type and scaling: an input in V, of
    another sensor type or rescaled is refused in one line."""
    amp, _node, _clock = rig(identity=identity, gauge_unit="mV/V")
    with pytest.raises(SetupError, match=match) as err:
        amp.identify()
    assert "\n" not in str(err.value)


def test_the_nodes_own_filter_as_its_dictionary_says(no_leaks: None) -> None:
    """Raw SDO writes (CiA 301 bytes, not the codec): ADC 0x6114:1 = 1000 Hz (the world's
    rate), filter type 0x61A0:1 = 1 (moving average), constant 0x61A1:1 = 4. At each SYNC the
    node sends the mean of its last four own samples of the ramp: 1.5 samples older than its
    last one, which is 0..1 sample old."""
    name = f"cia404-filter-{os.getpid()}-{next(_n)}"
    node = Cia404NodeSim(name, EDS, Ramp(), range(12), node_id=6, hear_sync=True)
    bus = can.Bus(interface="virtual", channel=name)
    try:

        def sdo(data: str) -> bytes:
            bus.send(
                can.Message(arbitration_id=0x606, data=bytes.fromhex(data), is_extended_id=False)
            )
            end = time.monotonic() + 2.0
            while time.monotonic() < end:
                m = bus.recv(0.05)
                if m is not None and m.arbitration_id == 0x586:
                    return bytes(m.data)
            raise AssertionError("no SDO answer")

        for data in (
            "23146101e8030000",  # 0x6114:1 = 1000
            "2fa0610101000000",  # 0x61A0:1 = 1
            "2fa1610104000000",  # 0x61A1:1 = 4
            "2300180186010080",  # TPDO1 disabled (COB-ID 0x186 | bit 31)
            "2f001a0000000000",  # mapping count 0
            "23001a0120013061",  # entry 0x6130:1 REAL32
            "2f001a0001000000",  # count 1
            "2f00180201000000",  # synchronous
            "2300180186010000",  # enabled at 0x186 (node 6)
        ):
            assert sdo(data)[0] == 0x60, data
        bus.send(can.Message(arbitration_id=0x000, data=b"\x01\x06", is_extended_id=False))
        time.sleep(0.2)
        got = []
        for _ in range(20):
            bus.send(can.Message(arbitration_id=0x080, data=b"", is_extended_id=False))
            end = time.monotonic() + 2.0
            while time.monotonic() < end:
                m = bus.recv(0.05)
                if m is not None and m.arbitration_id == 0x186:
                    got.append(struct.unpack("<f", bytes(m.data[:4]))[0])
                    break
    finally:
        bus.shutdown()
        node.close()
    assert len(got) == 20
    x = np.arange(20, dtype=float)  # its own world position at each SYNC heard
    lag = ((1e-3 + 1e-6 * x - np.asarray(got)) / 1e-6)[5:]  # samples, after the first filled
    assert np.all(lag >= 1.5 - 0.01) and np.all(lag < 2.5 + 0.01), lag
