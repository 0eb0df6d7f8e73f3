"""Backend ``loadcell = "dimacq-can"``: the CAN FD load cell amplifier through python-can.

Each load cell of the rig file is opened on its own handle of its channel's one bus (``interface =
loadcell_interface``, ``channel`` = the entry's or ``loadcell_channel``, CAN FD with the bit timing
of the ``loadcell_f_clock``/``loadcell_bitrate``/``loadcell_sample_point``/
``loadcell_data_bitrate``/``loadcell_data_sample_point`` settings, each overridable per rig file entry by ``f_clock``,
``bitrate``, ``sample_point``, ``data_bitrate``, ``data_sample_point``; filtered to the node's
identifiers) with the 6×12 matrix of its calibration file; the amplifier's serial number
must match the file's.
"""

from __future__ import annotations

from typing import Any

from dimacq.backends.base import DeviceContext
from dimacq.backends.can_bus import shared_can_bus
from dimacq.drivers.loadcell import protocol as lp
from dimacq.drivers.loadcell.driver import LoadCellAmplifier
from dimacq.errors import DataError, DeviceNotFoundError, DeviceTimeoutError, SetupError
from dimacq.io.loadcell_calibration import LoadCellCalibration, read_calibration
from dimacq.io.rig_file import LoadCellEntry

__all__ = ["bit_timing", "open_amplifier", "open_loadcell", "read_entry_calibration"]

_TIMING_SETTINGS = (
    "loadcell_f_clock, loadcell_bitrate, loadcell_sample_point, loadcell_data_bitrate, "
    "loadcell_data_sample_point"
)


def bit_timing(settings: Any, entry: LoadCellEntry | None = None) -> Any:
    """The ``can.BitTimingFd`` of the settings, each value overridden by the rig file entry's
    ``f_clock``/``bitrate``/``sample_point``/``data_bitrate``/``data_sample_point`` when given.

    Raises
    ------
    SetupError
        No valid timing for those rates, clock and sample points; names the settings (and the
        rig file entry when it gave a value).
    """
    import can

    s = settings
    given = {}
    values = {}
    for key in ("f_clock", "bitrate", "sample_point", "data_bitrate", "data_sample_point"):
        v = None if entry is None else getattr(entry, key)
        if v is not None:
            given[key] = v
        values[key] = v if v is not None else getattr(s, f"loadcell_{key}")
    try:
        return can.BitTimingFd.from_sample_point(
            f_clock=values["f_clock"],
            nom_bitrate=values["bitrate"],
            nom_sample_point=values["sample_point"],
            data_bitrate=values["data_bitrate"],
            data_sample_point=values["data_sample_point"],
        )
    except ValueError as err:
        where = (
            f"load cell {entry.node} of the rig file ({', '.join(given)}) and the settings "
            f"({_TIMING_SETTINGS})"
            if entry is not None and given
            else _TIMING_SETTINGS
        )
        raise SetupError(
            f"CAN FD bit timing: {err}; give rates that divide the adapter's clock ({where})"
        ) from err


def _filters(node_id: int) -> list[dict[str, Any]]:
    ids = (lp.response_id(node_id), lp.data_id(node_id), lp.heartbeat_id(node_id))
    return [{"can_id": i, "can_mask": 0x7FF, "extended": False} for i in ids]


def read_entry_calibration(ctx: DeviceContext, entry: LoadCellEntry) -> LoadCellCalibration:
    """The calibration file of ``entry`` (relative paths from the rig file).

    Raises
    ------
    SetupError
        Unreadable file; the message names the rig file item.
    """
    rig_file = ctx.rig_file
    try:
        return read_calibration(rig_file.calibration_path(entry))
    except (OSError, DataError) as err:
        raise SetupError(
            f"load cell {entry.node} (calibration_file of {rig_file.path}): {err}; give the "
            "cell's calibration file (dimacq loadcell calibrate writes one)"
        ) from err


