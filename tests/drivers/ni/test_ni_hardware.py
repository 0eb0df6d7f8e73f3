"""On a real NI DSA device (opt-in: ``pytest --device ni``; never run on CI, not run by its
author: no NI hardware at hand). Needs ``dimacq[ni]`` and NI-DAQmx; the first device that has AI
channels is used, its ai0 as an IEPE accelerometer input (open or with a sensor on it) at the
IEPE current the device offers; the rate is NI-DAQmx's, read back."""

from __future__ import annotations

import numpy as np
import pytest


@pytest.mark.device("ni")
def test_a_real_dsa_device_reads_one_second() -> None:
    from dimacq.backends.ni_daqmx import import_nidaqmx, offered
    from dimacq.drivers.ni.plan import ModuleSlot
    from dimacq.drivers.ni.task import NiDsaTask

    ni = import_nidaqmx()
    devices = [d for d in ni.system.System.local().devices if len(d.ai_physical_chans)]
    assert devices, "NI-DAQmx sees no device with analogue inputs"
    dev = devices[0]
    n = len(dev.ai_physical_chans)
    currents = offered(dev, "ai_current_int_excit_discrete_vals")
    slot = ModuleSlot(dev.name, str(dev.product_type), tuple(range(n)), n, currents)
    task = NiDsaTask(ni, [slot])
    ma = currents[0] * 1e3 if currents else 0.0
    task.add_accel_channel(0, "ai0 accel", 100.0, range_v=5.0, iepe_current_ma=ma)
    task.configure_timing(2048.0, 256)
    task.start()
    assert task.sample_rate_hz is not None and task.sample_rate_hz >= 2048.0
    try:
        block = task.read(2048, timeout_s=5.0)
    finally:
        task.stop()
    assert block.data.shape == (1, 2048) and np.isfinite(block.data).all()
    assert task.samples_clocked is not None and task.samples_clocked >= 2048
