"""The USB DAQ simulator through pyusb and the real driver (they meet only at the wire)."""

from __future__ import annotations

import time

import numpy as np
import pytest
import usb.core
from _acq_support import ImpulseSource

from dimacq.drivers.daq import protocol as p
from dimacq.drivers.daq.driver import DaqDevice, DaqTask
from dimacq.errors import DeviceNotFoundError, DeviceStateError, DeviceTimeoutError
from dimacq.pipeline.frf_estimation import estimate_frf
from dimacq.simulators.daq.backend import DaqFaults, DaqInput, VirtualDaqBackend

FORCE_MV_PER_N = 2.25
ACCEL_MV_PER_G = 100.0
G = 9.80665


def make(source, faults=None, force_range=5.0):
    wiring = {0: DaqInput(0, FORCE_MV_PER_N * 1e-3)}
    for k in range(source.n_responses):
        wiring[1 + k] = DaqInput(source.n_inputs + k, ACCEL_MV_PER_G * 1e-3 / G)
    backend = VirtualDaqBackend(source, wiring, faults=faults)
    dev = DaqDevice.open(backend=backend)
    task = DaqTask(dev)
    task.add_force_channel(0, "10+X force", FORCE_MV_PER_N, range_v=force_range)
    for k in range(source.n_responses):
        task.add_accel_channel(1 + k, f"{100 + k}+Z", ACCEL_MV_PER_G, range_v=5.0)
    task.configure_timing(source.sample_rate_hz, samples_per_frame=128)
    return backend, dev, task


def _started_force_task(task: DaqTask, src: ImpulseSource) -> DaqTask:
    """``task`` with the hammer's force on channel 0, 128-sample frames at the source's rate,
    started."""
    task.add_force_channel(0, "10+X force", FORCE_MV_PER_N)
    task.configure_timing(src.sample_rate_hz, samples_per_frame=128)
    task.start()
    return task


def test_find_and_identify():
    backend = VirtualDaqBackend(ImpulseSource(), {})
    raw = usb.core.find(idVendor=p.VENDOR_ID, idProduct=p.PRODUCT_ID, backend=backend)
    assert raw is not None
    with DaqDevice.open(backend=backend) as dev:
        ident = dev.identify()
        assert ident.n_channels == 64 and ident.adc_bits == 24
        assert ident.serial_number == "SIMDAQ-0001"
        assert not dev.get_status().running
    assert backend.open_handles == 0


def test_not_found_names_the_device():
    class Empty(VirtualDaqBackend):
        def enumerate_devices(self):
            return iter(())

    with pytest.raises(DeviceNotFoundError, match="1209:DA64"):
        DaqDevice.open(backend=Empty(ImpulseSource(), {}))


def test_samples_arrive_in_engineering_units():
    src = ImpulseSource(background=0.5)
    src.excite(0, 40)
    _backend, dev, task = make(src)
    with dev:
        task.start()
        block = task.read(1000)
        task.stop()
    assert block.first_sample == 0 and block.data.shape == (4, 1000)
    truth = src.read(np.arange(4), 0, 1000)
    # 24-bit quantisation on the 5 V range in each channel's unit
    lsb = np.array([5 / 2**23 / (FORCE_MV_PER_N * 1e-3)] + [5 / 2**23 / (0.1 / G)] * 3)
    assert np.all(np.abs(block.data - truth) <= 0.51 * lsb[:, None])
    assert block.units == ("N", "m/s^2", "m/s^2", "m/s^2")
    assert block.valid.all() and not block.overload.any() and not block.events


def test_frf_through_the_simulated_daq_matches_closed_form():
    src = ImpulseSource(n_responses=3)
    n = 2048
    for a in range(3):
        src.excite(0, a * n + 10)
    _backend, dev, task = make(src)
    with dev:
        task.start()
        recs = [task.read(n) for _ in range(3)]
        task.stop()
    force = np.stack([r.data[:1] for r in recs])
    resp = np.stack([r.data[1:] for r in recs])
    est = estimate_frf(force, resp, src.sample_rate_hz)
    h_true = src.frf(est.frequencies_hz)[:, :, :1]
    rel = np.abs(est.H - h_true) / np.abs(h_true).max()
    assert rel.max() < 1e-4
    assert est.coherence.min() > 0.9999


def test_iepe_off_reads_zero_and_unsupported_rate_is_refused():
    src = ImpulseSource(background=1.0)
    _backend, dev, task = make(src)
    with dev:
        dev.set_iepe(1, 0)  # the task will switch it on again at start
        task._channels[1] = task._channels[1].__class__(
            **{**task._channels[1].__dict__, "iepe_current_ua": 0}
        )
        task.start()
        block = task.read(256)
        task.stop()
        assert np.all(block.data[1] == 0) and np.any(block.data[2] != 0)
        with pytest.raises(DeviceStateError, match="SET_SAMPLE_RATE"):
            dev.set_sample_rate(1000)


