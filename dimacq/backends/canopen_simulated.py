"""Backend ``loadcell = "canopen-simulated"``: the virtual lab's load cells behind CANopen
amplifier simulators (:class:`~dimacq.simulators.canopen_loadcell.amplifier.CanopenAmplifierSim`,
a ``canopen.LocalNode`` from the same EDS file) on a python-can ``virtual`` channel, opened by
the same driver as ``"canopen"``; and the simulated dead-weight bench behind one
(``loadcell-bench = "canopen-simulated"``).

The simulators count the simulated DAQ's SYNC clock and read the lab's bridge outputs, cabled
as the rig file says (each entry's ``node_id`` is its node); the driver knows only the EDS, the
rig file and the calibration files.
"""

from __future__ import annotations

import itertools
import os
from typing import Any

from dimacq.backends.base import DeviceContext
from dimacq.backends.canopen_loadcell import open_canopen_amplifier
from dimacq.backends.simulated import world
from dimacq.drivers.canopen_loadcell.driver import CanopenLoadCell
from dimacq.io.rig_file import LoadCellEntry
from dimacq.model.channels import gauge_names

__all__ = ["open_dead_weight_bench", "open_loadcell"]

_SIMS = "canopen-simulated"
_names = itertools.count()


def _channel(ctx: DeviceContext) -> str:
    """The virtual channel of this context's CANopen simulators (made on first use: one node
    per rig file load cell, closed with the context)."""
    from dimacq.simulators.canopen_loadcell.amplifier import CanopenAmplifierSim

    got = ctx.shared.get(_SIMS)
    if got is not None:
        return str(got)
    w = world(ctx)
    channel = f"dimacq-canopen-{os.getpid()}-{next(_names)}"
    eds = ctx.settings.loadcell_canopen_eds_path
    for e in ctx.rig_file.load_cells:
        if e.node_id is None:  # not on CAN (its gauges may be DAQ inputs)
            continue
        gauges = [w.lab.channel_index(n) for n in gauge_names(e.node)]
        sim = CanopenAmplifierSim(
            channel, eds, w.lab, gauges, clock=w.clock, node_id=e.node_id, serial_number=e.node
        )
        ctx.on_close(sim.close)
    ctx.shared[_SIMS] = channel
    return channel


def open_loadcell(
    ctx: DeviceContext, entry: LoadCellEntry, *, require_calibration: bool = True
) -> CanopenLoadCell:
    """The table entry ``loadcell = "canopen-simulated"``."""
    import can

    channel = _channel(ctx)
    bus = can.Bus(interface="virtual", channel=channel)
    return open_canopen_amplifier(
        ctx,
        entry,
        bus,
        where=f"loadcell = 'canopen-simulated' (scenario {ctx.settings.scenario!r})",
        timeout_s=5.0,
        require_calibration=require_calibration and ctx.calibration_bench != entry.node,
    )


def open_dead_weight_bench(
    ctx: DeviceContext,
    *,
    node: int = 501,
    sample_rate_hz: float = 20.0,
    time_scale: float = 200.0,
    cell: Any = None,
    seed: int = 0,
) -> tuple[CanopenLoadCell, Any, Any]:
    """The simulated dead-weight bench of strain-gauge cell ``node`` behind a CANopen amplifier
    simulator (node id 1, its own clock at ``time_scale`` × real time), and the CANopen driver
    on it: ``(driver, operator, cell)`` as :func:`dimacq.backends.simulated.open_dead_weight_bench`."""
    import can
    import numpy as np

    from dimacq.config import Settings
    from dimacq.simulators.canopen_loadcell.amplifier import CanopenAmplifierSim
    from dimacq.simulators.lab.bridge import strain_gauge_cell
    from dimacq.simulators.loadcell.bench import DeadWeightBench

    settings = ctx.settings if ctx.settings is not None else Settings()
    eds = settings.loadcell_canopen_eds_path
    if cell is None:
        cell = strain_gauge_cell(node, temperature_ramp_k_per_s=2e-4)
    bench = DeadWeightBench(cell, node=node, sample_rate_hz=sample_rate_hz, seed=seed)
    name = f"dimacq-canopen-bench-{os.getpid()}-{next(_names)}"
    sim = CanopenAmplifierSim(
        name, eds, bench, list(range(12)), node_id=1, serial_number=node, time_scale=time_scale
    )
    ctx.on_close(sim.close)
    sim.rate_hz = float(sample_rate_hz)
    bus = can.Bus(interface="virtual", channel=name)
    ctx.on_close(bus.shutdown)
    amp = CanopenLoadCell(
        bus,
        node_id=1,
        eds=eds,
        timeout_s=5.0,
        heartbeat_ms=settings.loadcell_canopen_heartbeat_ms,
        heartbeat_factor=settings.loadcell_canopen_heartbeat_factor,
        label=f"load cell {node}",
    )
    ctx.on_close(amp.close)

    def operator(case: Any, _sample: int) -> None:
        bench.place(case.mass_kg, np.array(case.position_m), np.array(case.gravity))

    return amp, operator, cell
