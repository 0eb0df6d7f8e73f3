"""Backend ``loadcell = "netft-can"``: an ATI Net F/T on a CAN bus through python-can.

The rig file's ``[[load_cells]]`` entry gives its base address (``netft_base``, as its DIP
switches set it) and its calibration: counts per force and per torque unit and their unit codes
(``netft_counts_per_force``, ``netft_counts_per_torque``, ``netft_force_unit``,
``netft_torque_unit``, as the sensor's configuration page or its Read Calibration Info answer
give them: the CAN protocol carries no calibration). The bus is ``can.Bus(interface =
loadcell_interface, channel = the entry's or loadcell_channel, bitrate =
loadcell_netft_bitrate)``, opened once per channel (:func:`~dimacq.backends.can_bus.
shared_can_bus`: several sensors, or a sensor and CANopen nodes, share it), each sensor's handle
filtered to its seven identifiers. The requests on the DAQ's
clock are the rig's (see :mod:`dimacq.drivers.netft.can_driver`).
"""

from __future__ import annotations

from typing import Any

from dimacq.backends.base import DeviceContext
from dimacq.backends.can_bus import shared_can_bus
from dimacq.drivers.netft import protocol as p
from dimacq.drivers.netft.can_driver import NetFtCan, bus_filters
from dimacq.errors import DeviceNotFoundError, DeviceTimeoutError, SetupError
from dimacq.io.rig_file import LoadCellEntry

__all__ = ["calibration_info", "open_loadcell", "open_netft", "require_base"]


def require_base(entry: LoadCellEntry, where: str) -> int:
    if entry.netft_base is None:
        raise SetupError(
            f"load cell {entry.node}: {where} needs the Net F/T's CAN base address; give "
            "netft_base (as its DIP switches set it) in its [[load_cells]] entry of the rig file"
        )
    return entry.netft_base


def calibration_info(entry: LoadCellEntry, where: str) -> p.CalibrationInfo:
    """The sensor's counts per unit as the rig file states them."""
    if entry.netft_counts_per_force is None or entry.netft_counts_per_torque is None:
        raise SetupError(
            f"load cell {entry.node}: {where} needs the Net F/T's counts per unit; give "
            "netft_counts_per_force and netft_counts_per_torque (its calibration info: the "
            "configuration page) in its [[load_cells]] entry"
        )
    return p.CalibrationInfo(
        entry.netft_force_unit,
        entry.netft_torque_unit,
        entry.netft_counts_per_force,
        entry.netft_counts_per_torque,
    )


def open_netft(
    ctx: DeviceContext,
    entry: LoadCellEntry,
    bus: Any,
    *,
    where: str,
    timeout_s: float = 1.0,
) -> NetFtCan:
    """The driver of ``entry``'s sensor on ``bus`` (closed with ``ctx``), answering a request.

    Raises
    ------
    DeviceNotFoundError
        No answer.
    SetupError
        Base address or counts per unit missing from the rig file.
    """
    try:
        base = require_base(entry, where)
        cal = calibration_info(entry, where)
        drv = NetFtCan(
            bus,
            base=base,
            calibration=cal,
            serial_number=entry.node,
            timeout_s=timeout_s,
            bitrate=ctx.settings.loadcell_netft_bitrate,
            adc_rate_hz=entry.netft_ft_rate_hz,
            band_hz=entry.netft_band_hz,
            max_phase_deg=entry.netft_max_phase_deg,
            label=f"Net F/T of load cell {entry.node}",
        )
        try:
            drv.identify()
        except DeviceTimeoutError as err:
            raise DeviceNotFoundError(f"{where}: {err}") from err
    except BaseException:
        bus.shutdown()
        raise
    ctx.on_close(bus.shutdown)
    ctx.on_close(drv.close)
    return drv


def open_loadcell(ctx: DeviceContext, entry: LoadCellEntry) -> NetFtCan:
    """The table entry ``loadcell = "netft-can"``."""
    s = ctx.settings
    channel = entry.channel or s.loadcell_channel
    where = (
        f"loadcell = 'netft-can', loadcell_interface = {s.loadcell_interface!r}, channel "
        f"{channel!r}, loadcell_netft_bitrate = {s.loadcell_netft_bitrate}"
    )
    base = require_base(entry, where)
    bus = shared_can_bus(
        s,
        backend="netft-can",
        channel=channel,
        bitrate=s.loadcell_netft_bitrate,
        can_filters=bus_filters(base),
    )
    return open_netft(ctx, entry, bus, where=where)
