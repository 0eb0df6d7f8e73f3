"""The USB-1808X simulator behind the real driver: several units in step on one master clock,
the EEPROM calibration, the FPGA load, a loose clock cable, a FIFO overrun, and the driver's
host buffer (a pause longer than the FIFO holds; the host buffer's own overflow)."""

from __future__ import annotations

import errno
import threading
import time

import numpy as np
import pytest
import usb.core

from dimacq.drivers.mcc import protocol as p
from dimacq.drivers.mcc.driver import MccTask, Usb1808
from dimacq.errors import DeviceLostError, DeviceStateError, ProtocolError, SetupError
from dimacq.simulators.daq.backend import DaqInput
from dimacq.simulators.mcc.backend import Mcc1808Backend, lab_fpga_image

RATE = 2000.0


class Sines:
    """Two test signals, V: a 50 Hz sine of 3 V and a 120 Hz sine of 1.5 V."""

    sample_rate_hz = RATE
    channel_names = ("s50", "s120")
    channel_units = ("V", "V")

    def read(self, channels: np.ndarray, start: int, n: int) -> np.ndarray:
        t = (start + np.arange(n)) / RATE
        table = {0: 3.0 * np.sin(2 * np.pi * 50 * t), 1: 1.5 * np.sin(2 * np.pi * 120 * t + 0.3)}
        return np.stack([table[int(c)] for c in channels])

    def excite(self, input_index: int, at_sample: int) -> None:
        return None


def _units(backend: Mcc1808Backend) -> list[Usb1808]:
    found = usb.core.find(find_all=True, idVendor=p.VENDOR_ID, idProduct=0x013E, backend=backend)
    units = [Usb1808(d, timeout_s=1.0) for d in found]
    for u in units:
        u.configure_fpga(lab_fpga_image())
    return units


def _task(units: list[Usb1808]) -> MccTask:
    task = MccTask(units)
    task.add_voltage_channel(0, "u0 ai0")
    task.add_voltage_channel(21, "u2 ai5", range_v=5.0)
    task.add_voltage_channel(12, "u1 ai4", range_v=5.0)
    task.configure_timing(RATE, samples_per_frame=200)
    return task


def test_three_units_scan_in_step_and_are_calibrated() -> None:
    wiring = {0: DaqInput(0, 1.0), 21: DaqInput(0, 1.0), 12: DaqInput(1, 1.0)}
    backend = Mcc1808Backend(Sines(), wiring, n_units=3, time_scale=40.0, seed=3)
    units = _units(backend)
    task = _task(units)
    task.start()
    block = task.read(1500, timeout_s=2.0)
    task.stop()
    t = np.arange(1500) / RATE
    truth = np.stack(
        [
            3 * np.sin(2 * np.pi * 50 * t),
            3 * np.sin(2 * np.pi * 50 * t),
            1.5 * np.sin(2 * np.pi * 120 * t + 0.3),
        ]
    )  # channels in physical order: 0, 12, 21
    truth = truth[[0, 2, 1]]
    lsb = np.array([10.0, 5.0, 5.0]) / 131072
    err = np.abs(block.data - truth).max(axis=1)
    assert np.all(err < 1.01 * lsb)  # within one code after the EEPROM correction
    # the same signal on unit 0 and unit 2: the same instants (no skew of a whole scan)
    assert np.abs(block.data[0] - block.data[2]).max() < 2.1 * lsb[0]
    assert task.samples_clocked is not None and task.samples_clocked >= 1500
    assert block.valid.all() and not block.events
    # the test has power: read without the EEPROM tables, the same units are off by their
    # ADCs' gain and offset errors (sine fit: amplitude and DC, whatever the run's start)
    ident = [(np.ones((8, 4)), np.zeros((8, 4)))] * 3
    bare = MccTask(units, calibrations=ident)
    bare.add_voltage_channel(0, "u0 ai0")
    bare.configure_timing(RATE, samples_per_frame=200)
    bare.start()
    raw = bare.read(1600, timeout_s=2.0)
    bare.stop()
    amp, dc = _fit(raw.data[0], np.arange(1600) / RATE)
    assert max(abs(amp - 3.0), abs(dc)) > 5 * lsb[0]
    amp, dc = _fit(block.data[0, :1400], t[:1400])  # calibrated: within a code
    assert max(abs(amp - 3.0), abs(dc)) < lsb[0]


