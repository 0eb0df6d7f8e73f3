"""The CANopen load cell: EDS, mapping and matrix read from the node, and its faults.

Driver (:class:`~dimacq.drivers.canopen_loadcell.driver.CanopenLoadCell`) and simulator (a
``canopen.LocalNode`` from the same EDS) meet on python-can's ``virtual`` bus; the simulator
counts the DAQ simulator's clock. Every fault is reported naming the node and survived (the
stream goes on), and every sample accepted as valid is the source's value.
"""

from __future__ import annotations

import time

import can
import canopen
import numpy as np
import pytest
from _acq_support import ImpulseSource

from dimacq.config import Settings
from dimacq.drivers.canopen_loadcell import protocol as p
from dimacq.drivers.canopen_loadcell.driver import CanopenLoadCell
from dimacq.drivers.daq.driver import DaqDevice, DaqTask
from dimacq.errors import DeviceStateError, ProtocolError, SetupError
from dimacq.simulators.canopen_loadcell.amplifier import CanopenAmplifierSim, CanopenFaults
from dimacq.simulators.daq.backend import DaqInput, VirtualDaqBackend
from dimacq.simulators.daq.clock import SampleClock

EDS = Settings().loadcell_canopen_eds_path
LSB_V = 10 / 2**23
NODE = 9


def test_eds_validates_with_canopens_parser() -> None:
    od = canopen.import_od(str(EDS), NODE)
    assert od[0x1000].default == 0x194  # CiA 404 measuring device
    assert od.device_information.vendor_name == "dimacq"
    assert od[p.HEARTBEAT_TIME].default == 100
    assert od[p.CALIBRATION_MATRIX].data_type == canopen.objectdictionary.DOMAIN
    assert [od[p.GAUGES][g].data_type for g in range(1, 13)] == [
        canopen.objectdictionary.INTEGER24
    ] * 12
    maps = []
    for k in range(6):
        entries, offset = [], 0
        for sub in range(1, od[0x1A00 + k][0].default + 1):
            v = od[0x1A00 + k][sub].default
            entries.append(p.MappedEntry(v >> 16, (v >> 8) & 0xFF, v & 0xFF, offset))
            offset += v & 0xFF
        maps.append((od[0x1800 + k][1].default, True, entries))
    layout = p.PdoLayout.from_mappings(maps, full_scale_v=od[p.FULL_SCALE].default, where="EDS")
    assert layout.cob_ids == (
        0x180 + NODE,
        0x280 + NODE,
        0x380 + NODE,
        0x480 + NODE,
        0x1C0 + NODE,
        0x2C0 + NODE,
    )
    assert all(t.length == 8 for t in layout.tpdos)
    # the bus load a user is warned about: 12 gauges at 2048 S/s need more than 1 Mbit/s
    assert 1.5 < p.bus_load(layout, 2048, 1_000_000) < 1.8
    assert p.bus_load(layout, 1000, 1_000_000) < 0.85


@pytest.fixture
def rig(request, no_leaks):
    made = []

    def build(faults=None, remap=None, matrix=None):
        src = ImpulseSource(n_gauges=12, background=0.3)
        clock = SampleClock()
        g0 = src.n_inputs + src.n_responses
        name = f"co-{request.node.name}"
        sim = CanopenAmplifierSim(
            name,
            EDS,
            src,
            range(g0, g0 + 12),
            clock=clock,
            node_id=NODE,
            faults=faults,
            calibration_matrix=matrix,
        )
        if remap is not None:
            remap(sim)
        bus = can.Bus(interface="virtual", channel=name)
        amp = CanopenLoadCell(bus, node_id=NODE, eds=EDS, timeout_s=2.0, heartbeat_ms=100)
        backend = VirtualDaqBackend(src, {0: DaqInput(1, 0.01)}, clock=clock)
        dev = DaqDevice.open(backend=backend)
        task = DaqTask(dev)
        task.add_accel_channel(0, "100+Z", 100.0)
        task.configure_timing(src.sample_rate_hz, 128)
        made.append((sim, bus, dev, amp))
        return src, task, amp, sim

    yield build
    for sim, bus, dev, amp in made:
        dev.close()
        amp.close()
        bus.shutdown()
        sim.close()


