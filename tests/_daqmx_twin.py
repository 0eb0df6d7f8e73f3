"""A twin of NI-DAQmx under nidaqmx-python: an interpreter (the object nidaqmx's ``Task``,
channels, timing, export signals and readers call with NI's attribute ids) for a cDAQ chassis of
NI 9234 and NI 9237 modules, written from NI's documents, not from dimacq's plan:

- a task's modules share one master timebase: the one named ``master`` (default: an NI 9234's
  when the task has one, NI's default (NI KB "Valid Sampling Rates for the NI 9233, NI 9234,
  and NI 9237": a 9237 in a task with a 9234 runs at the 9234's rates), else the device of the
  task's first channel); data rate ``fs = (fM/256)/n``, ``n = 1..31``, coerced up to the
  next rate (NI KB kA00Z0000004A0YSAU);
- an NI 9234 measures ±5 V: a channel whose scaled limits ask more is refused (-200077);
- an NI 9234 gives 2 mA IEPE current or none (NI 9234 Operating Instructions, Figure 4); an
  NI 9237 internal excitation of 2.0, 2.5, 3.3 or 5.0 V; other values are refused
  (NI-DAQmx's -200077, "requested value is not a supported value");
- ``ai_filter_delay`` is the digital filter's delay ``D / fs`` (9234: ``D`` = 38.4; 9237:
  ``40 + 5/512``) in the channel's ``ai_filter_delay_units``; devices in ``no_delay_removal``
  refuse ``ai_remove_filter_delay`` (-200452, "specified property is not supported");
- reading returns, per channel, ``k + 1`` for its ``k``-th sample counted from start, in
  ``fill_mode`` group-by-channel.

nidaqmx's real ``Task`` runs on it (``nidaqmx.task._task._TaskAlternateConstructor``); the
constants, errors and stream readers are nidaqmx's own.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from types import SimpleNamespace
from typing import Any

import nidaqmx
import numpy as np
from nidaqmx.errors import DaqError
from nidaqmx.system.device import _DeviceAlternateConstructor
from nidaqmx.task._task import _TaskAlternateConstructor

#: NI-DAQmx attribute ids (nidaqmx-python's generated properties)
SAMP_CLK_RATE = 0x1344
SAMP_CLK_OUTPUT_TERM = 0x1663
REMOVE_FILTER_DELAY = 0x2FBD
FILTER_DELAY = 0x2FED
FILTER_DELAY_UNITS = 0x3071
FILTER_DELAY_ADJUSTMENT = 0x3074
COUPLING = 0x64
AVAIL_SAMP_PER_CHAN = 0x1223
NUM_CHANS = 0x217B
OVERLOADED_CHANS_EXIST = 0x2174
TOTAL_SAMP_PER_CHAN_ACQUIRED = 0x192A
TASK_NAME = 0x1276
PRODUCT_TYPE = 0x631
SERIAL_NUM = 0x632
AI_PHYSICAL_CHANS = 0x231E
AI_CURRENT_INT_EXCIT_DISCRETE_VALS = 0x29CB
AI_VOLTAGE_INT_EXCIT_DISCRETE_VALS = 0x29C9
SECONDS = nidaqmx.constants.DigitalWidthUnits.SECONDS.value
PERIODS = nidaqmx.constants.DigitalWidthUnits.SAMPLE_CLOCK_PERIODS.value
CURRENT_SOURCE_INTERNAL = nidaqmx.constants.ExcitationSource.INTERNAL.value

#: an NI 9234 measures ±5 V (NI 9144 User Guide, "NI 9234 Calibration Data")
RANGE_9234_V = 5.0
#: module model -> (internal fM, digital filter delay D in samples, IEPE currents, excitation V)
MODELS = {
    "NI 9234": (13.1072e6, 38.4, (2e-3,), ()),
    "NI 9237": (12.8e6, 40.0 + 5.0 / 512.0, (), (2.0, 2.5, 3.3, 5.0)),
}


def _refuse(code: int, what: str) -> DaqError:
    return DaqError(f"NI-DAQmx twin: {what}", code)


@dataclass
class _Chan:
    name: str
    device: str
    kind: str
    attrs: dict[int, Any] = field(default_factory=dict)


@dataclass
class _Task:
    name: str
    chans: list[_Chan] = field(default_factory=list)
    asked_hz: float | None = None
    rate_hz: float | None = None
    export: dict[int, str] = field(default_factory=dict)
    trigger: str = ""
    state: str = "verified"
    read: int = 0


class DaqmxTwin:
    """The interpreter. ``devices`` maps device names to models (``{"cDAQ1Mod1": "NI 9234"}``)."""

    def __init__(
        self,
        devices: dict[str, str],
        *,
        master: str = "",
        no_delay_removal: tuple[str, ...] = (),
    ) -> None:
        self.devices = devices
        self.master = master
        self.no_delay_removal = no_delay_removal
        self.tasks: dict[int, _Task] = {}
        self.driver_version = (24, 8, 0)

    # -- the nidaqmx namespace a driver is given --------------------------------------------
    def module(self) -> Any:
        """What ``NiDsaTask`` is injected with in place of the ``nidaqmx`` package."""

        def task(name: str = "") -> Any:
            handle = len(self.tasks) + 1
            self.tasks[handle] = _Task(name)
            return _TaskAlternateConstructor(handle, self, True)

        devices = [_DeviceAlternateConstructor(name, self) for name in self.devices]
        local = SimpleNamespace(devices=devices, driver_version=self.driver_version)
        system = SimpleNamespace(System=SimpleNamespace(local=lambda: local))
        return SimpleNamespace(
            Task=task, errors=nidaqmx.errors, constants=nidaqmx.constants, system=system
        )

    # -- devices ----------------------------------------------------------------------------
    def get_device_attribute_string(self, name: str, attr: int) -> str:
        if attr == PRODUCT_TYPE:
            return self.devices[name]
        assert attr == AI_PHYSICAL_CHANS
        return ", ".join(f"{name}/ai{k}" for k in range(4))

    def get_device_attribute_uint32(self, name: str, attr: int) -> int:
        assert attr == SERIAL_NUM
        return 0x1A2B3C00 + list(self.devices).index(name)

    def get_device_attribute_double_array(self, name: str, attr: int) -> list[float]:
        _fm, _d, currents, volts = MODELS[self.devices[name]]
        if attr == AI_CURRENT_INT_EXCIT_DISCRETE_VALS:
            return list(currents)
        assert attr == AI_VOLTAGE_INT_EXCIT_DISCRETE_VALS
        return list(volts)

    # -- tasks ----------------------------------------------------------------------------------
    def get_task_attribute_string(self, handle: int, attr: int) -> str:
        assert attr == TASK_NAME
        return self.tasks[handle].name

    def internal_get_last_created_chan(self) -> None:
        return None

    def _add(self, handle: int, phys: str, name: str, kind: str) -> None:
        device, _, _ai = phys.partition("/")
        if device not in self.devices:
            raise _refuse(-200220, f"device {device} not found")
        t = self.tasks[handle]
        t.chans.append(_Chan(name or phys, device, kind, {FILTER_DELAY_UNITS: PERIODS}))
        t.state = "verified"

    def _current(self, device: str, source: int, value: float) -> None:
        offered = MODELS[self.devices[device]][2]
        if source == CURRENT_SOURCE_INTERNAL and not any(abs(value - c) < 1e-9 for c in offered):
            raise _refuse(-200077, f"{device}: IEPE current {value} A is not supported")

    def _volts(self, device: str, top_v: float) -> None:
        if self.devices[device] == "NI 9234" and top_v > RANGE_9234_V * (1 + 1e-9):
            raise _refuse(-200077, f"{device}: ±{top_v} V is beyond its ±5 V")

    def create_ai_accel_chan(self, handle, phys, name, *args: Any) -> None:  # type: ignore[no-untyped-def]
        # (terminal_config, min, max, units [m/s^2], sensitivity [mV/g], sensitivity_units,
        #  current_excit_source, current_excit_val, custom_scale_name)
        device = phys.partition("/")[0]
        self._volts(device, args[2] / 9.80665 * args[4] * 1e-3)
        self._current(device, args[6], args[7])
        self._add(handle, phys, name, "accel")

    def create_ai_force_iepe_chan(self, handle, phys, name, *args: Any) -> None:  # type: ignore[no-untyped-def]
        # (terminal_config, min, max, units [N], sensitivity [mV/N], ...)
        device = phys.partition("/")[0]
        self._volts(device, args[2] * args[4] * 1e-3)
        self._current(device, args[6], args[7])
        self._add(handle, phys, name, "force")

    def create_ai_bridge_chan(self, handle, phys, name, *args: Any) -> None:  # type: ignore[no-untyped-def]
        # (min, max, units, bridge_config, voltage_excit_source, voltage_excit_val, R, scale)
        device = phys.partition("/")[0]
        offered = MODELS[self.devices[device]][3]
        if not any(abs(args[5] - v) < 1e-9 for v in offered):
            raise _refuse(-200077, f"{device}: excitation {args[5]} V is not supported")
        self._add(handle, phys, name, "bridge")

    def create_ai_voltage_chan(self, handle, phys, name, *args: Any) -> None:  # type: ignore[no-untyped-def]
        self._add(handle, phys, name, "voltage")

    def _chan(self, handle: int, name: str) -> _Chan:
        return next(c for c in self.tasks[handle].chans if c.name == name)

    def set_chan_attribute_int32(self, handle, name, attr, val) -> None:  # type: ignore[no-untyped-def]
        self._chan(handle, name).attrs[attr] = val

    def set_chan_attribute_bool(self, handle, name, attr, val) -> None:  # type: ignore[no-untyped-def]
        c = self._chan(handle, name)
        if attr == REMOVE_FILTER_DELAY and c.device in self.no_delay_removal:
            raise _refuse(-200452, f"{c.device}: filter delay removal is not supported")
        c.attrs[attr] = val

    def set_chan_attribute_double(self, handle, name, attr, val) -> None:  # type: ignore[no-untyped-def]
        self._chan(handle, name).attrs[attr] = val
        self.tasks[handle].state = "verified"

    def get_chan_attribute_double(self, handle, name, attr) -> float:  # type: ignore[no-untyped-def]
        c = self._chan(handle, name)
        if attr == FILTER_DELAY:
            t = self.tasks[handle]
            assert t.rate_hz is not None, "read ai_filter_delay after the task is committed"
            d = MODELS[self.devices[c.device]][1]
            in_s = c.attrs.get(FILTER_DELAY_UNITS) == SECONDS
            return d / t.rate_hz if in_s else d
        return float(c.attrs.get(attr, 0.0))

    # -- timing, export, trigger, control ---------------------------------------------------
    def cfg_samp_clk_timing(self, handle, rate, source, edge, mode, samps) -> None:  # type: ignore[no-untyped-def]
        self.tasks[handle].asked_hz = rate

    def set_exported_signal_attribute_string(self, handle, attr, val) -> None:  # type: ignore[no-untyped-def]
        self.tasks[handle].export[attr] = val

    def cfg_dig_edge_start_trig(self, handle, source, edge) -> None:  # type: ignore[no-untyped-def]
        self.tasks[handle].trigger = source

    def _commit(self, t: _Task) -> None:
        leads = [ch.device for ch in t.chans if self.devices[ch.device] == "NI 9234"]
        master = self.master or (leads[0] if leads else t.chans[0].device)
        fm = MODELS[self.devices[master]][0]
        top = fm / 256.0
        assert t.asked_hz is not None
        if t.asked_hz > top:
            raise _refuse(-200077, f"rate {t.asked_hz} above {top}")
        n = max(1, min(31, math.floor(top / t.asked_hz + 1e-9)))
        t.rate_hz = top / n
        t.state = "committed"

    def task_control(self, handle, action) -> None:  # type: ignore[no-untyped-def]
        if action == nidaqmx.constants.TaskMode.TASK_COMMIT.value:
            self._commit(self.tasks[handle])

    def get_timing_attribute_double(self, handle, attr) -> float:  # type: ignore[no-untyped-def]
        assert attr == SAMP_CLK_RATE
        t = self.tasks[handle]
        if t.rate_hz is None:
            self._commit(t)
        assert t.rate_hz is not None
        return t.rate_hz

    def start_task(self, handle) -> None:  # type: ignore[no-untyped-def]
        t = self.tasks[handle]
        if t.state != "committed":
            self._commit(t)
        t.state = "running"

    def stop_task(self, handle) -> None:  # type: ignore[no-untyped-def]
        self.tasks[handle].state = "committed"

    def clear_task(self, handle) -> None:  # type: ignore[no-untyped-def]
        self.tasks[handle].state = "cleared"

    # -- reading ----------------------------------------------------------------------------
    def get_read_attribute_uint32(self, handle, attr) -> int:  # type: ignore[no-untyped-def]
        if attr == NUM_CHANS:
            return len(self.tasks[handle].chans)
        assert attr == AVAIL_SAMP_PER_CHAN
        return 0

    def get_read_attribute_uint64(self, handle, attr) -> int:  # type: ignore[no-untyped-def]
        assert attr == TOTAL_SAMP_PER_CHAN_ACQUIRED
        return self.tasks[handle].read

    def get_read_attribute_bool(self, handle, attr) -> bool:  # type: ignore[no-untyped-def]
        assert attr == OVERLOADED_CHANS_EXIST
        return False

    def read_analog_f64(self, handle, n, timeout, fill_mode, data) -> tuple[Any, int]:  # type: ignore[no-untyped-def]
        t = self.tasks[handle]
        assert t.state == "running"
        k = np.arange(t.read, t.read + n, dtype=float) + 1.0
        data[:, :] = k[None, :]
        t.read += n
        return data, n
