"""Backend ``loadcell = "cia404"``: generic CiA 404 amplifiers over CANopen.

Each load cell of the rig file is the node its ``node_id`` names, on the CAN channel its entry
gives (or ``loadcell_channel``); every cell of one channel shares **one** ``can.Bus`` and one
``canopen.Network`` (:class:`~dimacq.drivers.cia404.driver.CanChannel`, on a handle of the channel's one bus,
:func:`~dimacq.backends.can_bus.shared_can_bus`: PCAN allows one client per channel), whose summed
load is checked when the rate is set. The node is described by ``loadcell_cia404_eds`` (default
``config/canopen/cia404-generic.eds``); its inputs 1..N carry the cell's gauges in the order of
the calibration file's columns (N = the matrix's columns), whose matrix the driver applies; the
node's serial number ``0x1018:04`` must be the calibration file's.
"""

from __future__ import annotations

from typing import Any

from dimacq.backends.base import DeviceContext
from dimacq.backends.can_bus import shared_can_bus
from dimacq.backends.can_loadcell import read_entry_calibration
from dimacq.drivers.cia404.driver import CanChannel, Cia404Amplifier
from dimacq.errors import DeviceNotFoundError, DeviceTimeoutError, SetupError
from dimacq.io.rig_file import LoadCellEntry

__all__ = ["open_loadcell", "open_node", "shared_channel"]


def shared_channel(
    ctx: DeviceContext, key: str, open_bus: Any, *, where: str, enforce: bool = True
) -> CanChannel:
    """The context's :class:`CanChannel` named ``key`` (opened with ``open_bus()`` the first
    time, closed with the context after its nodes)."""
    got = ctx.shared.get(f"cia404-channel:{key}")
    if got is not None:
        return got
    s = ctx.settings
    bus = open_bus()
    try:
        ch = CanChannel(
            bus,
            bitrate=s.loadcell_canopen_bitrate,
            max_load=s.loadcell_cia404_max_bus_load,
            where=where,
            enforce=enforce,
        )
    except BaseException:
        bus.shutdown()
        raise
    ctx.on_close(ch.close)
    ctx.shared[f"cia404-channel:{key}"] = ch
    return ch


def open_node(
    ctx: DeviceContext,
    entry: LoadCellEntry,
    channel: CanChannel,
    *,
    where: str,
    timeout_s: float = 2.0,
) -> Cia404Amplifier:
    """The driver of ``entry``'s node on ``channel``, identified (device type and identity
    against the EDS, serial number against the calibration file) and its TPDOs mapped.

    Raises
    ------
    DeviceNotFoundError
        The node does not answer.
    SetupError
        Another device than the EDS's, a calibration file of another cell, a bad EDS.
    """
    s = ctx.settings
    node_id = entry.require_node_id(where)
    bench = ctx.calibration_bench == entry.node
    missing = not ctx.rig_file.calibration_path(entry).exists()
    cal = None if (missing and bench) else read_entry_calibration(ctx, entry)
    n = s.loadcell_cia404_channels if cal is None else int(cal.matrix.shape[1])
    amp = Cia404Amplifier(
        channel,
        node_id=node_id,
        eds=s.loadcell_cia404_eds_path,
        n_channels=n,
        timeout_s=timeout_s,
        calibration_matrix=None if cal is None else cal.matrix,
        heartbeat_ms=s.loadcell_canopen_heartbeat_ms,
        heartbeat_factor=s.loadcell_canopen_heartbeat_factor,
        sync=s.loadcell_cia404_sync,
        process_value=s.loadcell_cia404_process_value,
        gauge_unit=None if cal is None else cal.gauge_unit,
        max_phase_deg=s.loadcell_cia404_max_phase_deg,
        label=f"load cell {entry.node}",
    )
    try:
        try:
            ident = amp.identify()
        except DeviceTimeoutError as err:
            raise DeviceNotFoundError(
                f"{where}: CANopen node {node_id} (load cell {entry.node}) does not answer "
                f"({err}); check its power, loadcell_canopen_bitrate and node_id in "
                f"{ctx.rig_file.path}"
            ) from err
        if cal is not None and str(ident.serial_number) != str(cal.serial_number):
            raise SetupError(
                f"load cell {entry.node}: CiA 404 node {node_id} reports serial number "
                f"{ident.serial_number} but {ctx.rig_file.calibration_path(entry)} calibrates "
                f"{cal.serial_number}; give this cell's own calibration file or correct node_id"
            )
    except BaseException:
        amp.close()
        raise
    ctx.on_close(amp.close)
    return amp


def open_loadcell(ctx: DeviceContext, entry: LoadCellEntry) -> Cia404Amplifier:
    """The table entry ``loadcell = "cia404"``."""
    s = ctx.settings
    chan = entry.channel or s.loadcell_channel
    where = (
        f"loadcell = 'cia404', loadcell_interface = {s.loadcell_interface!r}, channel "
        f"{chan!r}, loadcell_canopen_bitrate = {s.loadcell_canopen_bitrate}"
    )
    channel = shared_channel(
        ctx,
        f"{s.loadcell_interface}:{chan}",
        lambda: shared_can_bus(
            s, backend="cia404", channel=chan, bitrate=s.loadcell_canopen_bitrate
        ),
        where=where,
    )
    return open_node(ctx, entry, channel, where=where)
