"""The load cell contract (:class:`dimacq.devices.loadcell.LoadCell`) over both wire kinds: the
CAN FD amplifier (``dimacq-can``) and the CANopen one (``canopen``), each driver against its
simulator on python-can's ``virtual`` bus, counting the DAQ simulator's clock."""

from __future__ import annotations

import can
import numpy as np
import pytest
from _acq_support import ImpulseSource

from dimacq.config import Settings
from dimacq.devices.loadcell import LoadCell
from dimacq.drivers.canopen_loadcell.driver import CanopenLoadCell
from dimacq.drivers.daq.driver import DaqDevice, DaqTask
from dimacq.drivers.loadcell.driver import LoadCellAmplifier
from dimacq.errors import DeviceTimeoutError
from dimacq.simulators.canopen_loadcell.amplifier import CanopenAmplifierSim, CanopenFaults
from dimacq.simulators.daq.backend import DaqInput, VirtualDaqBackend
from dimacq.simulators.daq.clock import SampleClock
from dimacq.simulators.loadcell.amplifier import LoadCellAmplifierSim, LoadCellFaults

LSB_V = 10 / 2**23
EDS = Settings().loadcell_canopen_eds_path
KINDS = ["dimacq-can", "canopen"]


def _faults(kind: str, dropped: set[int] | None = None, silent: bool = False):
    if kind == "canopen":
        return CanopenFaults(dropped_frames=dropped or set(), silent=silent)
    return LoadCellFaults(dropped_samples=dropped or set(), silent=silent)


@pytest.fixture(params=KINDS)
def rig(request, no_leaks):
    """DAQ simulator + amplifier simulator of the kind on one source and one clock."""
    kind = request.param
    made = []

    def build(faults=None):
        src = ImpulseSource(n_gauges=12, background=0.3)
        clock = SampleClock()
        g0 = src.n_inputs + src.n_responses
        name = f"contract-{kind}-{request.node.name}"
        amp: LoadCell
        if kind == "canopen":
            sim = CanopenAmplifierSim(
                name, EDS, src, range(g0, g0 + 12), clock=clock, node_id=7, faults=faults
            )
            bus = can.Bus(interface="virtual", channel=name)
            amp = CanopenLoadCell(bus, node_id=7, eds=EDS, timeout_s=2.0)
        else:
            sim = LoadCellAmplifierSim(name, src, range(g0, g0 + 12), clock=clock, faults=faults)
            bus = can.Bus(interface="virtual", channel=name, fd=True)
            amp = LoadCellAmplifier(bus, timeout_s=2.0)
        backend = VirtualDaqBackend(src, {0: DaqInput(1, 0.01)}, clock=clock)
        dev = DaqDevice.open(backend=backend)
        task = DaqTask(dev)
        task.add_accel_channel(0, "100+Z", 100.0)
        task.configure_timing(src.sample_rate_hz, 128)
        made.append((sim, bus, dev, amp))
        return src, task, amp, sim

    build.kind = kind  # type: ignore[attr-defined]
    yield build
    for sim, bus, dev, amp in made:
        dev.close()
        if isinstance(amp, CanopenLoadCell):
            amp.close()
        bus.shutdown()
        sim.close()


def test_identify_and_calibration_round_trip(rig):
    _src, _task, amp, sim = rig()
    assert isinstance(amp, LoadCell)
    ident = amp.identify()
    assert ident.n_gauges == 12 and ident.serial_number == 501
    m = np.random.default_rng(3).standard_normal((6, 12))
    amp.download_calibration(m)
    np.testing.assert_allclose(sim.matrix, m, rtol=1e-6)
    np.testing.assert_allclose(amp.upload_calibration(), m, rtol=1e-6)


def test_streams_are_aligned_by_the_daq_counter(rig):
    src, task, amp, _sim = rig()
    src.excite(0, 100)
    amp.set_rate(int(src.sample_rate_hz))
    amp.start()  # armed before the DAQ: counter 0 = DAQ sample 0
    task.start()
    daq = task.read(1024)
    lc = amp.read_until(1024)
    task.stop()
    pulses = amp.stop()
    assert pulses == 1024
    assert amp.verify_count(1024) is None
    truth = src.read(np.arange(4, 16), 0, 1024)
    np.testing.assert_allclose(lc.gauges_v, truth, atol=0.51 * LSB_V)
    assert lc.valid.all() and not lc.events and daq.first_sample == lc.first_sample == 0


def test_dropped_frames_become_a_reported_gap(rig):
    src, task, amp, _sim = rig(faults=_faults(rig.kind, dropped={300, 301, 302}))
    amp.set_rate(int(src.sample_rate_hz))
    amp.start()
    task.start()
    task.read(512)
    lc = amp.read_until(512)
    task.stop()
    amp.stop()
    assert [(e.kind, e.first_sample, e.n_samples) for e in lc.events] == [("gap", 300, 3)]
    assert np.isnan(lc.gauges_v[:, 300:303]).all() and lc.valid.sum() == 509
    truth = src.read(np.arange(4, 16), 0, 512)
    ok = lc.valid
    np.testing.assert_allclose(lc.gauges_v[:, ok], truth[:, ok], atol=0.51 * LSB_V)


def test_silent_amplifier_times_out(rig):
    _src, _task, amp, _sim = rig(faults=_faults(rig.kind, silent=True))
    amp.timeout_s = 0.1
    if isinstance(amp, CanopenLoadCell):
        amp.node.sdo.RESPONSE_TIMEOUT = 0.1
    with pytest.raises(DeviceTimeoutError):
        amp.identify()


def test_lc_armed_but_daq_not_started_times_out_with_data_kept(rig):
    src, _task, amp, _sim = rig()
    amp.set_rate(int(src.sample_rate_hz))
    amp.start()
    with pytest.raises(DeviceTimeoutError, match="DAQ clock"):
        amp.read_until(10, timeout_s=0.1)
    amp.stop()
