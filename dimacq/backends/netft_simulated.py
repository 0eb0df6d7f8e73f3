"""Backend ``loadcell = "netft-can-simulated"``: the virtual lab's load cells behind simulated
ATI Net F/T sensors (:class:`~dimacq.simulators.netft.can_sensor.NetFtCanSim`) on a python-can
``virtual`` channel, with the rig's request trigger on the simulated DAQ's clock, opened by the
same driver as ``"netft-can"``.

Each simulated sensor reads its cell's bridge outputs (the lab's gauge channels, the same the
amplifier simulators read) through its own factory calibration — the cell's true gauge matrix
inverted, with a 0.2 % certificate error of its own, which the host never sees — and counts with
:data:`SENSOR_CALIBRATION`, which the driver reads from it: each sensor's Ethernet side
(:class:`~dimacq.simulators.netft.ethernet.NetFtEthernetSim`: Read Calibration Info on TCP, its
configuration page ``netftapi2.xml`` on HTTP, loopback), as from a real one (the rig file's
stated counts are checked against it).
"""

from __future__ import annotations

import itertools
import os

import numpy as np

from dimacq.backends.base import DeviceContext
from dimacq.backends.can_bus import BUSES
from dimacq.backends.netft_can import open_netft, require_base
from dimacq.backends.netft_udp import open_rdt
from dimacq.backends.simulated import SimulatedWorld, imperfections, world
from dimacq.drivers.netft import protocol as p
from dimacq.drivers.netft.can_driver import NetFtCan
from dimacq.drivers.netft.udp_driver import NetFtUdp
from dimacq.io.rig_file import LoadCellEntry
from dimacq.model.channels import gauge_names

__all__ = ["SENSOR_CALIBRATION", "SIM_LATENCY_FLOOR_S", "open_loadcell", "open_udp_loadcell"]

#: what the simulated sensors hold: N and N·m, 10⁶ counts per unit (ATI's example value)
SENSOR_CALIBRATION = p.CalibrationInfo(2, 3, 1_000_000, 1_000_000)

#: the simulated network's latency floor, wall s: loopback UDP and the simulator thread's
#: wake-up (measured ~70-90 us on the project's 2-core machine), what a lab states for its LAN
SIM_LATENCY_FLOOR_S = 100e-6

_SIMS = "netft-can-simulated"
_names = itertools.count()


def _factory_matrix(w: SimulatedWorld, node: int) -> np.ndarray:
    """The simulated sensor's own calibration of cell ``node``: its true gauge matrix inverted,
    with a 0.2 % certificate error of its own."""
    S = w.lab.gauge_matrix(node)
    err = 0.002 * np.random.default_rng([0x4E7F, node]).standard_normal((6, 6))
    return (np.eye(6) + err) @ np.linalg.pinv(S)


def _channel(ctx: DeviceContext) -> str:
    """The virtual channel of this context's Net F/T simulators (one per rig file load cell
    with a ``netft_base``; made on first use, closed with the context)."""
    from dimacq.simulators.netft.can_sensor import NetFtCanSim
    from dimacq.simulators.netft.ethernet import NetFtEthernetSim

    got = ctx.shared.get(_SIMS)
    if got is not None:
        return str(got)
    w = world(ctx)
    imp = imperfections(ctx)
    channel = f"dimacq-netft-{os.getpid()}-{next(_names)}"
    for e in ctx.rig_file.load_cells:
        if e.netft_base is None:
            continue
        gauges = [w.lab.channel_index(n) for n in gauge_names(e.node)]
        eth = NetFtEthernetSim(SENSOR_CALIBRATION, rdt_rate_hz=e.netft_rdt_rate_hz)
        ctx.on_close(eth.close)
        ctx.shared[f"{_SIMS}:eth:{e.node}"] = eth
        sim = NetFtCanSim(
            channel,
            w.source,
            gauges,
            _factory_matrix(w, e.node),
            SENSOR_CALIBRATION,
            base=e.netft_base,
            clock=w.clock,
            frame_loss_rate=imp.can_frame_loss_rate,
            seed=0 if ctx.seed is None else ctx.seed,
        )
        ctx.on_close(sim.close)
    ctx.shared[_SIMS] = channel
    return channel


def open_loadcell(ctx: DeviceContext, entry: LoadCellEntry) -> NetFtCan:
    """The table entry ``loadcell = "netft-can-simulated"``."""
    import can

    where = f"loadcell = 'netft-can-simulated' (scenario {ctx.settings.scenario!r})"
    require_base(entry, where)
    channel = _channel(ctx)
    # the channel is the simulators' own: every frame on it is a Net F/T's (no filter to run
    # in Python on each of the five frames per sample); the driver ignores other bases' frames
    bus = BUSES.acquire(
        "virtual", channel, lambda: can.Bus(interface="virtual", channel=channel), where=where
    )
    eth = ctx.shared[f"{_SIMS}:eth:{entry.node}"]
    return open_netft(
        ctx,
        entry,
        bus,
        where=where,
        timeout_s=5.0,
        host=eth.http_address[0],
        tcp_port=eth.tcp_address[1],
        http_port=eth.http_address[1],
    )


def open_udp_loadcell(ctx: DeviceContext, entry: LoadCellEntry) -> NetFtUdp:
    """The table entry ``loadcell = "netft-udp-simulated"``: an RDT simulator of the cell on a
    loopback UDP port (its own crystal within ±``loadcell_oscillator_ppm``, the rig file's RDT
    rate, buffered records of 40), and the ``"netft-udp"`` driver on it. Its records meet the
    simulated DAQ's in the lab's physical time: the DAQ's free-running clock (with a DAQ clocked as
    the host reads, the suite's kind world, there is no such time: the sensor reads the world
    where the DAQ's count stands, and an acquisition through it is not aligned)."""
    from dimacq.simulators.netft.udp_sensor import NetFtUdpSim

    where = f"loadcell = 'netft-udp-simulated' (scenario {ctx.settings.scenario!r})"
    w = world(ctx)
    imp = imperfections(ctx)
    ppm = float(
        np.random.default_rng([0 if ctx.seed is None else ctx.seed, 0x4E7F, entry.node]).uniform(
            -imp.loadcell_oscillator_ppm, imp.loadcell_oscillator_ppm
        )
    )
    sim = NetFtUdpSim(
        w.source,
        [w.lab.channel_index(n) for n in gauge_names(entry.node)],
        _factory_matrix(w, entry.node),
        SENSOR_CALIBRATION,
        clock=w.clock,
        rdt_rate_hz=entry.netft_rdt_rate_hz,
        ft_rate_hz=entry.netft_ft_rate_hz,
        time_scale=imp.daq_time_scale,
        ppm=ppm,
        per_datagram=40,
        loss_rate=imp.can_frame_loss_rate,
        seed=0 if ctx.seed is None else ctx.seed,
    )
    ctx.on_close(sim.close)
    host, port = sim.address
    # the sensor's counts per unit read from it, as from a real one (the rig file's ignored)
    device_entry = entry.model_copy(
        update={"netft_counts_per_force": None, "netft_counts_per_torque": None}
    )
    return open_rdt(
        ctx,
        device_entry,
        host,
        port,
        where=where,
        tcp_port=sim.tcp_address[1],
        time_scale=imp.daq_time_scale,
        latency_floor_s=SIM_LATENCY_FLOOR_S,
        # the twin's thread shares the host's cores: a loaded host can hold it for seconds
        # (a real sensor streams on its own), as the other simulated backends allow
        timeout_s=5.0,
    )