def _run(src, task, amp, n):
    amp.set_rate(int(src.sample_rate_hz))
    amp.start()
    task.start()
    task.read(n)
    block = amp.read_until(n)
    task.stop()
    pulses = amp.stop()
    return block, pulses


def _accepted_are_true(src, block):
    truth = src.read(np.arange(4, 16), 0, block.n_samples)
    ok = block.valid
    np.testing.assert_allclose(block.gauges_v[:, ok], truth[:, ok], atol=0.51 * LSB_V)


def test_mapping_is_read_from_the_node_not_assumed(rig) -> None:
    """The node maps gauges in another order, counter last: the driver decodes what it says."""

    def remap(sim):
        for k in range(6):
            m = sim._obj(0x1A00 + k)
            a, b = 12 - 2 * k, 11 - 2 * k  # gauges 12,11 in TPDO1 ... 2,1 in TPDO6
            m[1].raw = (p.GAUGES << 16) | (a << 8) | 24
            m[2].raw = (p.GAUGES << 16) | (b << 8) | 24
            m[3].raw = (p.COUNTER_LOW << 16) | 16
        sim.layout = sim._layout()

    src, task, amp, _sim = rig(remap=remap)
    amp.identify()
    assert amp.layout is not None
    assert amp.layout.tpdos[0].gauges == ((11, 0), (10, 3)) and amp.layout.tpdos[0].counter_at == 6
    block, pulses = _run(src, task, amp, 512)
    assert pulses == 512 and block.valid.all() and not block.events
    _accepted_are_true(src, block)


def test_a_mapping_without_every_gauge_is_refused_naming_them(rig) -> None:
    def remap(sim):
        sim._obj(0x1A05)[0].raw = 2  # TPDO6 carries the counter and gauge 11 only

    _src, _task, amp, _sim = rig(remap=remap)
    with pytest.raises(SetupError, match=r"gauges \[12\] are not mapped"):
        amp.identify()


def test_matrix_is_read_from_the_node_and_download_is_read_back(rig) -> None:
    m0 = np.random.default_rng(1).standard_normal((6, 12))
    _src, _task, amp, sim = rig(matrix=m0)
    np.testing.assert_array_equal(amp.upload_calibration(), m0.astype("<f4").astype(float))
    m1 = np.random.default_rng(2).standard_normal((6, 12))
    amp.download_calibration(m1, serial="501", date="2026-11-23")
    np.testing.assert_array_equal(amp.upload_calibration(), m1.astype("<f4").astype(float))
    assert sim._obj(p.CALIBRATION_SERIAL).raw == "501"


def test_sdo_abort_is_one_line_naming_the_object_and_survived(rig) -> None:
    src, task, amp, _sim = rig()
    amp.set_rate(int(src.sample_rate_hz))
    amp.start()
    task.start()
    with pytest.raises(DeviceStateError) as err:
        amp.download_calibration(np.eye(6, 12))
    msg = str(err.value)
    assert "\n" not in msg and f"node {NODE}" in msg
    assert "calibration matrix (0x2200:00)" in msg and "0x08000022" in msg
    task.read(256)
    block = amp.read_until(256)  # the stream went on
    task.stop()
    amp.stop()
    assert block.valid.all()
    amp.download_calibration(np.eye(6, 12))  # stopped: accepted
    np.testing.assert_array_equal(amp.upload_calibration(), np.eye(6, 12))
    with pytest.raises(ProtocolError, match=r"object \(0x2999:00\).*0x06020000"):
        amp._read(0x2999)


def test_emcy_is_a_device_error_naming_the_node_and_its_sample_rejected(rig) -> None:
    src, task, amp, _sim = rig(faults=CanopenFaults(emcy_at={200: p.EMCY_HARDWARE}))
    block, pulses = _run(src, task, amp, 512)
    errs = [e for e in block.events if e.kind == "device_error" and "EMCY" in e.message]
    assert len(errs) == 1 and errs[0].first_sample == 200
    assert f"node {NODE}" in errs[0].message and "EMCY 0x5000" in errs[0].message
    assert not block.valid[200] and block.valid.sum() == 511 and pulses == 512
    _accepted_are_true(src, block)


