"""NI C Series modules as NI publishes them: channels, data rates, input delay, excitation.

Pure: no ``nidaqmx`` import, no device. What a plan of a cDAQ task needs before any hardware is
there (:mod:`dimacq.drivers.ni.plan`), and what the task checks the device's own answers against.

Published figures (the sources are cited per entry in :data:`CATALOGUE`):

- **Data rates** of a delta-sigma module: ``fs = (fM / 256) / n``, ``n = 1 .. 31``, ``fM`` the
  master timebase (NI 9234: 13.1072 MHz internal, 51.2 kS/s .. 1.652 kS/s; NI 9237: 12.8 MHz
  internal, 50 kS/s .. 1.613 kS/s). A rate between two of them is coerced **up** to the next
  one (NI KB kA00Z0000004A0YSAU). Modules sampled together share one master timebase: a 9234
  slaved to a 9237's timebase runs at most 50 kS/s (NI CompactRIO manual, "NI 9234 maximum
  sample rate when synchronizing multiple modules"). In a task with an NI 9234, NI 9233 and
  NI 9237 modules run at the NI 9234's rates by default (NI KB "Valid Sampling Rates for the
  NI 9233, NI 9234, and NI 9237", digital.ni.com/public.nsf/allkb/593CC07F76B1405A862570DE005F6836):
  :attr:`ModuleSpec.leads_mixed_task`.
- **Input delay** (the digital filter's delay plus the analogue front end's):
  ``tau = D / fs + t_a``; NI 9237: ``D = 40 + 5/512``, ``t_a = 4.5 µs`` (NI KB
  kA00Z0000004A0YSAU, "Calculate the Input Delay on NI-9237"); NI 9234: ``D = 38.4``,
  ``t_a = 3 µs`` (NI 9234 Operating Instructions and Specifications, "Input delay"; the
  figure was not found in the text searched for this module: check it in your module's
  manual, the task compares it with NI-DAQmx's ``ai_filter_delay`` at start).
- **Input range** of the NI 9234: ±5 V (NI 9144 User Guide, "NI 9234 Calibration Data").
- **IEPE current** of the NI 9234: 2 mA, on or off, AC coupling only (NI 9234 Operating
  Instructions and Specifications, Figure 4 "Input Circuitry for One Channel": "2 mA IEPE
  on/off"; NI USB-9234 User Guide, "NI USB-9234 Circuitry").
- **Bridge excitation** of the NI 9237: internal 2.0, 2.5, 3.3 or 5.0 V (NI 9237 Operating
  Instructions and Specifications, "Excitation"; on a live system the values NI-DAQmx reports
  for the device, ``Device.ai_voltage_int_excit_discrete_vals``, are the ones used).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

from dimacq.errors import SetupError

__all__ = [
    "CATALOGUE",
    "ModuleSpec",
    "coerce_rate",
    "input_delay_s",
    "module_spec",
]

Kind = Literal["iepe", "bridge"]


@dataclass(frozen=True)
class ModuleSpec:
    """One C Series module model as its manual describes it.

    Attributes
    ----------
    model : str
        NI-DAQmx's product type, e.g. ``"NI 9234"``.
    kind : ``"iepe"`` (accelerometers, hammers, voltages) or ``"bridge"`` (strain gauges)
    n_channels : int
    timebase_hz : float
        Internal master timebase ``fM``, Hz.
    ext_rate_range_hz : (float, float)
        Data rates allowed on another module's timebase, Hz (min, max).
    n_max : int
        Largest divisor ``n`` of ``fs = fM / 256 / n``.
    delay_samples : float
        ``D`` of the input delay ``tau = D / fs + t_a``, in sample periods.
    analog_delay_s : float
        ``t_a``, s.
    iepe_currents_a : tuple of float
        IEPE currents offered (besides off), A; () for none.
    excitation_v : tuple of float
        Internal bridge excitation voltages offered, V; () for none.
    range_v : float or None
        Input range ±V of a voltage/IEPE module (None: not a voltage input).
    sources : str
        Where the figures come from.
    leads_mixed_task : bool
        Its timebase is the task's when it shares a task with modules of another timebase
        (NI's default), whatever the order of the channels.
    """

    model: str
    kind: Kind
    n_channels: int
    timebase_hz: float
    ext_rate_range_hz: tuple[float, float]
    n_max: int
    delay_samples: float
    analog_delay_s: float
    iepe_currents_a: tuple[float, ...]
    excitation_v: tuple[float, ...]
    sources: str
    range_v: float | None = None
    leads_mixed_task: bool = False

    @property
    def max_rate_hz(self) -> float:
        """``fM / 256``: the highest rate on its own timebase, Hz."""
        return self.timebase_hz / 256.0


#: The modules of the thesis's set-up bought from NI's catalogue.
CATALOGUE: dict[str, ModuleSpec] = {
    "NI 9234": ModuleSpec(
        model="NI 9234",
        kind="iepe",
        n_channels=4,
        timebase_hz=13.1072e6,
        ext_rate_range_hz=(391.0, 52734.0),
        n_max=31,
        delay_samples=38.4,
        analog_delay_s=3e-6,
        iepe_currents_a=(2e-3,),
        excitation_v=(),
        sources=(
            "NI-9234 Specifications (ni.com/docs, ni-9234-specs): fM 13.1072 MHz, data rate "
            "1.652 kS/s .. 51.2 kS/s internal, 0.391 .. 52.734 kS/s external timebase; NI USB-9234 "
            "User Guide: fs = (fM/256)/n, n = 1..31; NI 9234 Operating Instructions, Figure 4: "
            "2 mA IEPE on/off; input delay 38.4/fs + 3 us (the module's manual); NI 9144 User "
            "Guide, 'NI 9234 Calibration Data': nominal range ±5 V; NI KB 'Valid Sampling "
            "Rates for the NI 9233, NI 9234, and NI 9237': a 9237 in a task with a 9234 runs at "
            "the 9234's rates by default"
        ),
        range_v=5.0,
        leads_mixed_task=True,
    ),
    "NI 9237": ModuleSpec(
        model="NI 9237",
        kind="bridge",
        n_channels=4,
        timebase_hz=12.8e6,
        ext_rate_range_hz=(391.0, 52734.0),
        n_max=31,
        delay_samples=40.0 + 5.0 / 512.0,
        analog_delay_s=4.5e-6,
        iepe_currents_a=(),
        excitation_v=(2.0, 2.5, 3.3, 5.0),
        sources=(
            "NI KB kA00Z0000004A0YSAU 'Calculate the Input Delay on NI-9237': fs = (fM/256)/n, "
            "n = 1..31, fM 12.8 MHz internal, coerced up to the next rate; input delay = "
            "(40 + 5/512)/fs + 4.5 us; NI 9144 User Guide, 'NI 9237 Example Data Rates' (data "
            "rate 391 S/s .. 52.734 kS/s on an external clock); internal excitation 2.0, 2.5, "
            "3.3, 5.0 V (the module's manual)"
        ),
    ),
}


def module_spec(model: str) -> ModuleSpec | None:
    """The catalogue entry of ``model`` (``"NI 9234"``, ``"NI-9234"``, ``"ni9234"``), or None."""
    key = "".join(ch for ch in model.upper() if ch.isalnum())
    for name, spec in CATALOGUE.items():
        if "".join(ch for ch in name.upper() if ch.isalnum()) == key:
            return spec
    return None


def coerce_rate(
    spec: ModuleSpec, asked_hz: float, timebase_hz: float | None = None
) -> tuple[float, int]:
    """The data rate a module runs at when ``asked_hz`` is asked, and its divisor.

    .. math:: f_s = \\frac{f_M}{256\\,n}, \\quad
              n = \\min\\left(n_{max}, \\left\\lfloor \\frac{f_M}{256\\, f_{asked}} \\right\\rfloor
              \\right)

    the largest rate ``>= asked`` (NI coerces up to the next rate; below the lowest rate the
    lowest is used).

    Parameters
    ----------
    spec : ModuleSpec
    asked_hz : float
        The rig's rate, Hz.
    timebase_hz : float, optional
        The shared master timebase ``fM`` (another module's); default the module's own.

    Raises
    ------
    SetupError
        ``asked_hz`` above the module's highest rate, or a timebase that takes the module out of
        its external data-rate range.
    """
    fm = spec.timebase_hz if timebase_hz is None else timebase_hz
    top = fm / 256.0
    lo, hi = spec.ext_rate_range_hz
    if timebase_hz is not None and timebase_hz != spec.timebase_hz and top > hi * (1 + 1e-9):
        raise SetupError(
            f"{spec.model} on a {fm / 1e6:g} MHz timebase would run above its "
            f"{hi / 1e3:g} kS/s; share a timebase it accepts"
        )
    if asked_hz > top * (1 + 1e-12):
        raise SetupError(
            f"sample_rate_hz = {asked_hz:g} Hz: the {spec.model} runs at most {top:g} Hz on a "
            f"{fm / 1e6:g} MHz timebase; ask {top:g} Hz or less"
        )
    n = max(1, min(spec.n_max, math.floor(top / asked_hz * (1 + 1e-12))))
    rate = top / n
    if timebase_hz is not None and timebase_hz != spec.timebase_hz and rate < lo:
        raise SetupError(
            f"{spec.model} on a {fm / 1e6:g} MHz timebase: {rate:g} Hz is below its "
            f"{lo:g} Hz; ask a higher sample_rate_hz"
        )
    return rate, n


def input_delay_s(spec: ModuleSpec, rate_hz: float) -> float:
    """NI's published input delay of the module at data rate ``rate_hz``, s.

    .. math:: \\tau = D / f_s + t_a
    """
    return spec.delay_samples / rate_hz + spec.analog_delay_s
