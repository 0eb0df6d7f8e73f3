"""Backend ``loadcell = "cia404-simulated"``: the virtual lab's load cells behind simulated
generic CiA 404 amplifiers (:class:`~dimacq.simulators.cia404.node.Cia404NodeSim`, a
``canopen.LocalNode`` from ``loadcell_cia404_eds``: the generic EDS that maps 0x6130, not the
project's), with the rig's SYNC producer on the simulated DAQ's sample clock
(``loadcell_cia404_sync = "daq"``: the DAQ's clock wired to the SYNC producer), on a python-can
``virtual`` channel, opened by the same code as ``"cia404"`` (:func:`~dimacq.backends.cia404.
open_node` on one shared :class:`~dimacq.drivers.cia404.driver.CanChannel`).

Each node's inputs 1..12 are the cell's bridge outputs (the lab's gauge channels, the ones the
other amplifier simulators read), in the lab's units; the host knows only the EDS, the rig file
and the calibration files. The virtual bus has no bit rate: a load above
``loadcell_cia404_max_bus_load`` of ``loadcell_canopen_bitrate`` is logged (a real bus would
refuse it: 12 REAL32 inputs at the calibration mass's 2048 S/s are 177 % of 1 Mbit/s), not
refused, so the chain can be run whole on the shipped scenarios.
"""

from __future__ import annotations

import itertools
import os

from dimacq.backends.base import DeviceContext
from dimacq.backends.can_bus import BUSES
from dimacq.backends.cia404 import open_node, shared_channel
from dimacq.backends.simulated import world
from dimacq.drivers.cia404.driver import Cia404Amplifier
from dimacq.io.rig_file import LoadCellEntry
from dimacq.model.channels import gauge_names

__all__ = ["open_loadcell"]

_SIMS = "cia404-simulated"
_names = itertools.count()


def _channel(ctx: DeviceContext) -> str:
    """The virtual channel of this context's nodes and SYNC producer (made on first use: one
    node per rig file load cell with a ``node_id``; closed with the context)."""
    from dimacq.simulators.cia404.node import Cia404NodeSim, SyncProducerSim

    got = ctx.shared.get(_SIMS)
    if got is not None:
        return str(got)
    w = world(ctx)
    channel = f"dimacq-cia404-{os.getpid()}-{next(_names)}"
    eds = ctx.settings.loadcell_cia404_eds_path
    nodes = []
    for e in ctx.rig_file.load_cells:
        if e.node_id is None:
            continue
        inputs = [w.lab.channel_index(n) for n in gauge_names(e.node)]
        node = Cia404NodeSim(channel, eds, w.lab, inputs, node_id=e.node_id, serial_number=e.node)
        ctx.on_close(node.close)
        nodes.append(node)
    producer = SyncProducerSim(channel, w.clock, nodes)
    ctx.on_close(producer.close)
    ctx.shared[_SIMS] = channel
    return channel


def open_loadcell(ctx: DeviceContext, entry: LoadCellEntry) -> Cia404Amplifier:
    """The table entry ``loadcell = "cia404-simulated"``."""
    import can

    where = f"loadcell = 'cia404-simulated' (scenario {ctx.settings.scenario!r})"
    name = _channel(ctx)
    channel = shared_channel(
        ctx,
        name,
        lambda: BUSES.acquire(
            "virtual", name, lambda: can.Bus(interface="virtual", channel=name), where=where
        ),
        where=where,
        enforce=False,
    )
    return open_node(ctx, entry, channel, where=where, timeout_s=5.0)
