"""Backend ``daq = "nidaqmx"``: NI DSA devices (a cDAQ chassis's C Series modules: IEPE inputs
on NI 9234, load cell bridges on NI 9237, one task, one timebase) through the official
``nidaqmx`` API.

Optional: ``pip install "dimacq[ni]"`` and NI-DAQmx (the driver runtime, from NI) on the
machine. The rig file's ``[[daq.modules]]`` names the modules (``name = "cDAQ1Mod1"``,
``model = "NI 9234"``, ``inputs``: the rig inputs on its ``ai0``, ``ai1``, ...); each model is checked
against the device, and the IEPE currents and excitation voltages the device reports are the ones
a channel may ask. ``[daq] units`` (device names; input ``k`` is the ``k``-th of their AI
channels) is the short form. ``daq_ni_start_trigger`` (``"/cDAQ1/PFI0"``) starts the task on a
digital edge; ``daq_ni_sample_clock_out`` (``"/cDAQ1/PFI1"``) exports its sample clock.

:func:`plan_rig` is the plan of the rig file's task from NI's published figures alone, without
nidaqmx or NI-DAQmx (``dimacq devices plan --daq nidaqmx``). **No simulated twin; never run on
real hardware by its author** (see the manual, instruments-ni.md).
"""

from __future__ import annotations

import logging
from typing import Any

from dimacq.backends.base import DeviceContext
from dimacq.drivers.ni.plan import (
    ChannelKind,
    ChannelRequest,
    ModuleSlot,
    NiPlan,
    catalogue_slots,
    make_plan,
    no_overlap,
    propose_modules,
    slot_inputs,
)
from dimacq.errors import DeviceNotFoundError, SetupError
from dimacq.io.rig_file import RigFile

__all__ = ["import_nidaqmx", "ni_devices", "offered", "open_daq", "plan_rig", "rig_requests"]

log = logging.getLogger(__name__)

_WHERE = "daq = 'nidaqmx'"


def import_nidaqmx() -> Any:
    """The ``nidaqmx`` package, its runtime checked.

    Raises
    ------
    SetupError
        The package is not installed.
    DeviceNotFoundError
        NI-DAQmx (the runtime) is not installed.
    """
    try:
        import nidaqmx
        import nidaqmx.system
    except ImportError as err:
        raise SetupError(
            f"{_WHERE}: the Python package nidaqmx is not installed; pip install 'dimacq[ni]' "
            "(and NI-DAQmx from ni.com), or choose another daq (DIMACQ_DAQ)"
        ) from err
    try:
        nidaqmx.system.System.local().driver_version  # noqa: B018 (loads the runtime)
    except nidaqmx.errors.DaqNotFoundError as err:
        raise DeviceNotFoundError(
            f"{_WHERE}: NI-DAQmx (the driver runtime) is not installed on this machine; "
            "install it from ni.com (nidaqmx installdriver), or choose another daq (DIMACQ_DAQ)"
        ) from err
    return nidaqmx


def rig_requests(rf: RigFile, *, with_loadcells: bool = True) -> list[ChannelRequest]:
    """The rig file's inputs as channel requests: hammers (IEPE force), responses (IEPE
    acceleration) and, ``with_loadcells``, each load cell's ``daq_channels`` (its bridges,
    or its conditioned outputs as voltages)."""
    out = [
        ChannelRequest(
            h.physical_channel,
            f"hammer ch{h.physical_channel}",
            "force",
            f"hammers.{i}",
            h.iepe_current_ma,
            None,
            h.range_v,
            h.coupling,
        )
        for i, h in enumerate(rf.hammers)
    ]
    out += [
        ChannelRequest(
            r.physical_channel,
            r.key,
            "accel",
            f"responses.{i}",
            r.iepe_current_ma,
            None,
            r.range_v,
            r.coupling,
        )
        for i, r in enumerate(rf.responses)
    ]
    if with_loadcells:
        from dimacq.backends.daq_channels import channel_names

        for i, lc in enumerate(rf.load_cells):
            names = channel_names(lc) if lc.daq_channels else []
            for ch, name in zip(lc.daq_channels, names, strict=True):
                kind: ChannelKind = "bridge" if lc.daq_signals == "gauges" else "voltage"
                out.append(
                    ChannelRequest(
                        ch,
                        name,
                        kind,
                        f"load_cells.{i} (input {ch})",
                        0.0,
                        lc.excitation_v,
                        lc.daq_range_v,
                        lc.daq_coupling,
                    )
                )
    return out


