"""A :class:`~dimacq.devices.daq.Daq` through MCC's official ``uldaq`` Python package.

MCC's Universal Library for Linux (``github:mccdaq/uldaq``: ``libuldaq.so`` and its ``uldaq``
Python binding) loads each device's firmware and FPGA itself and covers MCC's IEPE DAQs: the
DT9837A/B/C (four 24-bit IEPE inputs, ``AiUsb9837x.cpp``: per-channel IEPE excitation and AC/DC
coupling from ``AiConfig``, ranges ±10 V and ±1 V, 195.313 Hz to 52.734 kHz (A) or 105.469 kHz)
and the USB-1808(X) (voltage inputs; IEPE conditioning external).

The task is the ``uldaq`` calls a lab would write by hand:

- channels: ``AiConfig.set_chan_iepe_mode`` (``IepeMode.ENABLED`` where the rig gives an IEPE
  current; the current itself is the device's fixed source, not settable through uldaq),
  ``set_chan_coupling_mode`` (``CouplingMode.AC`` / ``DC``), ``set_chan_sensor_sensitivity`` 1.0
  (the data stay in volts; the task divides by the transducer's sensitivity);
- one scan ``AiDevice.a_in_scan(low, high, AiInputMode.SINGLE_ENDED, range, n, rate,
  ScanOption.CONTINUOUS [| EXTTRIGGER], AInScanFlag.DEFAULT, buffer)`` over the contiguous
  inputs ``low..high`` (inputs between the task's channels are scanned and dropped), all on the
  one range the channels share (a uldaq scan has one range per call);
- ``set_trigger(TriggerType.POS_EDGE, 0, 0, 0, 0)`` before the scan when the task starts on the
  external trigger input;
- the circular buffer read as ``get_scan_status()`` reports ``current_total_count`` (samples of
  all channels since the start); a host later than the buffer holds is an overflow.

The mapping from the rig file to uldaq's enums (:func:`scan_plan`) needs no library and is
tested against uldaq's ``ul_enums.py``; the rest needs ``libuldaq`` and a device.
"""

from __future__ import annotations

import logging
import re
import time
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np

from dimacq.devices.daq import ChannelConfig, DaqEvent
from dimacq.drivers.daq.driver import ScanTask, accel_config, force_config
from dimacq.drivers.mcc.driver import MccIdentity
from dimacq.drivers.stream import CounterStream
from dimacq.errors import DeviceStateError, DeviceTimeoutError, SetupError

__all__ = ["ULDAQ_USB_IDS", "ScanPlan", "UldaqTask", "range_volts", "scan_plan"]

log = logging.getLogger(__name__)

#: USB (vendor id, product id) → model of the uldaq devices with analogue inputs (uldaq
#: src/DaqDeviceId.h, src/DaqDeviceManager.cpp:33-116; MCC 0x09DB, Data Translation 0x0867:
#: UsbDaqDevice.h:30)
ULDAQ_USB_IDS = {
    **{
        (0x09DB, pid): name
        for pid, name in {
            0x0099: "USB-1608HS-2AO",
            0x00BD: "USB-1608HS",
            0x00C4: "USB-1208HS",
            0x00C5: "USB-1208HS-2AO",
            0x00C6: "USB-1208HS-4AO",
            0x00E8: "USB-1208FS-Plus",
            0x00E9: "USB-1408FS-Plus",
            0x00EA: "USB-1608FS-Plus",
            0x0110: "USB-1608G",
            0x0111: "USB-1608GX",
            0x0112: "USB-1608GX-2AO",
            0x0113: "USB-201",
            0x0114: "USB-204",
            0x0118: "USB-2633",
            0x0119: "USB-2637",
            0x011C: "USB-2020",
            0x0120: "USB-2623",
            0x0121: "USB-2627",
            0x012B: "USB-202",
            0x012C: "USB-205",
            0x0134: "USB-1608G",
            0x0135: "USB-1608GX",
            0x0136: "USB-1608GX-2AO",
            0x013D: "USB-1808",
            0x013E: "USB-1808X",
        }.items()
    },
    (0x0867, 0x3998): "DT9837A/B/C",
}
#: the rate a device coerces to, accepted against the asked rate (relative)
RATE_TOLERANCE = 1e-4
#: seconds of data the circular buffer holds
BUFFER_S = 10.0