def test_bus_off_is_a_gap_and_an_emcy_and_the_stream_resumes(rig) -> None:
    src, task, amp, _sim = rig(faults=CanopenFaults(bus_off=(300, 100)))
    block, pulses = _run(src, task, amp, 1024)
    kinds = [(e.kind, e.first_sample, e.n_samples) for e in block.events]
    assert ("gap", 300, 100) in kinds and ("device_error", 400, 1) in kinds
    assert "bus-off" in next(e.message for e in block.events if e.first_sample == 400)
    assert block.valid.sum() == 924 and block.valid[400:].all() and pulses == 1024
    _accepted_are_true(src, block)


def test_bus_off_over_the_last_pulses_is_a_gap_not_a_timeout(rig) -> None:
    """No TPDO comes again once the SYNC stops: the driver reads the node's counter (0x2102)."""
    src, task, amp, _sim = rig(faults=CanopenFaults(bus_off=(900, 124)))
    block, pulses = _run(src, task, amp, 1024)
    assert ("gap", 900, 124) in [(e.kind, e.first_sample, e.n_samples) for e in block.events]
    assert block.valid[:900].all() and not block.valid[900:].any() and pulses == 1024
    _accepted_are_true(src, block)


def test_heartbeat_loss_is_reported_naming_the_node_and_survived(rig) -> None:
    src, task, amp, sim = rig()
    amp.identify()  # heartbeat 100 ms, lost after 3 periods
    amp.set_rate(int(src.sample_rate_hz))
    amp.start()
    task.start()
    task.read(256)
    first = amp.read_until(256)
    sim.lose_heartbeat()
    time.sleep(0.8)  # > 3 periods, with room for a loaded machine
    task.read(256)
    second = amp.read_until(512)
    task.stop()
    assert amp.stop() == 512
    lost = [e for e in second.events if e.kind == "device_error"]
    assert (
        len(lost) == 1 and f"node {NODE}" in lost[0].message and "no heartbeat" in lost[0].message
    )
    assert first.valid.all() and second.valid.all()
    truth = src.read(np.arange(4, 16), 256, 256)
    np.testing.assert_allclose(second.gauges_v, truth, atol=0.51 * LSB_V)


def test_stop_sends_the_backlog_in_bursts_before_answering_the_counter(rig) -> None:
    """NMT PRE-OPERATIONAL with 5000 pulses counted and none sent: the node sends their TPDOs
    as bursts (not a send per frame on the thread that answers SDO), all of them on the wire
    before the answer of the counter read (0x2102) that follows, as the driver expects."""
    src, _task, amp, sim = rig()
    clock = sim.clock
    tpdos = set(sim.layout.cob_ids)
    send_pulses = sim._send_pulses
    sim._send_pulses = lambda final=False: send_pulses(final) if final else 0  # only the stop
    bursts: list[int] = []
    send_frames = sim.network.bus.send_frames

    def count_bursts(frames):
        bursts.append(len(frames))
        send_frames(frames)

    sim.network.bus.send_frames = count_bursts
    single: list[int] = []
    send_message = sim.network.send_message

    def count_single(can_id, data, remote=False):
        single.append(can_id)
        send_message(can_id, data, remote)

    sim.network.send_message = count_single
    amp.set_rate(int(src.sample_rate_hz))
    amp.start()
    clock.start(0, src.sample_rate_hz)
    clock.advance(5000)
    clock.stop()
    wire = can.Bus(interface="virtual", channel=sim.network.bus.channel_id)  # listens from here
    try:
        assert amp.stop() == 5000
        order = []
        while (m := wire.recv(timeout=0)) is not None:
            order.append(m.arbitration_id)
    finally:
        wire.shutdown()
    answer = order.index(0x580 + NODE)  # the counter read's answer
    assert sum(a in tpdos for a in order[:answer]) == 6 * 5000
    assert not any(a in tpdos for a in order[answer:])
    assert not any(a in tpdos for a in single) and sum(bursts) == 6 * 5000
    assert len(bursts) == -(-5000 // 128)
    block = amp.read_until(5000)
    assert block.valid.all()
    _accepted_are_true(src, block)