def _fit(x: np.ndarray, t: np.ndarray) -> tuple[float, float]:
    """Amplitude and DC of a 50 Hz sine in ``x`` (least squares over whole periods)."""
    a = np.stack([np.sin(2 * np.pi * 50 * t), np.cos(2 * np.pi * 50 * t), np.ones_like(t)], 1)
    c = np.linalg.lstsq(a, x, rcond=None)[0]
    return float(np.hypot(c[0], c[1])), float(c[2])


def test_a_slave_missing_clock_pulses_is_caught_at_stop() -> None:
    wiring = {0: DaqInput(0, 1.0), 21: DaqInput(0, 1.0)}
    backend = Mcc1808Backend(
        Sines(), wiring, n_units=3, time_scale=40.0, missed_pulses={"01F2A002": 3}
    )
    task = _task(_units(backend))
    task.start()
    task.read(400, timeout_s=30.0)  # a bound on the wait only: a loaded host is slow to start
    with pytest.raises(ProtocolError, match=r"master clocked (\d+) scans but .*01F2A002.*ICLKO"):
        task.stop()


class StallingSines(Sines):
    """:class:`Sines` whose first read takes 0.3 s: the host's reader thread is late once."""

    def __init__(self) -> None:
        self.stalled = threading.Event()

    def read(self, channels: np.ndarray, start: int, n: int) -> np.ndarray:
        if not self.stalled.is_set():
            self.stalled.set()
            time.sleep(0.3)
        return super().read(channels, start, n)


def test_fifo_overrun_is_reported() -> None:
    """The reader thread is 0.3 s late once: 120 000 scans clocked, the FIFO holds 341."""
    backend = Mcc1808Backend(
        StallingSines(), {0: DaqInput(0, 1.0)}, n_units=3, time_scale=200.0, fifo_bytes=4096
    )
    task = _task(_units(backend))
    task.start()
    with pytest.raises(DeviceStateError, match="FIFO overrun") as err:
        for _ in range(50):
            task.read(200, timeout_s=2.0)
    assert "host buffer" not in str(err.value)
    assert any(e.kind == "overflow" for e in task.events)
    with pytest.raises(ProtocolError, match=r"FIFO overrun on .*read faster"):
        task.stop()


def _one_unit_task(backend: Mcc1808Backend, n_inputs: int, **kw: float) -> MccTask:
    task = MccTask(_units(backend), **kw)
    for k in range(n_inputs):
        task.add_voltage_channel(k, f"ai{k}")
    task.configure_timing(RATE, samples_per_frame=200)
    return task


@pytest.mark.slow
def test_a_pause_longer_than_the_fifo_loses_no_sample() -> None:
    """The device's 32 KiB FIFO holds 8192 samples: 2048 scans of four inputs, 1.02 s at
    2 kHz. The program pauses 2 s (at 1× time) between reads; the reader thread keeps every
    scan, so the samples after the pause are the 50 Hz sine at their own counters."""
    wiring = {k: DaqInput(0, 1.0) for k in range(4)}
    backend = Mcc1808Backend(Sines(), wiring, n_units=1, time_scale=1.0, seed=7)
    task = _one_unit_task(backend, 4)
    task.start()
    try:
        before = task.read(400, timeout_s=2.0)
        time.sleep(2.0)  # 4000 scans clocked: twice what the FIFO holds
        after = task.read(4000, timeout_s=2.0)
    finally:
        task.stop()
    assert backend.units[0].sent >= 4400 and not backend.units[0].overrun
    assert (before.first_sample, after.first_sample) == (0, 400)
    assert after.valid.all() and not after.events and not task.events
    t = np.arange(400, 4400) / RATE
    lsb = 10.0 / 131072
    assert np.abs(after.data - 3.0 * np.sin(2 * np.pi * 50 * t)).max() < 2.1 * lsb