_RANGE_NAME = re.compile(r"^BIP(\d*)(?:PT(\d+))?VOLTS$")


def range_volts(name: str) -> float | None:
    """The full scale (V) of a bipolar uldaq ``Range`` member name: ``BIP10VOLTS`` → 10,
    ``BIP2PT5VOLTS`` → 2.5, ``BIPPT625VOLTS`` → 0.625; None for the others (unipolar)."""
    m = _RANGE_NAME.match(name)
    if m is None or not (m.group(1) or m.group(2)):
        return None
    return float(f"{m.group(1) or 0}.{m.group(2) or 0}")


@dataclass(frozen=True)
class ScanPlan:
    """What the task asks of uldaq: the scanned inputs ``low..high``, the range member, the
    per-channel IEPE and coupling members, the scan options, and each task channel's column in
    the scanned block."""

    low: int
    high: int
    range: Any
    iepe: dict[int, Any]
    coupling: dict[int, Any]
    options: Any
    columns: list[int]


def scan_plan(
    ul: Any,
    channels: tuple[ChannelConfig, ...],
    supported_ranges: list[Any],
    *,
    n_inputs: int,
    supports_iepe: bool,
    external_trigger: bool = False,
) -> ScanPlan:
    """The uldaq calls for ``channels`` (sorted by input) on a device with ``n_inputs`` inputs.

    ``ul`` holds uldaq's enums (``Range``, ``IepeMode``, ``CouplingMode``, ``ScanOption``): the
    ``uldaq`` module itself, or its ``ul_enums``.

    Raises
    ------
    SetupError
        No channel; an input beyond the device; channels on different ranges; a range the
        device does not offer; IEPE on a device without it. Each names the channel and the fix.
    """
    if not channels:
        raise SetupError("the uldaq task has no channels; add channels before start()")
    for c in channels:
        if not 0 <= c.physical_channel < n_inputs:
            raise SetupError(
                f"channel {c.name}: physical_channel {c.physical_channel}; the device has "
                f"inputs 0..{n_inputs - 1}"
            )
    spans = {round(c.range_v, 9) for c in channels}
    if len(spans) > 1:
        raise SetupError(
            f"channels on ranges {sorted(spans)} V: a uldaq scan has one range; give every "
            "channel of the rig file the same range_v"
        )
    want = channels[0].range_v
    offered = {m: range_volts(m.name) for m in supported_ranges}
    match = [m for m, v in offered.items() if v is not None and abs(v - want) < 1e-9 * want]
    if not match:
        have = ", ".join(f"±{v:g} V" for v in offered.values() if v is not None) or "none"
        raise SetupError(
            f"channel {channels[0].name}: range_v = {want:g} V; the device offers {have}: set "
            "range_v to one of them in the rig file"
        )
    iepe: dict[int, Any] = {}
    coupling: dict[int, Any] = {}
    for c in channels:
        if c.iepe_current_ua > 0 and not supports_iepe:
            raise SetupError(
                f"channel {c.name}: IEPE current {c.iepe_current_ua} µA on a device without "
                "IEPE excitation; put an IEPE conditioner before it and set iepe_current_ma = 0"
            )
        if supports_iepe:
            iepe[c.physical_channel] = (
                ul.IepeMode.ENABLED if c.iepe_current_ua > 0 else ul.IepeMode.DISABLED
            )
            coupling[c.physical_channel] = (
                ul.CouplingMode.AC if c.coupling == "AC" else ul.CouplingMode.DC
            )
    low = channels[0].physical_channel
    high = channels[-1].physical_channel
    options = ul.ScanOption.CONTINUOUS
    if external_trigger:
        options |= ul.ScanOption.EXTTRIGGER
    return ScanPlan(
        low,
        high,
        match[0],
        iepe,
        coupling,
        options,
        [c.physical_channel - low for c in channels],
    )


