"""Every nidaqmx name the NI task and backend use exists in the installed nidaqmx-python (its
generated ``task/channels/_ai_channel.py``, ``task/_timing.py``, ``task/_export_signals.py``,
``system/device.py``, ``constants.py``): a guessed attribute fails here, not on a rig."""

from __future__ import annotations

import inspect

import pytest

nidaqmx = pytest.importorskip("nidaqmx")


def test_channel_timing_export_and_device_names_exist() -> None:
    from nidaqmx.system.device import Device
    from nidaqmx.task import Task
    from nidaqmx.task._export_signals import ExportSignals
    from nidaqmx.task._timing import Timing
    from nidaqmx.task.channels import AIChannel
    from nidaqmx.task.collections import AIChannelCollection

    for name in (
        "ai_coupling",
        "ai_filter_delay",
        "ai_filter_delay_units",
        "ai_filter_delay_adjustment",
        "ai_remove_filter_delay",
    ):
        assert isinstance(getattr(AIChannel, name), property), name
    assert isinstance(Timing.samp_clk_rate, property)
    assert callable(Timing.cfg_samp_clk_timing)
    assert isinstance(ExportSignals.samp_clk_output_term, property)
    assert callable(Task.control)
    for name in (
        "ai_current_int_excit_discrete_vals",
        "ai_voltage_int_excit_discrete_vals",
        "product_type",
        "dev_serial_num",
        "ai_physical_chans",
        "compact_daq_chassis_device",
    ):
        assert isinstance(getattr(Device, name), property), name
    wanted = {
        "add_ai_accel_chan": {
            "min_val", "max_val", "units", "sensitivity", "sensitivity_units",
            "current_excit_source", "current_excit_val",
        },
        "add_ai_force_iepe_chan": {
            "min_val", "max_val", "units", "sensitivity", "sensitivity_units",
            "current_excit_source", "current_excit_val",
        },
        "add_ai_bridge_chan": {
            "min_val", "max_val", "units", "bridge_config", "voltage_excit_source",
            "voltage_excit_val",
        },
        "add_ai_voltage_chan": {"min_val", "max_val"},
    }  # fmt: skip
    for method, params in wanted.items():
        got = set(inspect.signature(getattr(AIChannelCollection, method)).parameters)
        assert params <= got, (method, params - got)


def test_constants_used_exist() -> None:
    from nidaqmx import constants as c

    assert c.BridgeUnits.MILLIVOLTS_PER_VOLT and c.BridgeConfiguration.FULL_BRIDGE
    assert c.DigitalWidthUnits.SECONDS and c.TaskMode.TASK_COMMIT
    assert c.ExcitationSource.INTERNAL and c.ExcitationSource.NONE
    assert c.AccelUnits.METERS_PER_SECOND_SQUARED and c.ForceUnits.NEWTONS
    assert c.AccelSensitivityUnits.MILLIVOLTS_PER_G
    assert c.ForceIEPESensorSensitivityUnits.MILLIVOLTS_PER_NEWTON
    assert c.AcquisitionType.CONTINUOUS and c.Coupling.AC and c.Coupling.DC
