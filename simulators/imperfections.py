"""The imperfections of real devices that the simulated lab plays by default.

A real rig is not kind: its DAQ clock runs in wall time whether the host reads or not, and its
device FIFO overflows when the host is late; frames of the previous run wait in that FIFO at the
next START; the load cell amplifiers' oscillators are crystals off by tens of ppm; CAN frames are
lost and a node goes bus-off; the digitizer's serial line picks up noise and its USB-serial
adapter drops off; USB transfers time out and a device re-enumerates. :class:`Imperfections`
holds the rate or size of each; :class:`~dimacq.simulators.daq.backend.VirtualDaqBackend`,
:class:`~dimacq.simulators.loadcell.amplifier.LoadCellAmplifierSim` and
:class:`~dimacq.simulators.digitizer.device.SimulatedDigitizer` inject them at random (one
:class:`numpy.random.Generator` each, seeded) and log every fault they inject at WARNING as
``simulated fault <kind>: ...`` (the soak counts them: ``tests/scripts/soak.py``).

Defaults (:data:`DEFAULT`) are realistic and such that a simulated test still passes: the drivers
and the acquisition session survive them (averages hit by a fault are rejected and struck again).
The simulated lab runs ``daq_time_scale`` times faster than real time (a time-lapse: 240 s of
impact test in the demo would otherwise take 4 minutes; the host must keep
up with 4× the real data rate); 1 is a real DAQ. ``dimacq demo`` and ``dimacq acquire`` measure
at start what the host sustains and set the factor unless the setting gives one
(:mod:`dimacq.backends.time_lapse`). The service setting
``simulation_imperfections`` overrides any field (``{}``: the defaults; ``{enabled = false}``:
none, the kind simulators of before).

=========================== ======================================= ================================
field                        what                                    default
=========================== ======================================= ================================
daq_free_running             the DAQ clocks in wall time             true
daq_time_scale               simulated seconds per wall second       4
daq_adaptive_time_lapse      the time-lapse slows down (never below  true
                             0.25x) when the host falls behind,
                             instead of overflowing the FIFO
daq_fifo_bytes               device FIFO, 0: unbounded (host late:   4 MiB (19 s of the demo's 25
                             overflow)                               channels, 4.7 s wall at 4×)
daq_stale_frames             START keeps the previous run's frames   true
daq_stall_rate               per bulk read: the device NAKs a while  0.002
daq_stall_s                  how long (≥ the USB timeout: a timeout) 0.25 s
daq_reenumerate_rate         per bulk read: re-enumerates (new addr) 0
daq_reenumerate_s            how long it is off the bus              0.5 s
loadcell_oscillator_ppm      each amplifier's crystal within ±       50 ppm
can_frame_loss_rate          per CAN frame sent by an amplifier      1e-6
can_bus_off_rate             per second of streaming, per amplifier  0
can_bus_off_s                until the node has recovered            0.1 s
digitizer_noise_rate         per reply line: noise, bad checksum     0.01
digitizer_port_loss_rate     per command: the port drops off         0.002
digitizer_port_loss_s        until it is back                        0.3 s
=========================== ======================================= ================================

Re-enumeration and bus-off are off by default (0) in scenarios: they cost a restart of the run
(the average in progress is lost and struck again); the soak turns them on.
"""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from dimacq.errors import SetupError

__all__ = ["DEFAULT", "NONE", "Imperfections", "fault_log"]

#: the logger every simulator logs its injected faults to (``simulated fault <kind>: ...``)
fault_log = logging.getLogger("dimacq.simulators.faults")


@dataclass(frozen=True)
class Imperfections:
    """Rates and sizes of the simulated devices' imperfections (see the module docstring)."""

    enabled: bool = True
    daq_free_running: bool = True
    daq_time_scale: float = 4.0
    daq_adaptive_time_lapse: bool = True
    daq_fifo_bytes: int = 4 << 20
    daq_stale_frames: bool = True
    daq_stall_rate: float = 0.002
    daq_stall_s: float = 0.25
    daq_reenumerate_rate: float = 0.0
    daq_reenumerate_s: float = 0.5
    loadcell_oscillator_ppm: float = 50.0
    can_frame_loss_rate: float = 1e-6
    can_bus_off_rate: float = 0.0
    can_bus_off_s: float = 0.1
    digitizer_noise_rate: float = 0.01
    digitizer_port_loss_rate: float = 0.002
    digitizer_port_loss_s: float = 0.3

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):
            v = getattr(self, f.name)
            if isinstance(v, bool):
                continue
            if not (isinstance(v, int | float) and v == v and v >= 0 and v != float("inf")):
                raise SetupError(
                    f"simulation_imperfections.{f.name} = {v!r}: give a finite number ≥ 0"
                )
            if f.name.endswith("_rate") and v > 1:
                raise SetupError(
                    f"simulation_imperfections.{f.name} = {v!r}: a probability, give 0 .. 1"
                )
        if self.daq_time_scale <= 0:
            raise SetupError(
                f"simulation_imperfections.daq_time_scale = {self.daq_time_scale}: give a "
                "positive factor (1: real time)"
            )

    @classmethod
    def from_mapping(cls, values: Mapping[str, Any]) -> Imperfections:
        """The defaults with ``values`` over them; ``enabled = false``: none at all.

        Raises
        ------
        SetupError
            An unknown key or a value out of range, named.
        """
        names = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(values) - names)
        if unknown:
            raise SetupError(
                f"simulation_imperfections: unknown key(s) {unknown}; use {sorted(names)}"
            )
        base = DEFAULT if values.get("enabled", True) else NONE
        try:
            return dataclasses.replace(base, **dict(values))
        except TypeError as err:  # pragma: no cover - names are checked above
            raise SetupError(f"simulation_imperfections: {err}") from err


#: the defaults of every scenario
DEFAULT = Imperfections()
#: a kind world: the DAQ clocks as the host reads, nothing is lost, no noise
NONE = Imperfections(
    enabled=False,
    daq_free_running=False,
    daq_time_scale=1.0,
    daq_adaptive_time_lapse=False,
    daq_fifo_bytes=0,
    daq_stale_frames=False,
    daq_stall_rate=0.0,
    loadcell_oscillator_ppm=0.0,
    can_frame_loss_rate=0.0,
    digitizer_noise_rate=0.0,
    digitizer_port_loss_rate=0.0,
)
