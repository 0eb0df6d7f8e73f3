"""NI DSA devices (cDAQ C Series modules: NI 9234, NI 9237, ...; USB-4431) through the official
``nidaqmx`` Python API.

Written against nidaqmx-python's API (names checked against its source: ``task.ai_channels``
``add_ai_accel_chan`` / ``add_ai_force_iepe_chan`` with internal IEPE current and AC coupling,
``add_ai_bridge_chan`` full bridge in mV/V with internal voltage excitation, ``add_ai_voltage_chan``;
per channel ``ai_remove_filter_delay``, ``ai_filter_delay`` / ``ai_filter_delay_units`` /
``ai_filter_delay_adjustment``; ``timing.cfg_samp_clk_timing`` continuous, read back with
``timing.samp_clk_rate`` after ``control(TaskMode.TASK_COMMIT)``;
``export_signals.samp_clk_output_term``; ``triggers.start_trigger.cfg_dig_edge_start_trig``;
``stream_readers.AnalogMultiChannelReader.read_many_sample``). NI-DAQmx scales the data to m/s²,
N and mV/V itself. **Never run on real hardware by its author**; NI-DAQmx's simulated devices
(NI MAX) are the way to try it without hardware.

The channels are placed by :func:`dimacq.drivers.ni.plan.place` on the modules given
(``ModuleSlot``: device, model, rig inputs, what it offers): a current or excitation the module
does not offer is refused when the channel is added. The rate is NI-DAQmx's, read back from the
committed task whenever it is asked (the plan's rate, where it differs, is logged); a rate that
changes after it was reported (channels added later) refuses the start, so no block or FRF
line is labelled with a rate the modules do not run at. Every channel's input delay is removed by NI-DAQmx
(``ai_remove_filter_delay``), up to NI's published figure (``ai_filter_delay_adjustment``); a
task whose modules' delays differ and cannot be removed is refused.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np

from dimacq.devices.daq import ChannelConfig, DaqBlock, DaqEvent
from dimacq.drivers.daq.driver import STANDARD_GRAVITY
from dimacq.drivers.ni.modules import input_delay_s
from dimacq.drivers.ni.plan import ChannelRequest, ModuleSlot, PlannedChannel, place, task_rate
from dimacq.errors import DeviceError, DeviceStateError, DeviceTimeoutError, SetupError

__all__ = ["NiDsaTask", "NiIdentity"]

log = logging.getLogger(__name__)

#: NI-DAQmx error codes (nidaqmx.error_codes.DAQmxErrors)
_TIMEOUT = -200284  # SAMPLES_NOT_YET_AVAILABLE
_OVERWRITTEN = -200279  # SAMPLES_NO_LONGER_AVAILABLE: the host buffer overflowed
#: a read-back rate differing from the plan's by more than this (relative) is refused
_RATE_TOL = 1e-6
#: channel delays left in the data that differ by more than this (s) refuse the task
_DELAY_TOL_S = 1e-6


@dataclass(frozen=True)
class _IepeChannel:
    """How NI-DAQmx takes one kind of IEPE sensor: the ``task.ai_channels`` method, its units
    and sensitivity units (``(enum, member)`` names of ``nidaqmx.constants``), and our SI unit
    with the size of NI's sensitivity unit in it (mV/g: g₀ m/s²; mV/N: 1 N)."""

    method: str
    units: tuple[str, str]
    sensitivity_units: tuple[str, str]
    si_unit: str
    unit_in_si: float


_IEPE_CHANNELS = {
    "accel": _IepeChannel(
        "add_ai_accel_chan",
        ("AccelUnits", "METERS_PER_SECOND_SQUARED"),
        ("AccelSensitivityUnits", "MILLIVOLTS_PER_G"),
        "m/s^2",
        STANDARD_GRAVITY,
    ),
    "force": _IepeChannel(
        "add_ai_force_iepe_chan",
        ("ForceUnits", "NEWTONS"),
        ("ForceIEPESensorSensitivityUnits", "MILLIVOLTS_PER_NEWTON"),
        "N",
        1.0,
    ),
}


@dataclass(frozen=True)
class NiIdentity:
    model: str
    serial_number: str
    units: tuple[str, ...]
    models: tuple[str, ...] = ()