def test_host_buffer_overflow_names_the_host_not_the_device() -> None:
    """A 0.5 s host buffer (1000 scans) and a program that does not read for 10 s of lab time
    (1 s at 10×): the host buffer fills, the reader stops reading the unit, whose FIFO (8192
    scans, 4.1 s) then overruns. Every scan up to the overrun is read, in order; then the read
    and ``stop()`` name the host falling behind, not the device's FIFO."""
    backend = Mcc1808Backend(Sines(), {0: DaqInput(0, 1.0)}, n_units=1, time_scale=10.0)
    task = _one_unit_task(backend, 1, host_buffer_s=0.5)
    task.start()
    blocks = [task.read(200, timeout_s=2.0)]
    time.sleep(1.0)
    with pytest.raises(DeviceStateError, match=r"host fell behind: its buffer .*1000 scans") as err:
        for _ in range(100):
            blocks.append(task.read(200, timeout_s=2.0))
    assert "FIFO overrun after" not in str(err.value)  # the device's own message
    with pytest.raises(DeviceStateError, match="host fell behind"):
        task.stop()
    rest = task.read_buffered()
    blocks += [rest] if rest is not None else []
    data = np.concatenate([b.data[0] for b in blocks])
    assert backend.units[0].overrun and data.size == task.samples_clocked
    assert data.size > 8192 and all(b.valid.all() for b in blocks)
    t = np.arange(data.size) / RATE
    assert np.abs(data - 3.0 * np.sin(2 * np.pi * 50 * t)).max() < 2.1 * 10.0 / 131072
    (over,) = [e for e in task.events if e.kind == "overflow"]
    assert "host fell behind" in over.message


class UnpluggedSines(Sines):
    """:class:`Sines` whose unit drops off the bus after scan 1023 (libusb's ENODEV)."""

    def read(self, channels: np.ndarray, start: int, n: int) -> np.ndarray:
        if start + n > 1024:
            raise usb.core.USBError("No such device", error_code=-4, errno=errno.ENODEV)
        return super().read(channels, start, n)


def test_reader_thread_error_is_raised_by_the_next_read() -> None:
    """The unit drops off the bus under the reader thread: the scans before it are read, then
    the read raises the thread's error (and ``stop()`` too: the unit is gone)."""
    backend = Mcc1808Backend(UnpluggedSines(), {0: DaqInput(0, 1.0)}, n_units=1, time_scale=10.0)
    task = _one_unit_task(backend, 1)  # transfers of 256 scans: 4 arrive
    task.start()
    try:
        first = task.read(512, timeout_s=2.0)
        with pytest.raises(DeviceLostError, match="dropped off the USB bus"):
            task.read(2000, timeout_s=2.0)
    finally:
        with pytest.raises(DeviceLostError):
            task.stop()
    rest = task.read_buffered()
    assert first.valid.all() and rest is not None and rest.valid.all()
    assert (rest.first_sample, rest.data.shape[1]) == (512, 512)


def test_fpga_must_be_loaded_first() -> None:
    backend = Mcc1808Backend(Sines(), {}, n_units=1)
    (dev,) = usb.core.find(find_all=True, idVendor=p.VENDOR_ID, backend=backend)
    unit = Usb1808(dev)
    assert not unit.status() & p.Status.FPGA_CONFIGURED
    with pytest.raises(DeviceStateError, match="refused AIN_SCAN_STOP"):
        unit.scan_stop()
    with pytest.raises(SetupError, match="no Xilinx sync word"):
        unit.configure_fpga(b"\x00" * 4096)  # refused by the driver: nothing sent
    assert not unit.status() & (p.Status.FPGA_CONFIGURED | p.Status.FPGA_CONFIG_MODE)
    unit.configure_fpga(lab_fpga_image())
    assert unit.status() & p.Status.FPGA_CONFIGURED
    unit.scan_stop()


def test_clipping_is_an_overload_event() -> None:
    """3 V × 3 = ±9 V on the ±5 V range: codes at the ends of the 18-bit scale."""
    backend = Mcc1808Backend(Sines(), {3: DaqInput(0, 3.0)}, n_units=1, time_scale=40.0)
    task = MccTask(_units(backend))
    task.add_voltage_channel(3, "hot", range_v=5.0)
    task.configure_timing(RATE, samples_per_frame=200)
    task.start()
    block = task.read(400, timeout_s=2.0)
    task.stop()
    assert block.overload[0].any() and not block.overload[0].all()
    assert block.first_sample == 0  # a fresh lab: the run starts at its sample 0
    v = 9.0 * np.sin(2 * np.pi * 50 * np.arange(400) / RATE)
    assert block.overload[0][np.abs(v) > 5.05].all()
    assert not block.overload[0][np.abs(v) < 4.95].any()
    assert any(e.kind == "overload" and e.channels == ("hot",) for e in block.events)