def plan_rig(
    rf: RigFile, *, with_loadcells: bool = True, chassis: str = "cDAQ1"
) -> tuple[NiPlan, bool]:
    """The plan of the rig file's NI task from the catalogue (no driver), and whether its
    modules were proposed (the rig file has no ``[[daq.modules]]``) rather than given.

    Raises
    ------
    SetupError
        A ``[[daq.modules]]`` model not in the catalogue, or modules that overlap.
    """
    requests = rig_requests(rf, with_loadcells=with_loadcells)
    if rf.daq.modules:
        slots = catalogue_slots([(m.name, m.model, m.inputs) for m in rf.daq.modules])
        proposed = False
    else:
        slots = propose_modules(requests, chassis=chassis)
        proposed = True
    return make_plan(requests, slots, rf.daq.sample_rate_hz), proposed


def offered(dev: Any, attr: str) -> tuple[float, ...]:
    """A ``Device`` list property, () where NI-DAQmx says the device has none."""
    import nidaqmx.errors

    try:
        return tuple(float(v) for v in getattr(dev, attr))
    except nidaqmx.errors.DaqError:
        return ()


def _norm(model: str) -> str:
    return "".join(ch for ch in model.upper() if ch.isalnum())


def ni_slots(ni: Any, rf: RigFile) -> list[ModuleSlot]:
    """The rig's modules as the devices report them (model, AI count, IEPE currents,
    excitation voltages).

    Raises
    ------
    DeviceNotFoundError
        A module the rig file names is not there.
    SetupError
        A device whose product type is not the rig file's model.
    """
    present = {d.name: d for d in ni.system.System.local().devices}
    if rf.daq.modules:
        named = [(m.name, m.model, list(m.inputs)) for m in rf.daq.modules]
    else:
        units = list(rf.daq.units) or list(present)[:1]
        named = [(u, "", []) for u in units]
    missing = [n for n, _m, _i in named if n not in present]
    if not named or missing:
        raise DeviceNotFoundError(
            f"{_WHERE}: NI device(s) {', '.join(missing) or '(none)'} not found (NI-DAQmx sees "
            f"{', '.join(present) or 'none'}); name them in [[daq.modules]] of {rf.path}"
        )
    slots: list[ModuleSlot] = []
    nxt = 0
    for i, (name, model, inputs) in enumerate(named):
        dev = present[name]
        product = str(dev.product_type)
        item = f"rig file {rf.path}, daq.modules.{i}"
        if model and _norm(model) != _norm(product):
            raise SetupError(
                f"{item}: {name} is an {product}, not the {model} the rig file says; correct "
                "model (or cable the module it names)"
            )
        n = len(dev.ai_physical_chans)
        slot = ModuleSlot(
            name,
            product,
            slot_inputs(inputs, nxt, n, item),
            n,
            offered(dev, "ai_current_int_excit_discrete_vals"),
            offered(dev, "ai_voltage_int_excit_discrete_vals"),
        )
        no_overlap(slots, slot, item)
        slots.append(slot)
        nxt = max(slot.inputs) + 1
    return slots


def open_daq(ctx: DeviceContext) -> Any:
    """The table entry ``"nidaqmx"``: a :class:`~dimacq.drivers.ni.task.NiDsaTask`."""
    from dimacq.drivers.ni.task import NiDsaTask

    ni = import_nidaqmx()
    slots = ni_slots(ni, ctx.rig_file)
    task = NiDsaTask(
        ni,
        slots,
        start_trigger=ctx.settings.daq_ni_start_trigger,
        sample_clock_out=ctx.settings.daq_ni_sample_clock_out,
    )
    ctx.on_close(task.close)
    return task


def ni_devices() -> tuple[list[dict[str, Any]], str]:
    """The NI devices NI-DAQmx sees (``name``, ``model``, ``serial``, ``chassis``, ``slot``,
    ``ai``), and why none can be listed ("" when they could)."""
    try:
        ni = import_nidaqmx()
    except (SetupError, DeviceNotFoundError) as err:
        return [], str(err)
    out = []
    for d in ni.system.System.local().devices:
        row: dict[str, Any] = {"name": d.name, "model": "", "serial": "", "chassis": "", "ai": 0}
        try:
            row["model"] = str(d.product_type)
            row["serial"] = f"{int(d.dev_serial_num):X}"
            row["ai"] = len(d.ai_physical_chans)
            row["chassis"] = str(d.compact_daq_chassis_device.name)
        except ni.errors.DaqError:  # not a cDAQ module (no chassis), or a property it lacks
            pass
        out.append(row)
    return out, ""
