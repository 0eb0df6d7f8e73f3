"""A second DAQ kind, for the test that adding one is one backend entry and one driver module.

``PanelDaq`` is the driver of a (fictitious) fixed-range panel DAQ: ±5 V on every input, 24-bit
codes, blocks pulled from its device by sample counter. It implements
:class:`dimacq.devices.daq.Daq` and nothing in ``dimacq`` knows it: the settings name its
factory, ``daq = "_second_daq:open_daq"``, and the one rig builder opens it from the table.

The device behind it is the acquisition tests' closed-form impulse lab
(:class:`_acq_support.ImpulseSource`: two inputs, three responses, FRFs known exactly), cabled
as the rig file says (input ``k`` of the source on ``physical_channel`` ``k``), with true
sensitivities of :data:`HAMMER_MV_PER_N` and :data:`ACCEL_MV_PER_G`; its own hand strikes when the
session asks (``ctx.operator``), so a service in another process can acquire with it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
from _acq_support import ImpulseSource

from dimacq.backends.base import DeviceContext
from dimacq.devices.daq import ChannelConfig, DaqBlock, DaqEvent
from dimacq.errors import DeviceStateError, SetupError
from dimacq.model.frf import STANDARD_GRAVITY

HAMMER_MV_PER_N = 2.25
ACCEL_MV_PER_G = 100.0
RANGE_V = 5.0
_LSB_V = 2 * RANGE_V / 2**24


@dataclass(frozen=True)
class PanelIdentity:
    model: str
    serial_number: str
    n_inputs: int


class PanelDevice:
    """The panel DAQ's hardware: its source's channels in volts on its inputs."""

    n_inputs = 8

    def __init__(self, source: ImpulseSource, wiring: dict[int, tuple[int, float]]) -> None:
        self.source = source
        self.wiring = wiring  # physical input → (source channel, true V per unit)

    def read_volts(self, inputs: list[int], start: int, n: int) -> np.ndarray:
        out = np.zeros((len(inputs), n))
        wired = [(row, *self.wiring[ch]) for row, ch in enumerate(inputs) if ch in self.wiring]
        if wired:
            data = self.source.read(np.array([w[1] for w in wired]), start, n)
            for (row, _src, v_per_unit), x in zip(wired, data, strict=True):
                out[row] = x * v_per_unit
        codes = np.clip(np.round(out / _LSB_V), -(2**23), 2**23 - 1)
        return codes * _LSB_V


class PanelDaq:
    """Driver of the panel DAQ (implements :class:`dimacq.devices.daq.Daq`)."""

    def __init__(self, device: PanelDevice) -> None:
        self.device = device
        self.sample_rate_hz: float | None = None
        self.events: list[DaqEvent] = []
        self._channels: list[ChannelConfig] = []
        self._running = False
        self._next = 0
        #: its clock runs only when pulled, so what it clocked is what was read
        self.samples_clocked: int | None = None

    @property
    def channel_names(self) -> tuple[str, ...]:
        return tuple(c.name for c in self._channels)

    @property
    def running(self) -> bool:
        return self._running

    def identify(self) -> PanelIdentity:
        return PanelIdentity("panel DAQ", "PANEL-0001", self.device.n_inputs)

    def _add(self, ch: int, name: str, units: str, v_per_unit: float, range_v: float) -> None:
        if not 0 <= ch < self.device.n_inputs:
            raise SetupError(f"input {ch} is not 0..{self.device.n_inputs - 1} of the panel DAQ")
        if abs(range_v - RANGE_V) > 1e-9:
            raise SetupError(f"range ±{range_v} V is not supported; the panel DAQ has ±5.0 V only")
        self._channels.append(ChannelConfig(ch, name, units, v_per_unit, range_v))

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
        self._add(physical_channel, name, "m/s^2", v, range_v)

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
        self._add(physical_channel, name, "N", sensitivity_mv_per_n * 1e-3, range_v)

    def configure_timing(self, sample_rate_hz: float, samples_per_frame: int = 256) -> None:
        if sample_rate_hz != self.device.source.sample_rate_hz:
            raise SetupError(
                f"sample rate {sample_rate_hz:g} Hz: the panel DAQ runs at "
                f"{self.device.source.sample_rate_hz:g} Hz only"
            )
        self.sample_rate_hz = sample_rate_hz

    def start(self) -> None:
        if self.sample_rate_hz is None or not self._channels:
            raise DeviceStateError("panel DAQ: add channels and configure the timing first")
        self._running, self._next = True, 0
        self.samples_clocked = None

    def stop(self) -> None:
        self._running = False
        self.samples_clocked = self._next

    def read(self, n_samples: int, timeout_s: float | None = None) -> DaqBlock:
        assert self.sample_rate_hz is not None
        first = self._next
        volts = self.device.read_volts(
            [c.physical_channel for c in self._channels], first, n_samples
        )
        scale = np.array([c.sensitivity_v_per_unit for c in self._channels])[:, None]
        self._next += n_samples
        return DaqBlock(
            first_sample=first,
            sample_rate_hz=self.sample_rate_hz,
            channel_names=self.channel_names,
            units=tuple(c.units for c in self._channels),
            data=volts / scale,
            overload=np.abs(volts) >= RANGE_V - _LSB_V,
            valid=np.ones(n_samples, bool),
        )

    def read_available(self, timeout_s: float | None = None) -> DaqBlock:
        return self.read(256, timeout_s)

    def read_buffered(self) -> DaqBlock | None:
        return None

    def samples_clocked_now(self) -> int | None:
        return None  # a plug-in that cannot say: the session searches from what it has read


def open_daq(ctx: DeviceContext) -> PanelDaq:
    """The backend factory the settings name (``daq = "_second_daq:open_daq"``)."""
    source = ImpulseSource(n_inputs=2, n_responses=3, response_gain=0.01)
    rf = ctx.rig_file
    wiring = {h.physical_channel: (h.physical_channel, HAMMER_MV_PER_N * 1e-3) for h in rf.hammers}
    for r in rf.responses:
        wiring[r.physical_channel] = (r.physical_channel, ACCEL_MV_PER_G * 1e-3 / STANDARD_GRAVITY)
    daq = PanelDaq(PanelDevice(source, wiring))
    if ctx.setup is not None:
        ctx.operator = lambda j, daq_sample: source.excite(j, daq_sample)
    return daq