def open_amplifier(
    ctx: DeviceContext,
    entry: LoadCellEntry,
    *,
    interface: str | None,
    channel: str,
    where: str,
    timeout_s: float = 2.0,
    require_calibration: bool = True,
    timing: Any = None,
    retries: int = 2,
) -> LoadCellAmplifier:
    """Open the amplifier of ``entry`` on ``can.Bus(interface, channel)`` (``interface`` None:
    the real adapter of the settings, :func:`~dimacq.backends.can_bus.open_can_bus`; CAN FD, with the
    ``can.BitTimingFd`` ``timing`` when given), calibrated from its file; the bus's closer goes
    to ``ctx``. ``require_calibration=False`` (bench calibration of a new cell): a missing
    calibration file is allowed (no matrix is set); an existing one must still belong to the
    cell. ``retries``: further attempts of an idempotent command (IDENTIFY, SET_RATE, START,
    STOP, GET_STATUS) that got no answer (a node bus-off for a moment).

    Raises
    ------
    DeviceNotFoundError
        The bus cannot be opened, or the amplifier does not answer.
    SetupError
        The calibration file is unreadable or belongs to another cell.
    """
    import can

    node_id = entry.require_node_id(where)
    missing = not ctx.rig_file.calibration_path(entry).exists()
    cal = None if (missing and not require_calibration) else read_entry_calibration(ctx, entry)
    extra = {} if timing is None else {"timing": timing}
    bus: Any
    if interface is None:  # a real adapter: the settings' interface or python-can's own
        bus = shared_can_bus(
            ctx.settings,
            backend="dimacq-can",
            channel=channel,
            fd=True,
            can_filters=_filters(node_id),
            **extra,
        )
    else:
        try:
            bus = can.Bus(
                interface=interface,
                channel=channel,
                fd=True,
                can_filters=_filters(node_id),
                **extra,
            )
        except Exception as err:  # python-can raises anything without the vendor library
            raise DeviceNotFoundError(
                f"{where}: cannot open the CAN bus ({type(err).__name__}: {err})"
            ) from err
    try:
        amp = LoadCellAmplifier(
            bus,
            node_id=node_id,
            timeout_s=timeout_s,
            retries=retries,
            calibration_matrix=None if cal is None else cal.matrix,
            clock_tolerance_ppm=ctx.settings.loadcell_clock_tolerance_ppm,
        )
        try:
            ident = amp.identify()
        except DeviceTimeoutError as err:
            raise DeviceNotFoundError(
                f"{where}: load cell amplifier node_id {entry.node_id} (load cell {entry.node}) "
                f"does not answer ({err}); check its power, the bit rate and node_id in "
                f"{ctx.rig_file.path}"
            ) from err
        if cal is not None and str(ident.serial_number) != str(cal.serial_number):
            raise SetupError(
                f"load cell {entry.node}: amplifier node_id {entry.node_id} reports serial number "
                f"{ident.serial_number} but {ctx.rig_file.calibration_path(entry)} calibrates "
                f"{cal.serial_number}; give this cell's own calibration file or correct node_id"
            )
    except BaseException:
        bus.shutdown()
        raise
    ctx.on_close(bus.shutdown)
    return amp


def open_loadcell(ctx: DeviceContext, entry: LoadCellEntry) -> LoadCellAmplifier:
    """The table entry ``"dimacq-can"`` (the cell on the calibration bench,
    ``ctx.calibration_bench``, may have no calibration file yet)."""
    s = ctx.settings
    channel = entry.channel or s.loadcell_channel
    return open_amplifier(
        ctx,
        entry,
        interface=None,
        channel=channel,
        timing=bit_timing(s, entry),
        require_calibration=ctx.calibration_bench != entry.node,
        where=(
            f"loadcell = 'dimacq-can', loadcell_interface = {s.loadcell_interface!r}, channel "
            f"{channel!r} (loadcell_channel)"
        ),
    )