@dataclass(frozen=True)
class _Chan:
    config: ChannelConfig
    placed: PlannedChannel
    sensitivity: float  # mV/g, mV/N, or 1
    scale: float = 1.0  # data = NI-DAQmx's value x scale (a voltage input read in mV: 1e3)


class NiDsaTask:
    """A :class:`~dimacq.devices.daq.Daq` (and a channel DAQ for load cells on its inputs) on
    NI DSA modules.

    Parameters
    ----------
    nidaqmx : module
        The imported ``nidaqmx`` package (injected).
    slots : sequence of ModuleSlot
        The modules and the rig inputs each carries (``inputs[k]`` is its
        ``ai<k>``), with the IEPE currents and excitation voltages the device offers.
    start_trigger : str
        A digital edge that starts the task (``"/cDAQ1/PFI0"``), or "" (start at once).
    sample_clock_out : str
        A terminal the task's sample clock is exported to (``"/cDAQ1/PFI1"``) for devices that
        sample on it, or "" (not exported).
    """

    def __init__(
        self,
        nidaqmx: Any,
        slots: Sequence[ModuleSlot],
        *,
        start_trigger: str = "",
        sample_clock_out: str = "",
        name: str = "impact",
    ) -> None:
        self._ni = nidaqmx
        self.slots = tuple(slots)
        self.start_trigger = start_trigger
        self.sample_clock_out = sample_clock_out
        self.name = name
        self._chans: dict[int, _Chan] = {}
        self._asked_hz: float | None = None
        self._reported_hz: float | None = None  # the rate told before the task existed
        self._read_back_hz: float | None = None
        self.samples_per_frame = 256
        self.events: list[DaqEvent] = []
        self.samples_clocked: int | None = None
        self._built: Any = None
        self._task: Any = None
        self._reader: Any = None
        self._next = 0
        #: per channel name: (NI-DAQmx's filter delay, the published delay), s, once built
        self.filter_delays_s: dict[str, tuple[float, float | None]] = {}

    @property
    def units(self) -> tuple[str, ...]:
        return tuple(s.device for s in self.slots)

    def identify(self) -> NiIdentity:
        from nidaqmx.system import Device

        dev = Device(self.units[0])
        return NiIdentity(
            str(dev.product_type),
            f"{int(dev.dev_serial_num):X}",
            self.units,
            tuple(s.model for s in self.slots),
        )

    # -- channels ---------------------------------------------------------------------------
    def _add(
        self, req: ChannelRequest, cfg: ChannelConfig, sens: float, scale: float = 1.0
    ) -> None:
        if self._task is not None:
            raise DeviceStateError(f"task {self.name} is running; stop it before adding channels")
        if req.input in self._chans:
            raise SetupError(
                f"physical channel {req.input} is already in task {self.name} as "
                f"{self._chans[req.input].config.name!r}; use another input"
            )
        placed = place(req, self.slots)
        self._drop_built()
        self._chans[req.input] = _Chan(cfg, placed, sens, scale)

    def _add_iepe(
        self,
        kind: Literal["accel", "force"],
        physical_channel: int,
        name: str,
        sensitivity: float,
        range_v: float,
        iepe_current_ma: float,
        coupling: Literal["AC", "DC"],
    ) -> None:
        """An IEPE sensor of ``kind`` with ``sensitivity`` in mV per its unit (g or N, as
        NI-DAQmx takes it); the config in SI: ``v = sensitivity · 10⁻³ / u`` V per m/s² or N,
        ``u`` = g₀ for an accelerometer, 1 for a force sensor."""
        unit, per_si = _IEPE_CHANNELS[kind].si_unit, _IEPE_CHANNELS[kind].unit_in_si
        cfg = ChannelConfig(
            physical_channel, name, unit, sensitivity * 1e-3 / per_si, range_v, 0, coupling
        )
        req = ChannelRequest(
            physical_channel, name, kind, "", iepe_current_ma, None, range_v, coupling
        )
        self._add(req, cfg, sensitivity)

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
        self._add_iepe(
            "accel", physical_channel, name, sensitivity_mv_per_g, range_v, iepe_current_ma,
            coupling,
        )  # fmt: skip

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
        self._add_iepe(
            "force", physical_channel, name, sensitivity_mv_per_n, range_v, iepe_current_ma,
            coupling,
        )  # fmt: skip

    def add_voltage_channel(
        self,
        physical_channel: int,
        name: str,
        *,
        range_v: float = 5.0,
        coupling: Literal["AC", "DC"] = "DC",
    ) -> None:
        cfg = ChannelConfig(physical_channel, name, "V", 1.0, range_v, 0, coupling)
        req = ChannelRequest(physical_channel, name, "voltage", "", 0.0, None, range_v, coupling)
        self._add(req, cfg, 1.0)

    def add_channel(self, config: ChannelConfig) -> None:
        """A channel in the config's own unit: ``"mV/V"`` is a full bridge read in mV/V with
        ``sensitivity_v_per_unit × 1000`` V of excitation (V per mV/V); ``"V"`` and ``"mV"`` a
        voltage input; ``"m/s^2"`` and ``"N"`` an IEPE accelerometer or force sensor.

        Raises
        ------
        SetupError
            Another unit, or what :func:`~dimacq.drivers.ni.plan.place` refuses.
        """
        c = config
        if c.units == "mV/V":
            exc = c.sensitivity_v_per_unit * 1e3
            req = ChannelRequest(
                c.physical_channel, c.name, "bridge", "", 0.0, exc, c.range_v, c.coupling
            )
            self._add(req, c, 1.0)
        elif c.units in ("V", "mV"):
            req = ChannelRequest(
                c.physical_channel, c.name, "voltage", "", 0.0, None, c.range_v, c.coupling
            )
            self._add(req, c, 1.0, 1.0 / c.sensitivity_v_per_unit)
        elif kind := next((k for k, v in _IEPE_CHANNELS.items() if v.si_unit == c.units), None):
            self._add_iepe(
                kind,  # type: ignore[arg-type]
                c.physical_channel,
                c.name,
                c.sensitivity_v_per_unit * _IEPE_CHANNELS[kind].unit_in_si * 1e3,
                c.range_v,
                c.iepe_current_ua * 1e-3,
                c.coupling,
            )
        else:
            raise SetupError(
                f"channel {c.name}: unit {c.units!r}; an NI task reads 'mV/V' (bridge), 'V', "
                "'mV', 'm/s^2' or 'N'"
            )

    @property
    def channels(self) -> tuple[ChannelConfig, ...]:
        return tuple(self._chans[k].config for k in sorted(self._chans))

    @property
    def channel_names(self) -> tuple[str, ...]:
        return tuple(c.name for c in self.channels)

    @property
    def planned(self) -> tuple[PlannedChannel, ...]:
        return tuple(self._chans[k].placed for k in sorted(self._chans))

    @property
    def running(self) -> bool:
        return self._task is not None

    # -- timing -----------------------------------------------------------------------------
    def configure_timing(self, sample_rate_hz: float, samples_per_frame: int = 256) -> None:
        if sample_rate_hz <= 0 or samples_per_frame <= 0:
            raise SetupError(
                f"[daq] sample_rate_hz = {sample_rate_hz}, samples_per_frame = "
                f"{samples_per_frame}: give positive values"
            )
        self._drop_built()
        self._asked_hz = float(sample_rate_hz)
        self.samples_per_frame = int(samples_per_frame)

    def _used_slots(self) -> list[ModuleSlot]:
        used: list[ModuleSlot] = []
        for c in self.planned:
            if c.slot not in used:
                used.append(c.slot)
        return used

    @property
    def sample_rate_hz(self) -> float | None:
        """The rate the modules run at, Hz: NI-DAQmx's ``timing.samp_clk_rate`` read back (the
        task is built and committed, not started, to ask it); without the driver (``nidaqmx``
        None: a plan) the plan's; None before ``configure_timing``."""
        if self._read_back_hz is not None:
            return self._read_back_hz
        if self._asked_hz is None or not self._chans:
            return self._asked_hz
        if self._ni is None:
            rate, _fm, _m = task_rate(self._used_slots(), self._asked_hz)
            return rate
        self._build()
        self._reported_hz = self._read_back_hz
        return self._read_back_hz

    @sample_rate_hz.setter
    def sample_rate_hz(self, value: float | None) -> None:
        if value is None:
            self._drop_built()
            self._asked_hz = None
        else:
            self.configure_timing(value, self.samples_per_frame)

    # -- the NI-DAQmx task ------------------------------------------------------------------
    def _drop_built(self) -> None:
        if self._built is not None:
            self._built.close()
        self._built = None
        self._read_back_hz = None

    def _add_to(self, task: Any, ch: _Chan) -> Any:
        from nidaqmx import constants as c

        cfg, pc = ch.config, ch.placed
        phys = pc.physical
        if pc.request.kind == "bridge":
            assert pc.excitation_v is not None
            full = cfg.range_v / cfg.sensitivity_v_per_unit  # ± mV/V
            return task.ai_channels.add_ai_bridge_chan(
                phys,
                cfg.name,
                min_val=-full,
                max_val=full,
                units=c.BridgeUnits.MILLIVOLTS_PER_VOLT,
                bridge_config=c.BridgeConfiguration.FULL_BRIDGE,
                voltage_excit_source=c.ExcitationSource.INTERNAL,
                voltage_excit_val=pc.excitation_v,
            )
        full = cfg.range_v / cfg.sensitivity_v_per_unit  # ± full scale, units
        excite = c.ExcitationSource.INTERNAL if pc.iepe_current_a > 0 else c.ExcitationSource.NONE
        iepe = _IEPE_CHANNELS.get(pc.request.kind)
        if iepe is not None:
            units_enum, units_name = iepe.units
            sens_enum, sens_name = iepe.sensitivity_units
            ai = getattr(task.ai_channels, iepe.method)(
                phys,
                cfg.name,
                min_val=-full,
                max_val=full,
                units=getattr(getattr(c, units_enum), units_name),
                sensitivity=ch.sensitivity,
                sensitivity_units=getattr(getattr(c, sens_enum), sens_name),
                current_excit_source=excite,
                current_excit_val=pc.iepe_current_a,
            )
        else:
            ai = task.ai_channels.add_ai_voltage_chan(
                phys, cfg.name, min_val=-cfg.range_v, max_val=cfg.range_v
            )
        ai.ai_coupling = c.Coupling.AC if cfg.coupling == "AC" else c.Coupling.DC
        return ai

    def _build(self) -> Any:
        """Create and commit the NI-DAQmx task (not started): channels, delay removal, timing,
        the sample clock's export; read the rate back."""
        from nidaqmx import constants as c

        if self._built is not None:
            return self._built
        if not self._chans or self._asked_hz is None:
            raise SetupError(f"task {self.name}: add channels and configure_timing() first")
        err_t = self._ni.errors.DaqError
        task = self._ni.Task(self.name)
        try:
            ais: dict[int, Any] = {}
            kept: dict[int, str] = {}  # inputs whose delay NI-DAQmx does not remove: why
            for k in sorted(self._chans):
                ai = self._add_to(task, self._chans[k])
                ais[k] = ai
                try:
                    ai.ai_filter_delay_units = c.DigitalWidthUnits.SECONDS
                    ai.ai_remove_filter_delay = True
                except err_t as err:
                    kept[k] = str(err).splitlines()[0]
            task.timing.cfg_samp_clk_timing(
                self._asked_hz,
                sample_mode=c.AcquisitionType.CONTINUOUS,
                samps_per_chan=max(int(self._asked_hz * 10), 4 * self.samples_per_frame),
            )
            if self.sample_clock_out:
                task.export_signals.samp_clk_output_term = self.sample_clock_out
            if self.start_trigger:
                task.triggers.start_trigger.cfg_dig_edge_start_trig(self.start_trigger)
            task.control(c.TaskMode.TASK_COMMIT)
            rate = float(task.timing.samp_clk_rate)
            self._compensate(task, ais, kept, rate)
            self._check_plan(rate)
        except err_t as err:
            task.close()
            raise SetupError(f"task {self.name}: NI-DAQmx refused the set-up: {err}") from err
        except SetupError:
            task.close()
            raise
        self._built = task
        self._read_back_hz = rate
        return task

    def _compensate(
        self, task: Any, ais: dict[int, Any], kept: dict[int, str], rate: float
    ) -> None:
        """Remove the rest of each channel's published input delay (``ai_filter_delay_adjustment``
        = published - NI-DAQmx's filter delay); refuse delays left in the data that differ."""
        from nidaqmx import constants as c

        self.filter_delays_s = {}
        left: dict[int, float] = {}
        for k, ai in ais.items():
            ch = self._chans[k]
            spec = ch.placed.slot.spec
            published = input_delay_s(spec, rate) if spec is not None else None
            daqmx = float(ai.ai_filter_delay)
            self.filter_delays_s[ch.config.name] = (daqmx, published)
            if k in kept:
                left[k] = published if published is not None else daqmx
            elif published is not None and abs(published - daqmx) > 0:
                ai.ai_filter_delay_adjustment = published - daqmx
                log.info(
                    "task %s: %s (%s) input delay %.6g ms published, NI-DAQmx's filter delay "
                    "%.6g ms: %.4g us adjusted",
                    self.name,
                    ch.placed.physical,
                    ch.placed.slot.model,
                    published * 1e3,
                    daqmx * 1e3,
                    (published - daqmx) * 1e6,
                )
        if left and (
            len(left) < len(ais) or max(left.values()) - min(left.values()) > _DELAY_TOL_S
        ):
            k = max(left, key=lambda j: left[j])
            ch = self._chans[k]
            raise SetupError(
                f"task {self.name}: NI-DAQmx does not remove the filter delay of "
                f"{ch.placed.physical} ({ch.placed.slot.model}: {kept[k]}); its "
                f"{left[k] * 1e3:.4g} ms would differ from the other channels' and turn the FRF "
                "phases: put these inputs on modules whose delay NI-DAQmx removes"
            )
        task.control(c.TaskMode.TASK_COMMIT)

    def _check_plan(self, rate: float) -> None:
        """Log where NI-DAQmx's rate is not the plan's (the plan's timebase was not the one
        NI-DAQmx shares): the read-back is what is used."""
        assert self._asked_hz is not None
        try:
            planned, _fm, master = task_rate(self._used_slots(), self._asked_hz)
        except SetupError:
            return
        if abs(rate - planned) > _RATE_TOL * planned:
            log.warning(
                "task %s: NI-DAQmx runs the modules at %.6g Hz where the plan (%s's timebase) "
                "said %.6g Hz for %g Hz asked; %.6g Hz is used",
                self.name,
                rate,
                master.device,
                planned,
                self._asked_hz,
                rate,
            )

    def start(self) -> None:
        """Build the task if not built (channels, delays, timing, clock export, trigger), check
        its rate against the one told before, start."""
        from nidaqmx.stream_readers import AnalogMultiChannelReader

        if self._task is not None:
            raise DeviceStateError(f"task {self.name} is already running")
        task = self._build()
        rate = self._read_back_hz
        assert rate is not None
        told = self._reported_hz
        if told is not None and abs(rate - told) > _RATE_TOL * told:
            self._drop_built()
            raise SetupError(
                f"task {self.name}: NI-DAQmx runs the modules at {rate:.6g} Hz, but {told:.6g} Hz "
                "was reported before channels or timing changed; configure every channel before "
                "the rate is read, then start"
            )
        try:
            task.start()
        except self._ni.errors.DaqError as err:
            self._drop_built()
            raise SetupError(f"task {self.name}: NI-DAQmx refused to start: {err}") from err
        log.info(
            "task %s: %d channels at %.6g Hz (asked %g)",
            self.name,
            len(self._chans),
            rate,
            self._asked_hz,
        )
        self._task = task
        self._built = None
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
        scale = np.array([self._chans[k].scale for k in sorted(self._chans)])
        if np.any(scale != 1.0):
            data *= scale[:, None]
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

    def close(self) -> None:
        """Stop, and release the NI-DAQmx task built to read the rate back (it reserves the
        modules until closed)."""
        self.stop()
        self._drop_built()

    def stop(self) -> None:
        if self._task is None:
            return
        try:
            self.samples_clocked = int(self._task.in_stream.total_samp_per_chan_acquired)
            self._task.stop()
        finally:
            self._task.close()
            self._task = None