class UldaqTask(ScanTask):
    """A task on one uldaq device (``uldaq.DaqDevice``, connected).

    Parameters
    ----------
    ul : module
        ``uldaq``.
    device : uldaq.DaqDevice
    name : str
    external_trigger : bool
        The scan starts on the device's external trigger input (rising edge).
    """

    def __init__(
        self, ul: Any, device: Any, name: str = "task", *, external_trigger: bool = False
    ) -> None:
        self.ul = ul
        self.device = device
        self.name = name
        self.external_trigger = external_trigger
        self.ai = device.get_ai_device()
        info = self.ai.get_info()
        self.n_inputs = int(info.get_num_chans())
        self.supports_iepe = bool(info.supports_iepe())
        self.ranges = list(info.get_ranges(ul.AiInputMode.SINGLE_ENDED))
        self._channels: dict[int, ChannelConfig] = {}
        self.sample_rate_hz: float | None = None
        self.samples_per_frame = 256
        self.events: list[DaqEvent] = []
        self.samples_clocked: int | None = None
        self._running = False
        self._stream: CounterStream[DaqEvent] = CounterStream(0)
        self._plan: ScanPlan | None = None
        self._buffer: Any = None
        self._view = np.zeros(0)
        self._read = 0

    # -- identity and channels -------------------------------------------------------------
    def identify(self) -> MccIdentity:
        d = self.device.get_descriptor()
        serial = str(d.unique_id)
        return MccIdentity(str(d.product_name), serial, (serial,), "uldaq", self.n_inputs)

    def add_channel(self, config: ChannelConfig) -> None:
        self._check_new_channel(config)
        self._channels[config.physical_channel] = config
        try:
            scan_plan(
                self.ul,
                self.channels,
                self.ranges,
                n_inputs=self.n_inputs,
                supports_iepe=self.supports_iepe,
            )
        except SetupError:
            del self._channels[config.physical_channel]
            raise

    def add_accel_channel(
        self,
        physical_channel: int,
        name: str,
        sensitivity_mv_per_g: float,
        *,
        range_v: float = 10.0,
        iepe_current_ma: float = 4.0,
        coupling: Literal["AC", "DC"] = "AC",
    ) -> None:
        """An IEPE accelerometer (excitation on when ``iepe_current_ma`` > 0); data in m/s²."""
        self.add_channel(
            accel_config(
                physical_channel, name, sensitivity_mv_per_g, range_v, iepe_current_ma, coupling
            )
        )

    def add_force_channel(
        self,
        physical_channel: int,
        name: str,
        sensitivity_mv_per_n: float,
        *,
        range_v: float = 10.0,
        iepe_current_ma: float = 4.0,
        coupling: Literal["AC", "DC"] = "AC",
    ) -> None:
        """An IEPE force transducer (hammer); data in N."""
        self.add_channel(
            force_config(
                physical_channel, name, sensitivity_mv_per_n, range_v, iepe_current_ma, coupling
            )
        )

    # -- run ---------------------------------------------------------------------------------
    def start(self) -> None:
        """Channel settings, trigger, then the continuous scan; the rate the device gives must be
        the rate asked within :data:`RATE_TOLERANCE`."""
        ul = self.ul
        if self._running:
            raise DeviceStateError(f"task {self.name} is already running")
        if self.sample_rate_hz is None:
            raise SetupError(f"task {self.name}: call configure_timing() before start()")
        chans = self.channels
        plan = scan_plan(
            ul,
            chans,
            self.ranges,
            n_inputs=self.n_inputs,
            supports_iepe=self.supports_iepe,
            external_trigger=self.external_trigger,
        )
        config = self.ai.get_config()
        for ch, mode in plan.iepe.items():
            config.set_chan_iepe_mode(ch, mode)
            config.set_chan_coupling_mode(ch, plan.coupling[ch])
            config.set_chan_sensor_sensitivity(ch, 1.0)
        if self.external_trigger:
            self.ai.set_trigger(ul.TriggerType.POS_EDGE, 0, 0.0, 0.0, 0)
        n_scan = plan.high - plan.low + 1
        per_channel = max(self.samples_per_frame * 4, int(BUFFER_S * self.sample_rate_hz))
        self._buffer = ul.create_float_buffer(n_scan, per_channel)  # (c_double * n)()
        self._view = np.ctypeslib.as_array(self._buffer)  # no copy: the device writes into it
        actual = self.ai.a_in_scan(
            plan.low,
            plan.high,
            ul.AiInputMode.SINGLE_ENDED,
            plan.range,
            per_channel,
            self.sample_rate_hz,
            plan.options,
            ul.AInScanFlag.DEFAULT,
            self._buffer,
        )
        if abs(actual / self.sample_rate_hz - 1) > RATE_TOLERANCE:
            self.ai.scan_stop()
            raise SetupError(
                f"[daq] sample_rate_hz = {self.sample_rate_hz:g}: the device scans at "
                f"{actual:.6g} Hz instead; set sample_rate_hz to {actual:.6g}"
            )
        self._plan = plan
        self._read = 0
        self._scale = np.array([1.0 / c.sensitivity_v_per_unit for c in chans])
        self._stream = CounterStream(len(chans), flag_shape=(len(chans),), flag_dtype=np.bool_)
        self.events = []
        self.samples_clocked = None
        self._running = True
        log.info("uldaq task %s: inputs %d..%d at %g Hz", self.name, plan.low, plan.high, actual)

    def _poll(self) -> int:
        """Copy the scans the device has put in the circular buffer; how many were new."""
        assert self._plan is not None
        _status, xfer = self.ai.get_scan_status()
        n_scan = self._plan.high - self._plan.low + 1
        total = int(xfer.current_total_count) // n_scan
        cap = self._view.size // n_scan
        new = total - self._read
        if new <= 0:
            return 0
        if new > cap:
            msg = (
                f"task {self.name}: the host fell {new - cap} scans behind the {cap}-scan buffer "
                "(read faster); stop and restart the task"
            )
            ev = DaqEvent("overflow", self._stream.end, new - cap, self.channel_names, msg)
            self._stream.record(ev)
            self.events.append(ev)
            raise DeviceStateError(msg)
        idx = (np.arange(self._read, total) % cap)[:, None] * n_scan + np.array(self._plan.columns)
        volts = self._view[idx]
        full = float(self.channels[0].range_v)
        over = np.abs(volts) >= full
        self._stream.put(self._stream.end, volts * self._scale, over)
        self._read = total
        return new

    def _fill(self, n_samples: int, timeout_s: float | None) -> None:
        deadline = time.monotonic() + (1.0 if timeout_s is None else timeout_s)
        while self._stream.buffered < n_samples:
            if not self._running:
                raise DeviceStateError(
                    f"task {self.name} is not running and holds {self._stream.buffered} of the "
                    f"{n_samples} samples asked for; start() it or read_buffered()"
                )
            if self._poll():
                continue
            if time.monotonic() > deadline:
                raise DeviceTimeoutError(
                    f"task {self.name}: no new scans within {timeout_s} s "
                    f"({self._stream.buffered} samples kept; read again)"
                )
            time.sleep(0.002)

    def stop(self) -> None:
        if not self._running:
            return
        self.ai.scan_stop()
        self._poll()
        self._running = False
        self.samples_clocked = self._read

    def close(self) -> None:
        if self._running:
            self.stop()
        self.device.disconnect()
        self.device.release()
