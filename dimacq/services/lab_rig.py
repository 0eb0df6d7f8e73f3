"""The acquisition rig behind :meth:`dimacq.services.lab.Lab.start_acquisition`.

:class:`Rig` bundles a configured DAQ task, the load cell amplifiers, the channel names of each
input's hammer and of each response, and (in simulation) the virtual operator who strikes.
:func:`build_rig` makes one from the settings: the simulated DAQ (pyusb backend) and load cell
(python-can ``virtual``) fed by the configured virtual-lab scenario, or real devices.
:func:`run_impact_test` runs an :class:`~dimacq.services.acquisition.ImpactSession` on it and
hands every completed average to a callback *as soon as it is decided*, so the caller can make it
durable before the next strike.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from dimacq.config import Settings
from dimacq.errors import DeviceNotFoundError, SetupError
from dimacq.model.frf import Channel, FrfData
from dimacq.model.setup import TestSetup

__all__ = ["Rig", "build_rig", "run_impact_test"]

log = logging.getLogger(__name__)

AverageCallback = Callable[[int, bool, Sequence[str], Mapping[str, NDArray[Any]]], None]
ProgressCallback = Callable[[float, str], None]


@dataclass
class Rig:
    """Devices ready for an impact test.

    Attributes
    ----------
    daq : Daq task (channels and timing configured, not started)
    input_channels : DAQ channel name of the hammer force, per setup excitation (in order)
    response_channels : DAQ channel name per setup response (in order)
    loadcells : amplifiers in the order of ``setup.load_cells``
    operator : callable (input_index, daq_sample), optional (simulation: strikes the virtual lab)
    closers : called in reverse order by :meth:`close`
    """

    daq: Any
    input_channels: list[str]
    response_channels: list[str]
    loadcells: list[Any] = field(default_factory=list)
    operator: Callable[[int, int], None] | None = None
    closers: list[Callable[[], None]] = field(default_factory=list)

    def close(self) -> None:
        while self.closers:
            fn = self.closers.pop()
            try:
                fn()
            except Exception:  # closing must go on for the others
                log.exception("closing part of the acquisition rig failed")


def build_rig(settings: Settings, setup: TestSetup, cfg: Mapping[str, Any]) -> Rig:
    """The rig for ``setup``: simulated from the configured scenario, or the real devices."""
    if not settings.simulated:
        raise DeviceNotFoundError(
            "real DAQ/load cell rigs are not wired into the service in this build; use "
            "daq_backend = 'simulated'"
        )
    try:
        from dimacq.simulators.lab import scenarios  # type: ignore[attr-defined]
    except ImportError as err:
        raise DeviceNotFoundError(
            f"the simulated rig needs the virtual lab's time-domain scenarios "
            f"(dimacq.simulators.lab.scenarios, scenario {settings.scenario!r}), which this build "
            "does not have yet"
        ) from err
    if not hasattr(scenarios, "build_simulated_rig"):
        raise DeviceNotFoundError(
            "dimacq.simulators.lab.scenarios has no build_simulated_rig(); the simulated rig "
            "cannot be assembled in this build"
        )
    parts = scenarios.build_simulated_rig(settings.scenario, setup, seed=int(cfg.get("seed", 0)))
    return Rig(**parts)


def run_impact_test(
    rig: Rig,
    setup: TestSetup,
    cfg: Mapping[str, Any],
    *,
    on_average: AverageCallback,
    on_progress: ProgressCallback,
) -> FrfData:
    """Run the impact test; return FRFs in the setup's channel order (SI units)."""
    from dimacq.services.acquisition import ImpactSession, ImpactSettings, Progress

    if len(rig.input_channels) != len(setup.excitations):
        raise SetupError(
            f"rig has {len(rig.input_channels)} hammer channels for {len(setup.excitations)} inputs"
        )
    if len(rig.response_channels) != len(setup.responses):
        raise SetupError(
            f"rig has {len(rig.response_channels)} response channels for {len(setup.responses)} responses"
        )
    settings = ImpactSettings(
        record_samples=int(cfg.get("record_samples", 2048)),
        pretrigger_samples=int(cfg.get("pretrigger_samples", 32)),
        trigger_level=float(cfg.get("trigger_level_n", 5.0)),
        averages_per_input=int(cfg.get("averages_per_input", 5)),
        force_window_samples=cfg.get("force_window_samples"),
        exponential_tau_s=cfg.get("exponential_tau_s"),
        estimator=cfg.get("estimator", "H1"),
    )
    n_in = len(setup.excitations)
    wanted = settings.averages_per_input

    class Session(ImpactSession):
        def _check(
            self, input_index: int, s0: int, n: int
        ) -> tuple[list[str], dict[str, NDArray[np.float64]]]:
            reasons, rec = super()._check(input_index, s0, n)
            on_average(
                input_index, not reasons, list(reasons), {k: np.asarray(v) for k, v in rec.items()}
            )
            return reasons, rec

    def progress(p: Progress) -> None:
        done = p.input_index * wanted + p.accepted
        on_progress(done / (n_in * wanted), p.message)

    session = Session(
        rig.daq,
        rig.input_channels,
        rig.response_channels,
        rig.loadcells,
        settings=settings,
        operator=rig.operator,
        progress=progress,
    )
    res = session.run()
    outputs = [Channel(c.node, c.direction) for c in setup.responses]
    kinds: list[Any] = ["acceleration"] * len(outputs)
    for lc in setup.load_cells:
        outputs += [Channel(lc.node, k) for k in range(1, 7)]
        kinds += ["reaction"] * 6
    inputs = tuple(Channel(e.node, e.direction) for e in setup.excitations)
    keep = res.frequencies_hz > 0
    return FrfData(
        frequencies_hz=res.frequencies_hz[keep],
        H=res.H[keep],
        outputs=tuple(outputs),
        output_kinds=tuple(kinds),
        inputs=inputs,
        coherence=res.coherence[keep],
        meta={"source": "dimacq impact acquisition"},
    )
