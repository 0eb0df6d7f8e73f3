"""Backend ``loadcell = "netft-can"``: an ATI Net F/T on a CAN bus through python-can.

The rig file's ``[[load_cells]]`` entry gives its base address (``netft_base``, as its DIP
switches set it) and its Ethernet address (``netft_host``): the CAN protocol carries no
calibration, so its counts per force and per torque unit and their units are **read from the
sensor** — Read Calibration Info over TCP (port 49151) and its configuration page
``netftapi2.xml`` over HTTP (:mod:`dimacq.drivers.netft.config_page`) — and the two must agree
(and agree with ``netft_counts_per_force`` ... where the entry states them too). Without
``netft_host`` the entry's stated values are used, logged as not read from the sensor. Its
internal sample rate (``netft_ft_rate_hz``, 7000) is on neither and stays as stated. The bus is ``can.Bus(interface =
loadcell_interface, channel = the entry's or loadcell_channel, bitrate =
loadcell_netft_bitrate)``, opened once per channel (:func:`~dimacq.backends.can_bus.
shared_can_bus`: several sensors, or a sensor and CANopen nodes, share it), each sensor's handle
filtered to its seven identifiers. The requests on the DAQ's
clock are the rig's (see :mod:`dimacq.drivers.netft.can_driver`).
"""

from __future__ import annotations

import logging
import socket
from typing import Any

from dimacq.backends.base import DeviceContext
from dimacq.backends.can_bus import shared_can_bus
from dimacq.drivers.netft import protocol as p
from dimacq.drivers.netft.can_driver import NetFtCan, bus_filters
from dimacq.drivers.netft.config_page import HTTP_PORT, NetFtConfig, read_config_page
from dimacq.drivers.netft.tcp_calibration import read_calibration_info
from dimacq.errors import DeviceError, DeviceNotFoundError, DeviceTimeoutError, SetupError
from dimacq.io.rig_file import LoadCellEntry

__all__ = [
    "calibration_info",
    "open_loadcell",
    "open_netft",
    "require_base",
    "sensor_calibration",
]

log = logging.getLogger(__name__)


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


def sensor_calibration(
    entry: LoadCellEntry,
    host: str,
    *,
    where: str,
    tcp_port: int = p.TCP_PORT,
    http_port: int = HTTP_PORT,
) -> tuple[p.CalibrationInfo, NetFtConfig]:
    """The sensor's counts per unit and units read from it at ``host`` (TCP and HTTP), checked
    against each other and against what the entry states.

    Raises
    ------
    DeviceNotFoundError
        It cannot be reached or does not answer.
    SetupError
        The two answers disagree, or the entry states other values.
    """
    try:
        with socket.create_connection((host, tcp_port), timeout=2.0) as tcp:
            tcp.settimeout(2.0)
            cal = read_calibration_info(tcp, where=where)
        page = read_config_page(host, http_port, where=where)
        from_page = page.calibration()
    except (OSError, DeviceError) as err:
        raise DeviceNotFoundError(
            f"{where}: cannot read its calibration from {host} (TCP {tcp_port}, HTTP "
            f"{http_port}): {err}; check netft_host in the rig file and the sensor's network"
        ) from err
    said = (cal.force_unit, cal.torque_unit, cal.counts_per_force, cal.counts_per_torque)
    shown = (
        from_page.force_unit,
        from_page.torque_unit,
        from_page.counts_per_force,
        from_page.counts_per_torque,
    )
    if said != shown:
        raise SetupError(
            f"{where}: Read Calibration Info gives units/counts {said} but its configuration "
            f"page's active configuration {page.index} ({page.name!r}) shows {shown}; select the "
            "configuration whose calibration is loaded on the sensor's pages"
        )
    stated = (entry.netft_counts_per_force, entry.netft_counts_per_torque)
    if stated != (None, None) and stated != (cal.counts_per_force, cal.counts_per_torque):
        raise SetupError(
            f"load cell {entry.node}: the rig file states counts per force/torque {stated} but "
            f"the sensor holds ({cal.counts_per_force}, {cal.counts_per_torque}); remove "
            "netft_counts_per_force/_torque from its entry (they are read from the sensor)"
        )
    return cal, page


def open_netft(
    ctx: DeviceContext,
    entry: LoadCellEntry,
    bus: Any,
    *,
    where: str,
    timeout_s: float = 1.0,
    host: str | None = None,
    tcp_port: int = p.TCP_PORT,
    http_port: int = HTTP_PORT,
) -> NetFtCan:
    """The driver of ``entry``'s sensor on ``bus`` (closed with ``ctx``), answering a request;
    its calibration read from the sensor at ``host`` (default the entry's ``netft_host``; none:
    the entry's stated values).

    Raises
    ------
    DeviceNotFoundError
        No answer.
    SetupError
        Base address or counts per unit missing from the rig file.
    """
    try:
        base = require_base(entry, where)
        host = entry.netft_host if host is None else host
        if host:
            cal, _page = sensor_calibration(
                entry, host, where=where, tcp_port=tcp_port, http_port=http_port
            )
        else:
            cal = calibration_info(entry, where)
            log.warning(
                "%s: load cell %s: counts per unit taken from the rig file, not read from the "
                "sensor (give netft_host to read them)",
                where,
                entry.node,
            )
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
