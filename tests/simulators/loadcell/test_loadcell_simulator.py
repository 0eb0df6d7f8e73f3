"""The load cell amplifier simulator with the real driver, counting the DAQ simulator's clock."""

from __future__ import annotations

import can
import numpy as np
import pytest
from _acq_support import ImpulseSource

from dimacq.drivers.daq.driver import DaqDevice, DaqTask
from dimacq.drivers.loadcell.driver import LoadCellAmplifier
from dimacq.simulators.daq.backend import DaqInput, VirtualDaqBackend
from dimacq.simulators.daq.clock import SampleClock
from dimacq.simulators.loadcell.amplifier import LoadCellAmplifierSim, LoadCellFaults

LSB_V = 10 / 2**23


@pytest.fixture
def rig(request, no_leaks):
    """DAQ simulator + load cell simulator on one source and one clock; closed afterwards."""
    made = []

    def build(faults=None, **kw):
        src = ImpulseSource(n_gauges=12, background=0.3)
        clock = SampleClock()
        g0 = src.n_inputs + src.n_responses
        sim = LoadCellAmplifierSim(
            f"rig-{request.node.name}", src, range(g0, g0 + 12), clock=clock, faults=faults, **kw
        )
        bus = can.Bus(interface="virtual", channel=f"rig-{request.node.name}", fd=True)
        backend = VirtualDaqBackend(src, {0: DaqInput(1, 0.01)}, clock=clock)
        dev = DaqDevice.open(backend=backend)
        task = DaqTask(dev)
        task.add_accel_channel(0, "100+Z", 100.0)
        task.configure_timing(src.sample_rate_hz, 128)
        amp = LoadCellAmplifier(bus, timeout_s=2.0)
        made.append((sim, bus, dev))
        return src, backend, task, amp, sim

    yield build
    for sim, bus, dev in made:
        dev.close()
        bus.shutdown()
        sim.close()


def test_missed_sync_pulses_are_reported_as_drift(rig):
    src, _backend, task, amp, _sim = rig(faults=LoadCellFaults(missed_pulses={600: 2}))
    amp.set_rate(int(src.sample_rate_hz))
    amp.start()
    task.start()
    task.read(1536)
    lc = amp.read_until(1000)
    task.stop()
    pulses = amp.stop()
    kinds = [e.kind for e in amp.events]
    assert "drift" in kinds, amp.events
    assert pulses == 1534
    ev = amp.verify_count(1536)
    assert ev is not None and "-2" in ev.message
    # the samples after the miss are labelled 2 samples early: visibly misaligned
    truth = src.read(np.arange(4, 16), 0, 1002)
    assert np.allclose(lc.gauges_v[:, 700], truth[:, 702], atol=LSB_V)


def test_simulator_answers_the_reference_bytes(rig):
    """Raw frames to the simulator: its answers are the protocol's documented bytes."""
    _src, _backend, _task, amp, _sim = rig()
    exchanges = [
        ("01", "81 0c 01 00 f5 01 00 00"),  # IDENTIFY: 12 gauges, firmware 1.0, serial 501
        ("04 00 00 00 00", "ff 04 02"),  # SET_RATE 0 Hz: bad argument
        ("02 07", "ff 02 02"),  # START with clock 7: bad argument
        ("0c", "ff 0c 01"),  # not a command: unknown
        ("0b", "8b 00 02 00 00 00 00 00"),  # GET_STATUS: idle, flags bit1 SYNC missing, counter 0
    ]
    for sent, answered in exchanges:
        amp.bus.send(
            can.Message(arbitration_id=0x601, data=bytes.fromhex(sent), is_extended_id=False)
        )
        reply = amp.bus.recv(2.0)
        assert reply is not None and reply.arbitration_id == 0x581
        assert bytes(reply.data) == bytes.fromhex(answered), sent


def run_for(src, task, amp, n, chunk=4096, missed=0):
    amp.set_rate(int(src.sample_rate_hz))
    amp.start()
    task.start()
    for end in range(chunk, n + 1, chunk):
        task.read(chunk)
        amp.read_until(end - missed)  # the counter lags the pulses it missed
    task.stop()
    return amp.stop()


@pytest.mark.parametrize("ppm", [50.0, -45.0])
def test_crystal_mismatch_within_tolerance_is_no_drift(rig, ppm):
    """20 s at 2048 Hz with the amplifier's oscillator ±50 ppm off the DAQ's clock: 2 samples
    of heartbeat-time mismatch, which the old absolute 1.5-sample check took for drift; the
    mismatch is estimated from the heartbeats (within 2 ppm) and no event is raised."""
    src, _backend, task, amp, _sim = rig(oscillator_ppm=ppm)
    n = 20 * 2048
    assert run_for(src, task, amp, n) == n
    assert not amp.events, amp.events
    assert amp.verify_count(n) is None
    # heartbeat time runs (1 + ppm) slow: the SYNC pulses look -ppm fast against it
    assert amp.clock_mismatch_ppm == pytest.approx(-ppm, abs=2.0)


def test_clock_beyond_tolerance_is_drift(rig):
    src, _backend, task, amp, _sim = rig(oscillator_ppm=400.0)
    run_for(src, task, amp, 3 * 4096)
    (ev,) = amp.events
    assert ev.kind == "drift" and "-400 ppm" in ev.message and "100" in ev.message


def test_missed_pulses_under_a_corrected_mismatch_are_drift(rig):
    """45 ppm off (estimated and corrected) and 2 SYNC pulses missed: the one step."""
    src, _backend, task, amp, _sim = rig(
        oscillator_ppm=45.0, faults=LoadCellFaults(missed_pulses={5000: 2})
    )
    run_for(src, task, amp, 3 * 4096, missed=2)
    (ev,) = amp.events
    assert ev.kind == "drift" and "-2.0 samples" in ev.message
