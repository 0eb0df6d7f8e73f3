"""Backend ``loadcell = "canopen"``: CANopen load cell amplifiers through ``canopen``.

Each load cell of the rig file is the CANopen node its ``node_id`` names (the rig file says which
node is which cell), on a classic CAN bus ``can.Bus(interface=loadcell_interface, channel=the
entry's channel or loadcell_channel, bitrate=loadcell_canopen_bitrate)``, described by the EDS
file ``loadcell_canopen_eds`` (default ``config/canopen/loadcell.eds``). The driver
(:class:`~dimacq.drivers.canopen_loadcell.driver.CanopenLoadCell`) reads the PDO mapping from
the node; the node's serial number (``0x1018:04``) must match the calibration file, whose
matrix the driver applies. ``loadcell_canopen_node_ids``, when given, lists the node ids that
may be on the bus.
"""

from __future__ import annotations

from typing import Any

from dimacq.backends.base import DeviceContext
from dimacq.backends.can_bus import shared_can_bus
from dimacq.backends.can_loadcell import read_entry_calibration
from dimacq.drivers.canopen_loadcell.driver import CanopenLoadCell
from dimacq.errors import DeviceNotFoundError, DeviceTimeoutError, SetupError
from dimacq.io.rig_file import LoadCellEntry

__all__ = ["open_canopen_amplifier", "open_loadcell"]


def _check_node_id(ctx: DeviceContext, entry: LoadCellEntry) -> None:
    ids = ctx.settings.loadcell_canopen_node_ids
    if ids and entry.node_id not in ids:
        raise SetupError(
            f"load cell {entry.node}: node_id {entry.node_id} in {ctx.rig_file.path} is not one of "
            f"loadcell_canopen_node_ids {sorted(ids)}; correct the rig file or the setting"
        )


def open_canopen_amplifier(
    ctx: DeviceContext,
    entry: LoadCellEntry,
    bus: Any,
    *,
    where: str,
    timeout_s: float = 2.0,
    require_calibration: bool = True,
) -> CanopenLoadCell:
    """The driver of ``entry``'s node on ``bus`` (closed with ``ctx`` together with the bus),
    identified (serial number against the calibration file) and its mapping read.
    ``require_calibration=False`` (bench calibration of a new cell): a missing calibration file
    is allowed.

    Raises
    ------
    DeviceNotFoundError
        The node does not answer.
    SetupError
        Bad EDS or mapping, calibration file unreadable or of another cell.
    """
    s = ctx.settings
    node_id = entry.require_node_id(where)
    _check_node_id(ctx, entry)
    missing = not ctx.rig_file.calibration_path(entry).exists()
    cal = None if (missing and not require_calibration) else read_entry_calibration(ctx, entry)
    try:
        cell = CanopenLoadCell(
            bus,
            node_id=node_id,
            eds=s.loadcell_canopen_eds_path,
            timeout_s=timeout_s,
            calibration_matrix=None if cal is None else cal.matrix,
            heartbeat_ms=s.loadcell_canopen_heartbeat_ms,
            heartbeat_factor=s.loadcell_canopen_heartbeat_factor,
            bitrate=s.loadcell_canopen_bitrate,
            label=f"load cell {entry.node}",
        )
    except BaseException:
        bus.shutdown()
        raise
    try:
        try:
            ident = cell.identify()
        except DeviceTimeoutError as err:
            raise DeviceNotFoundError(
                f"{where}: CANopen node {entry.node_id} (load cell {entry.node}) does not answer "
                f"({err}); check its power, loadcell_canopen_bitrate and node_id in "
                f"{ctx.rig_file.path}"
            ) from err
        if cal is not None and str(ident.serial_number) != str(cal.serial_number):
            raise SetupError(
                f"load cell {entry.node}: CANopen node {entry.node_id} reports serial number "
                f"{ident.serial_number} but {ctx.rig_file.calibration_path(entry)} calibrates "
                f"{cal.serial_number}; give this cell's own calibration file or correct node_id"
            )
    except BaseException:
        cell.close()
        bus.shutdown()
        raise
    ctx.on_close(bus.shutdown)
    ctx.on_close(cell.close)
    return cell


def open_loadcell(
    ctx: DeviceContext, entry: LoadCellEntry, *, require_calibration: bool = True
) -> CanopenLoadCell:
    """The table entry ``"canopen"`` (the bus: one per channel,
    :func:`~dimacq.backends.can_bus.shared_can_bus`)."""
    s = ctx.settings
    channel = entry.channel or s.loadcell_channel
    where = (
        f"loadcell = 'canopen', loadcell_interface = {s.loadcell_interface!r}, channel "
        f"{channel!r} (loadcell_channel), loadcell_canopen_bitrate = {s.loadcell_canopen_bitrate}"
    )
    bus = shared_can_bus(s, backend="canopen", channel=channel, bitrate=s.loadcell_canopen_bitrate)
    return open_canopen_amplifier(
        ctx,
        entry,
        bus,
        where=where,
        require_calibration=require_calibration and ctx.calibration_bench != entry.node,
    )
