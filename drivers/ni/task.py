"""NI DSA devices (USB-4431, NI 9234, ...) through the official ``nidaqmx`` Python API.

Written against nidaqmx's documented API (``nidaqmx.Task``: ``ai_channels.add_ai_accel_chan``
/ ``add_ai_force_iepe_chan`` with internal IEPE current excitation and AC coupling,
``timing.cfg_samp_clk_timing`` continuous, ``triggers.start_trigger.cfg_dig_edge_start_trig``,
``stream_readers.AnalogMultiChannelReader.read_many_sample`` in blocks, ``in_stream``
overload and sample counters). NI-DAQmx scales the data to m/s² and N from the sensitivities
itself. **No simulated twin**: NI-DAQmx's own simulated devices (NI MAX) are the way to try it
without hardware; dimacq's tests cover only its setup and error paths (README).

Several DSA devices in one task (the channels of ``[daq] units`` in order) are synchronised by
NI-DAQmx itself where the hardware allows it (modules of one cDAQ chassis; USB-4431s need their
sync cabling); physical channel ``k`` is the ``k``-th AI of the units' AI channels.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np

from dimacq.devices.daq import ChannelConfig, DaqBlock, DaqEvent
from dimacq.drivers.daq.driver import STANDARD_GRAVITY
from dimacq.errors import DeviceError, DeviceStateError, DeviceTimeoutError, SetupError

__all__ = ["NiDsaTask", "NiIdentity"]

log = logging.getLogger(__name__)

#: NI-DAQmx error codes (nidaqmx.error_codes.DAQmxErrors)
_TIMEOUT = -200284  # SAMPLES_NOT_YET_AVAILABLE
_OVERWRITTEN = -200279  # SAMPLES_NO_LONGER_AVAILABLE: the host buffer overflowed


@dataclass(frozen=True)
class NiIdentity:
    model: str
    serial_number: str
    units: tuple[str, ...]


@dataclass(frozen=True)
class _Chan:
    config: ChannelConfig
    kind: Literal["accel", "force", "voltage"]
    sensitivity: float  # mV/g, mV/N or 1
    iepe_a: float


class NiDsaTask:
    """A :class:`~dimacq.devices.daq.Daq` on NI DSA devices.

    Parameters
    ----------
    nidaqmx : module
        The imported ``nidaqmx`` package (injected).
    physical_channels : list of str
        ``"Dev1/ai0"`` ... : the units' AI channels in order (physical channel k = item k).
    units : tuple of str
        Device names.
    start_trigger : str
        A digital edge that starts the task (``"/cDAQ1/PFI0"``), or "" (start at once).
    """

    def __init__(
        self,
        nidaqmx: Any,
        physical_channels: list[str],
        units: tuple[str, ...],
        *,
        start_trigger: str = "",
        name: str = "impact",
    ) -> None:
        self._ni = nidaqmx
        self.physical_channels = physical_channels
        self.units = units
        self.start_trigger = start_trigger
        self.name = name
        self._chans: dict[int, _Chan] = {}
        self.sample_rate_hz: float | None = None
        self.samples_per_frame = 256
        self.events: list[DaqEvent] = []
        self.samples_clocked: int | None = None
        self._task: Any = None
        self._reader: Any = None
        self._next = 0

    def identify(self) -> NiIdentity:
        from nidaqmx.system import Device

        dev = Device(self.units[0])
        return NiIdentity(str(dev.product_type), f"{int(dev.dev_serial_num):X}", self.units)

    def _add(self, k: int, chan: _Chan) -> None:
        if self._task is not None:
            raise DeviceStateError(f"task {self.name} is running; stop it before adding channels")
        if not 0 <= k < len(self.physical_channels):
            raise SetupError(
                f"channel {chan.config.name}: physical_channel {k}; the units "
                f"{', '.join(self.units)} have {len(self.physical_channels)} AI channels: add a "
                "device to [daq] units or use another input"
            )
        if k in self._chans:
            raise SetupError(f"physical channel {k} is already in task {self.name}")
        self._chans[k] = chan

    def add_accel_channel(
        self,
        physical_channel: int,
        name: str,
        sensitivity_mv_per_g: float,
        *,
        range_v: float = 5.0,
        iepe_current_ma: float = 4.0,
        coupling: Literal["AC", "DC"] = "AC",
    ) -> None:
        v = sensitivity_mv_per_g * 1e-3 / STANDARD_GRAVITY
        cfg = ChannelConfig(physical_channel, name, "m/s^2", v, range_v, 0, coupling)
        self._add(physical_channel, _Chan(cfg, "accel", sensitivity_mv_per_g, iepe_current_ma))

    def add_force_channel(
        self,
        physical_channel: int,
        name: str,
        sensitivity_mv_per_n: float,
        *,
        range_v: float = 5.0,
        iepe_current_ma: float = 4.0,
        coupling: Literal["AC", "DC"] = "AC",
    ) -> None:
        cfg = ChannelConfig(
            physical_channel, name, "N", sensitivity_mv_per_n * 1e-3, range_v, 0, coupling
        )
        self._add(physical_channel, _Chan(cfg, "force", sensitivity_mv_per_n, iepe_current_ma))

    def add_voltage_channel(
        self,
        physical_channel: int,
        name: str,
        *,
        range_v: float = 10.0,
        coupling: Literal["AC", "DC"] = "DC",
    ) -> None:
        cfg = ChannelConfig(physical_channel, name, "V", 1.0, range_v, 0, coupling)
        self._add(physical_channel, _Chan(cfg, "voltage", 1.0, 0.0))

    @property
    def channels(self) -> tuple[ChannelConfig, ...]:
        return tuple(self._chans[k].config for k in sorted(self._chans))

    @property
    def channel_names(self) -> tuple[str, ...]:
        return tuple(c.name for c in self.channels)

    @property
    def running(self) -> bool:
        return self._task is not None

    def configure_timing(self, sample_rate_hz: float, samples_per_frame: int = 256) -> None:
        if sample_rate_hz <= 0 or samples_per_frame <= 0:
            raise SetupError(
                f"[daq] sample_rate_hz = {sample_rate_hz}, samples_per_frame = "
                f"{samples_per_frame}: give positive values"
            )
        self.sample_rate_hz = float(sample_rate_hz)
        self.samples_per_frame = int(samples_per_frame)

    def start(self) -> None:
        """Create the NI-DAQmx task, add the channels (IEPE from the device), time, start."""
        from nidaqmx import constants as c
        from nidaqmx.stream_readers import AnalogMultiChannelReader

        if self._task is not None:
            raise DeviceStateError(f"task {self.name} is already running")
        if not self._chans or self.sample_rate_hz is None:
            raise SetupError(f"task {self.name}: add channels and configure_timing() first")
        task = self._ni.Task(self.name)
        try:
            for k in sorted(self._chans):
                ch = self._chans[k]
                cfg, phys = ch.config, self.physical_channels[k]
                full = cfg.range_v / cfg.sensitivity_v_per_unit  # ± full scale, units
                excite = c.ExcitationSource.INTERNAL if ch.iepe_a > 0 else c.ExcitationSource.NONE
                if ch.kind == "accel":
                    ai = task.ai_channels.add_ai_accel_chan(
                        phys,
                        cfg.name,
                        min_val=-full,
                        max_val=full,
                        units=c.AccelUnits.METERS_PER_SECOND_SQUARED,
                        sensitivity=ch.sensitivity,
                        sensitivity_units=c.AccelSensitivityUnits.MILLIVOLTS_PER_G,
                        current_excit_source=excite,
                        current_excit_val=ch.iepe_a * 1e-3,
                    )
                elif ch.kind == "force":
                    ai = task.ai_channels.add_ai_force_iepe_chan(
                        phys,
                        cfg.name,
                        min_val=-full,
                        max_val=full,
                        units=c.ForceUnits.NEWTONS,
                        sensitivity=ch.sensitivity,
                        sensitivity_units=c.ForceIEPESensorSensitivityUnits.MILLIVOLTS_PER_NEWTON,
                        current_excit_source=excite,
                        current_excit_val=ch.iepe_a * 1e-3,
                    )
                else:
                    ai = task.ai_channels.add_ai_voltage_chan(
                        phys, cfg.name, min_val=-full, max_val=full
                    )
                ai.ai_coupling = c.Coupling.AC if cfg.coupling == "AC" else c.Coupling.DC
            task.timing.cfg_samp_clk_timing(
                self.sample_rate_hz,
                sample_mode=c.AcquisitionType.CONTINUOUS,
                samps_per_chan=max(int(self.sample_rate_hz * 10), 4 * self.samples_per_frame),
            )
            if self.start_trigger:
                task.triggers.start_trigger.cfg_dig_edge_start_trig(self.start_trigger)
            task.start()
        except self._ni.errors.DaqError as err:
            task.close()
            raise SetupError(f"task {self.name}: NI-DAQmx refused the set-up: {err}") from err
        self._task = task
        self._reader = AnalogMultiChannelReader(task.in_stream)
        self._next = 0
        self.events = []
        self.samples_clocked = None

    def read(self, n_samples: int, timeout_s: float | None = None) -> DaqBlock:
        if self._task is None:
            raise DeviceStateError(f"task {self.name} is not running; start() it")
        data = np.zeros((len(self._chans), n_samples))
        try:
            self._reader.read_many_sample(data, n_samples, 10.0 if timeout_s is None else timeout_s)
        except self._ni.errors.DaqError as err:
            if err.error_code == _TIMEOUT:
                ev = DaqEvent("timeout", self._next, 0, (), f"NI-DAQmx timeout: {err}")
                self.events.append(ev)
                raise DeviceTimeoutError(f"task {self.name}: no samples in time ({err})") from err
            if err.error_code == _OVERWRITTEN:
                ev = DaqEvent("overflow", self._next, 0, self.channel_names, str(err))
                self.events.append(ev)
                raise DeviceStateError(
                    f"task {self.name}: the NI-DAQmx buffer overflowed (read faster); restart"
                ) from err
            raise DeviceError(f"task {self.name}: NI-DAQmx read failed: {err}") from err
        overload = np.zeros(data.shape, dtype=bool)
        events: tuple[DaqEvent, ...] = ()
        stream = self._task.in_stream
        if stream.overloaded_chans_exist:
            hit = tuple(str(n) for n in stream.overloaded_chans)
            over = [nm in hit for nm in self.channel_names]
            overload[np.array(over, dtype=bool)] = True
            events = (DaqEvent("overload", self._next, n_samples, hit, f"overload on {hit}"),)
            self.events.extend(events)
        assert self.sample_rate_hz is not None
        block = DaqBlock(
            self._next,
            self.sample_rate_hz,
            self.channel_names,
            tuple(c.units for c in self.channels),
            data,
            overload,
            np.ones(n_samples, dtype=bool),
            events,
        )
        self._next += n_samples
        return block

    def read_available(self, timeout_s: float | None = None) -> DaqBlock:
        avail = int(self._task.in_stream.avail_samp_per_chan) if self._task is not None else 0
        return self.read(max(avail, 1), timeout_s)

    def read_buffered(self) -> DaqBlock | None:
        return None  # NI-DAQmx keeps nothing readable after stop

    def samples_clocked_now(self) -> int | None:
        """``in_stream.total_samp_per_chan_acquired``: the samples the device has transferred
        into the task's buffer (behind its clock by what is in transit: never ahead)."""
        if self._task is None:
            return None
        return int(self._task.in_stream.total_samp_per_chan_acquired)

    def stop(self) -> None:
        if self._task is None:
            return
        try:
            self.samples_clocked = int(self._task.in_stream.total_samp_per_chan_acquired)
            self._task.stop()
        finally:
            self._task.close()
            self._task = None
