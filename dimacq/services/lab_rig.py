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
    defaults : impact settings used where the request leaves a value out (None)
    fixed : impact settings the rig imposes (e.g. how far ahead the simulated lab can be struck)
    """

    daq: Any
    input_channels: list[str]
    response_channels: list[str]
    loadcells: list[Any] = field(default_factory=list)
    operator: Callable[[int, int], None] | None = None
    closers: list[Callable[[], None]] = field(default_factory=list)
    defaults: dict[str, Any] = field(default_factory=dict)
    fixed: dict[str, Any] = field(default_factory=dict)

    def close(self) -> None:
        while self.closers:
            fn = self.closers.pop()
            try:
                fn()
            except Exception:  # closing must go on for the others
                log.exception("closing part of the acquisition rig failed")


def build_rig(settings: Settings, setup: TestSetup, cfg: Mapping[str, Any]) -> Rig:
    """The rig for ``setup``: the configured virtual-lab scenario behind the simulated USB DAQ and
    CAN FD load cells (:class:`dimacq.services.simulated_lab.SimulatedRig`, real drivers), or
    real devices.

    The service's setup (e.g. built from digitized geometry) is matched to the scenario's article
    channel by channel (node and direction); the virtual operator strikes the article's input
    that the session asks for.
    """
    if not settings.simulated:
        raise DeviceNotFoundError(
            "real DAQ/load cell rigs are not wired into the service in this build; use "
            "daq_backend = 'simulated'"
        )
    from dimacq.services.simulated_lab import SimulatedRig
    from dimacq.simulators.lab.impact import virtual_lab
    from dimacq.simulators.lab.scenarios import build_scenario

    seed = cfg.get("seed")
    built = build_scenario(settings.scenario, None if seed is None else int(seed))
    lab = virtual_lab(built)
    true = lab.model.setup
    resp = {(c.node, c.direction): i for i, c in enumerate(true.responses)}
    inp = {(e.node, e.direction): i for i, e in enumerate(true.excitations)}
    cells = {lc.node: i for i, lc in enumerate(true.load_cells)}
    missing = [c.name for c in setup.responses if (c.node, c.direction) not in resp]
    missing += [e.name for e in setup.excitations if (e.node, e.direction) not in inp]
    missing += [lc.name for lc in setup.load_cells if lc.node not in cells]
    if missing:
        raise SetupError(
            f"setup channels {missing} are not instrumented in scenario {settings.scenario!r}; "
            "use the scenario's node numbers (see dimacq simulate --list)"
        )
    rig = SimulatedRig(lab)
    in_index = [inp[(e.node, e.direction)] for e in setup.excitations]

    def operator(j: int, daq_sample: int) -> None:
        rig.strike(in_index[j], daq_sample)

    acq = built.spec.acquisition
    return Rig(
        daq=rig.task,
        input_channels=["hammer"] * len(setup.excitations),
        response_channels=[
            rig.response_channels[resp[(c.node, c.direction)]] for c in setup.responses
        ],
        loadcells=[rig.loadcells[cells[lc.node]] for lc in setup.load_cells],
        operator=operator,
        closers=[rig.close],
        defaults={
            "record_samples": acq.record_samples,
            "pretrigger_samples": acq.pretrigger_samples,
            "averages_per_input": acq.averages,
            "exponential_tau_s": acq.exponential_tau_s,
            "force_window_samples": 64,
        },
        fixed={"hit_delay_samples": lab.block_samples, "block_samples": 512},
    )


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

    def value(key: str, fallback: Any) -> Any:
        v = cfg.get(key)
        return rig.defaults.get(key, fallback) if v is None else v

    settings = ImpactSettings(
        record_samples=int(value("record_samples", 2048)),
        pretrigger_samples=int(value("pretrigger_samples", 32)),
        trigger_level=float(value("trigger_level_n", 5.0)),
        averages_per_input=int(value("averages_per_input", 5)),
        force_window_samples=value("force_window_samples", None),
        exponential_tau_s=value("exponential_tau_s", None),
        estimator=value("estimator", "H1"),
        **rig.fixed,
    )
    n_in = len(setup.excitations)
    wanted = settings.averages_per_input

    def decided(
        input_index: int,
        _average_index: int,
        accepted: bool,
        reasons: Sequence[str],
        blocks: Mapping[str, NDArray[np.float64]],
    ) -> None:
        on_average(
            input_index, accepted, list(reasons), {k: np.asarray(v) for k, v in blocks.items()}
        )

    def progress(p: Progress) -> None:
        done = p.input_index * wanted + p.accepted
        on_progress(done / (n_in * wanted), p.message)

    session = ImpactSession(
        rig.daq,
        rig.input_channels,
        rig.response_channels,
        rig.loadcells,
        settings=settings,
        operator=rig.operator,
        progress=progress,
        on_average=decided,
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