def test_overload_is_flagged_on_the_clipping_channel_only():
    src = ImpulseSource(
        amplitude_n=1000.0, response_gain=0.001
    )  # 1000 N x 2.25 mV/N = 2.25 V > 1 V range
    src.excite(0, 300)
    _backend, dev, task = make(src, force_range=1.0)
    with dev:
        task.start()
        block = task.read(512)
        task.stop()
    ev = [e for e in block.events if e.kind == "overload"]
    assert len(ev) == 1 and ev[0].channels == ("10+X force",)
    assert ev[0].first_sample <= 300 < ev[0].first_sample + ev[0].n_samples
    assert block.overload[0, 300] and not block.overload[1:].any()
    assert np.isclose(block.data[0, 300], 1.0 / 2.25e-3, rtol=1e-6)  # clipped at full scale


def test_timeout_is_reported_and_no_sample_is_lost():
    src = ImpulseSource(background=1.0)
    _backend, dev, task = make(src, faults=DaqFaults(timeout_reads={2}))
    with dev:
        task.start()
        with pytest.raises(DeviceTimeoutError, match="256 samples received and kept"):
            task.read(512)
        block = task.read(512)
        task.stop()
    assert block.first_sample == 0 and block.valid.all()
    truth = src.read(np.array([1]), 0, 512)[0]
    np.testing.assert_allclose(block.data[1], truth, atol=1e-3)
    assert [e.kind for e in task.events] == ["timeout"]


def test_fifo_overflow_and_lost_transfer_leave_aligned_gaps():
    src = ImpulseSource(background=1.0)
    faults = DaqFaults(fifo_overflow_frames={1}, lost_transfers={3})
    _backend, dev, task = make(src, faults=faults)
    with dev:
        task.start()
        block = task.read(128 * 6)
        status = dev.get_status()
        task.stop()
    kinds = [(e.kind, e.first_sample, e.n_samples) for e in block.events]
    # frame 1 (samples 128..255) lost in the FIFO; transfer of sequence 3 lost on the way:
    # sequence 3 is the 4th delivered frame, samples 512..639 (frame 1 took no sequence).
    assert kinds == [("overflow", 128, 128), ("lost_transfer", 512, 128)]
    assert np.all(np.isnan(block.data[:, 128:256])) and not block.valid[128:256].any()
    assert np.all(np.isnan(block.data[:, 512:640]))
    ok = block.valid
    truth = src.read(np.array([1]), 0, 128 * 6)[0]
    np.testing.assert_allclose(block.data[1, ok], truth[ok], atol=1e-3)
    assert status.overflowed and status.frames_lost == 1


def test_clock_counts_samples_and_runs_continue_the_world():
    src = ImpulseSource(background=1.0)
    backend, dev, task = make(src)
    with dev:
        task.start()
        task.read(300)
        st = backend.clock.state()
        assert st.running and st.count == 384 and st.epoch == 0  # 3 frames of 128
        task.stop()
        assert not backend.clock.state().running
        task.start()
        block = task.read(128)
        task.stop()
    assert backend.clock.state().epoch == 384
    truth = src.read(np.array([1]), 384, 128)[0]
    np.testing.assert_allclose(block.data[1], truth, atol=1e-3)


def test_stale_frames_of_a_previous_run_are_drained_by_start():
    """The DAQ keeps the frames clocked after the host's last read (FIFO) across STOP and
    START; the driver drains them, so the new run starts clean at sample 0 with no event."""
    src = ImpulseSource(background=1.0)
    faults = DaqFaults(frames_clocked_before_stop=3, stale_frames_survive_start=True)
    backend, dev, task = make(src, faults)
    with dev:
        task.start()
        task.read(256)
        task.stop()
        assert task.samples_clocked == 256 + 3 * 128  # GET_STATUS: clocked, not received
        assert backend.clock.state().count == 640
        task.start()
        block = task.read(256)
        task.stop()
    assert block.first_sample == 0 and block.valid.all() and not task.events
    assert backend.clock.state().epoch == 640
    truth = src.read(np.array([1]), 640, 256)[0]
    np.testing.assert_allclose(block.data[1], truth, atol=1e-3)


def test_free_running_clock_runs_in_wall_time_without_reads():
    src = ImpulseSource(background=1.0)  # 2048 S/s
    wiring = {0: DaqInput(0, FORCE_MV_PER_N * 1e-3)}
    backend = VirtualDaqBackend(src, wiring, free_running=True)
    with DaqDevice.open(backend=backend) as dev:
        task = _started_force_task(DaqTask(dev), src)
        first = task.read(128)
        time.sleep(0.25)  # the host reads nothing, the DAQ keeps clocking (~512 samples)
        status = dev.get_status()
        assert status.samples_clocked >= 128 + 0.25 * 2048
        later = task.read(256)  # already in the FIFO: no wait, no gap
        task.stop()
    assert first.first_sample == 0 and later.first_sample == 128 and later.valid.all()
    assert task.samples_clocked is not None and task.samples_clocked >= status.samples_clocked
    truth = src.read(np.array([0]), 0, 384)[0]
    got = np.concatenate([first.data[0], later.data[0]])
    np.testing.assert_allclose(got, truth, atol=5 / 2**23 / (FORCE_MV_PER_N * 1e-3))


