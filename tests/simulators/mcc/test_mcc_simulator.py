"""The USB-1808X simulator behind the real driver: several units in step on one master clock,
the EEPROM calibration, the FPGA load, a loose clock cable and a FIFO overrun."""

from __future__ import annotations

import numpy as np
import pytest
import usb.core

from dimacq.drivers.mcc import protocol as p
from dimacq.drivers.mcc.driver import MccTask, Usb1808
from dimacq.errors import DeviceStateError, ProtocolError, SetupError
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
    task.read(400, timeout_s=2.0)
    with pytest.raises(ProtocolError, match=r"master clocked (\d+) scans but .*01F2A002.*ICLKO"):
        task.stop()


def test_fifo_overrun_is_reported() -> None:
    backend = Mcc1808Backend(
        Sines(), {0: DaqInput(0, 1.0)}, n_units=3, time_scale=200.0, fifo_bytes=4096
    )
    task = _task(_units(backend))
    task.start()
    import time

    time.sleep(0.3)  # the host is late: 120 000 scans clocked, the FIFO holds 341
    with pytest.raises(DeviceStateError, match="FIFO overrun"):
        for _ in range(50):
            task.read(200, timeout_s=0.2)
    assert any(e.kind == "overflow" for e in task.events)
    with pytest.raises(ProtocolError, match=r"FIFO overrun on .*read faster"):
        task.stop()


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
