"""Backend ``loadcell = "daq-channels"``: a load cell's gauges, or its six conditioned F/T
outputs, read as inputs of the rig's DAQ, sampled with the accelerometers on one clock (the
thesis's set-up).

The rig file's ``[[load_cells]]`` entry says which DAQ inputs carry the cell
(``daq_channels``, in the calibration matrix's column order), whether they are its bridges
(``daq_signals = "gauges"``, the calibration's 6×N matrix; ``excitation_v`` when it is in mV/V)
or six conditioned outputs (``"outputs"``, a 6×6 matrix in N/V, N·m/V), and their
``daq_range_v`` and ``daq_coupling``. The calibration file's matrix is applied as for an
amplifier on CAN (``F = C g``). Real or simulated is the DAQ's backend: on the simulated lab
(``daq = "simulated"``) the simulated USB DAQ carries the cell's bridge outputs on those inputs,
from the same physics the CAN amplifier simulator reads.

The factory takes the DAQ the rig opened (``ctx.daq``; it opens the configured one itself when
called alone, e.g. by the devices check), wraps it once in a
:class:`~dimacq.drivers.daq_loadcell.driver.DaqSplitter` and claims the cell's inputs on it.
"""

from __future__ import annotations

from dimacq.backends import lookup
from dimacq.backends.base import DeviceContext
from dimacq.backends.can_loadcell import read_entry_calibration
from dimacq.devices.daq import ChannelConfig
from dimacq.drivers.daq_loadcell.driver import ChannelDaq, DaqChannelLoadCell, DaqSplitter
from dimacq.errors import SetupError
from dimacq.io.rig_file import LoadCellEntry
from dimacq.model.channels import load_names, loadcell_prefix

__all__ = ["channel_names", "open_loadcell", "splitter"]

#: V per gauge unit of a gauge unit that needs no excitation
_VOLTS = {"V": 1.0, "mV": 1e-3}


def channel_names(entry: LoadCellEntry) -> list[str]:
    """The DAQ channel names of the cell's inputs: ``"LC501 g01"`` .. (gauges) or
    ``"LC501 Fx"`` .. ``"LC501 Mz"`` (conditioned outputs)."""
    if entry.daq_signals == "outputs":
        return load_names(entry.node)
    return [f"{loadcell_prefix(entry.node)} g{k + 1:02d}" for k in range(len(entry.daq_channels))]


def splitter(ctx: DeviceContext) -> DaqSplitter:
    """The context's DAQ wrapped once in a :class:`DaqSplitter` (the DAQ opened first when the
    rig has not: ``daq`` setting)."""
    daq = ctx.daq
    if daq is None:
        daq = lookup("daq", ctx.settings.daq)(ctx)
    if isinstance(daq, DaqSplitter):
        return daq
    if not isinstance(daq, ChannelDaq):
        raise SetupError(
            f"loadcell = 'daq-channels': the DAQ of daq = {ctx.settings.daq!r} "
            f"({type(daq).__name__}) cannot add a voltage input (no add_channel); use a DAQ "
            "backend that can, or a load cell amplifier backend"
        )
    wrapped = DaqSplitter(daq)
    ctx.daq = wrapped
    return wrapped


def _sensitivity(entry: LoadCellEntry, gauge_unit: str, where: str) -> float:
    """V per gauge unit of the cell's inputs."""
    if gauge_unit == "mV/V":
        if entry.excitation_v is None:
            raise SetupError(
                f"{where}: the calibration is in mV/V; give the bridges' excitation_v (V) in the "
                "rig file entry, or a calibration in V"
            )
        return entry.excitation_v * 1e-3
    if gauge_unit in _VOLTS:
        return _VOLTS[gauge_unit]
    raise SetupError(
        f"{where}: calibration gauge_unit {gauge_unit!r}; a cell on DAQ inputs reads 'V', 'mV' or "
        "'mV/V' (with excitation_v)"
    )


def open_loadcell(ctx: DeviceContext, entry: LoadCellEntry) -> DaqChannelLoadCell:
    """The table entry ``loadcell = "daq-channels"`` (the cell on the calibration bench,
    ``ctx.calibration_bench``, may have no calibration file yet: gauges only).

    Raises
    ------
    SetupError
        No ``daq_channels`` in the entry, a matrix whose columns are not one per input, a gauge
        unit the inputs cannot read, an input the DAQ refuses (each names the rig file item).
    """
    rf = ctx.rig_file
    where = f"load cell {entry.node} (loadcell = 'daq-channels', rig file {rf.name})"
    if not entry.daq_channels:
        raise SetupError(
            f"{where}: no daq_channels; list the DAQ inputs of its gauges (or of its six "
            "conditioned outputs, daq_signals = 'outputs') in the calibration's column order"
        )
    bench = ctx.calibration_bench == entry.node
    cal = (
        None
        if bench and not rf.calibration_path(entry).exists()
        else read_entry_calibration(ctx, entry)
    )
    n = len(entry.daq_channels)
    if cal is not None and cal.n_gauges != n:
        raise SetupError(
            f"{where}: {rf.calibration_path(entry).name} has {cal.n_gauges} gauge columns but "
            f"daq_channels lists {n} inputs; list one input per column"
        )
    if entry.daq_signals == "outputs" and cal is not None and cal.gauge_unit == "mV/V":
        raise SetupError(
            f"{where}: daq_signals = 'outputs' with a calibration in mV/V; conditioned outputs "
            "are volts: give their 6x6 matrix in N/V and N*m/V (gauge_unit 'V')"
        )
    unit = cal.gauge_unit if cal is not None else ("mV/V" if entry.excitation_v else "V")
    sens = _sensitivity(entry, unit, where)
    configs = [
        ChannelConfig(ch, name, unit, sens, entry.daq_range_v, 0, entry.daq_coupling)
        for ch, name in zip(entry.daq_channels, channel_names(entry), strict=True)
    ]
    split = splitter(ctx)
    try:
        feed = split.claim(configs)
    except SetupError as err:
        raise SetupError(f"{where}, daq_channels: {err}") from err
    serial = cal.serial_number if cal is not None else str(entry.node)
    return DaqChannelLoadCell(
        feed,
        calibration_matrix=None if cal is None else cal.matrix,
        serial_number=int(serial) if serial.isdigit() else entry.node,
        label=f"load cell {entry.node}",
    )