@pytest.mark.parametrize("scale", [1.0, 40.0])
def test_a_bulk_read_waits_for_its_frame_at_the_clocks_pace(monkeypatch, scale):
    """A bulk read returns once its frame is clocked: at a time-lapse the frame takes its
    samples' duration over the factor, so the simulator never sleeps longer than that (it slept
    the real-time duration at any factor: the host read 40× late at 40×, and every strike
    waited behind that backlog). The sleeps asked for are recorded; no wall time is asserted."""
    from dimacq.simulators.daq import backend as daq_backend

    asked: list[float] = []
    real_sleep = time.sleep

    def sleep(s: float) -> None:
        asked.append(s)
        real_sleep(s)

    monkeypatch.setattr(daq_backend.time, "sleep", sleep)
    src = ImpulseSource(background=1.0)  # 2048 S/s
    wiring = {0: DaqInput(0, FORCE_MV_PER_N * 1e-3)}
    backend = VirtualDaqBackend(src, wiring, free_running=True, time_scale=scale)
    with DaqDevice.open(backend=backend) as dev:
        task = _started_force_task(DaqTask(dev), src)
        block = task.read(512)
        task.stop()
    assert block.valid.all() and block.first_sample == 0
    frame_s = 128 / (src.sample_rate_hz * scale)  # one frame at the clock's pace
    assert asked and max(asked) <= frame_s * (1 + 1e-9)


def test_a_late_host_overflows_the_bounded_fifo_and_the_gap_is_reported():
    """A real DAQ's FIFO is bounded: while the host does not read, the clock runs on, and the
    samples clocked once the FIFO is full are lost. The driver sees the overflow flag and the
    sample counter jump and reports exactly those samples as lost (NaN, not valid)."""
    src = ImpulseSource(background=1.0)  # 2048 S/s
    wiring = {0: DaqInput(0, FORCE_MV_PER_N * 1e-3)}
    fifo = 16 * p.frame_size(128, 1)  # 16 frames of 128 samples: 1 s at 2048 S/s
    backend = VirtualDaqBackend(src, wiring, free_running=True, fifo_bytes=fifo)
    with DaqDevice.open(backend=backend) as dev:
        task = _started_force_task(DaqTask(dev), src)
        task.read(128)
        # the host is late: it reads nothing until the DAQ has clocked 4 frames beyond a full
        # FIFO (a deadline on that progress, not a fixed sleep: load only makes the gap longer)
        deadline = time.monotonic() + 30
        while dev.get_status().samples_clocked < 128 + 20 * 128:
            assert time.monotonic() < deadline, "the free-running clock did not run"
            time.sleep(0.05)
        block = task.read(16 * 128 + 1024)
        task.stop()
        status = dev.get_status()
    (ev,) = [e for e in block.events if e.kind == "overflow"]
    assert ev.first_sample == 128 + 16 * 128  # the FIFO held 16 frames after the last read
    assert ev.n_samples >= 512 and not block.valid[ev.first_sample - 128 :][: ev.n_samples].any()
    assert block.valid[: ev.first_sample - 128].all()
    assert status.frames_lost == ev.n_samples // 128 and status.overflowed
    assert backend.injected["fifo_overflow"] == 1


def test_re_enumeration_kills_the_handle_and_the_task_finds_the_daq_again():
    """The DAQ drops off the bus (a reset) and comes back at a new address: every transfer on
    the old handle fails with ENODEV (DeviceLostError); reconnect() finds it again by serial
    number and the task starts on it as configured."""
    from dimacq.errors import DeviceLostError

    src = ImpulseSource(background=1.0)
    wiring = {0: DaqInput(0, FORCE_MV_PER_N * 1e-3)}
    faults = DaqFaults(reenumerate_rate=1.0, reenumerate_s=0.2)
    backend = VirtualDaqBackend(src, wiring, free_running=True, time_scale=4.0, faults=faults)

    def reopen() -> DaqDevice:
        return DaqDevice.open(backend=backend, serial_number="SIMDAQ-0001")

    task = _started_force_task(DaqTask(DaqDevice.open(backend=backend), reopen=reopen), src)
    old = task.device.name
    with pytest.raises(DeviceLostError, match="dropped off the USB bus"):
        task.read(128)
    with pytest.raises(DeviceLostError):  # the old handle stays dead
        task.device.get_status()
    faults.reenumerate_rate = 0.0
    task.reconnect(timeout_s=5.0)
    assert task.reconnects == 1 and task.device.name != old and not task.running
    task.start()
    block = task.read(256)
    task.stop()
    task.device.close()
    assert block.first_sample == 0 and block.valid.all()
    assert backend.injected == {"usb_reenumeration": 1}
