"""On a real USB-1808X (opt-in: ``pytest --device mcc``; never run on CI, not run by its author:
no unit was at hand). Needs libusb, the udev rule (config/udev) and, after power-up, the binary
FPGA image in ``DIMACQ_DAQ_FPGA_FILE`` (``dimacq devices mcc-fpga``) or an installed libuldaq.
Leave AI0 open or on a conditioner output."""

from __future__ import annotations

import os

import numpy as np
import pytest
import usb.core

from dimacq.drivers.mcc import fpga
from dimacq.drivers.mcc import protocol as p
from dimacq.drivers.mcc.driver import MccTask, Usb1808


@pytest.mark.device("mcc")
def test_a_real_unit_scans_one_second() -> None:
    found = [
        d
        for d in usb.core.find(find_all=True, idVendor=p.VENDOR_ID) or []
        if int(d.idProduct) in p.PRODUCT_IDS
    ]
    assert found, "no USB-1808(X) on the bus"
    unit = Usb1808(found[0], timeout_s=2.0)
    try:
        if not unit.status() & p.Status.FPGA_CONFIGURED:
            name = os.environ.get("DIMACQ_DAQ_FPGA_FILE", "")
            found = (fpga.read_image(name), name) if name else fpga.image_from_library()
            assert found, "set DIMACQ_DAQ_FPGA_FILE to USB_1808.bin or install libuldaq"
            unit.configure_fpga(*found)
        slope, offset = unit.read_calibration()
        assert np.all(np.abs(slope[:, :2] - 1) < 0.05) and np.all(np.abs(offset[:, :2]) < 2000)
        task = MccTask([unit], calibrations=[(slope, offset)])
        task.add_voltage_channel(0, "ai0", range_v=10.0)
        task.configure_timing(10_000.0, samples_per_frame=1024)
        task.start()
        block = task.read(10_000, timeout_s=3.0)
        task.stop()
        assert block.valid.all() and np.all(np.abs(block.data) <= 10.0)
        assert task.samples_clocked is not None and task.samples_clocked >= 10_000
    finally:
        unit.close()
