"""Backend ``daq = "nidaqmx"``: NI DSA devices through the official ``nidaqmx`` API.

Optional: ``pip install "dimacq[ni]"`` and NI-DAQmx (the driver runtime, from NI) on the
machine. The rig file's ``[daq] units`` names the NI devices (``"cDAQ1Mod1"``, ``"Dev1"``) in
channel order; physical channel ``k`` is the ``k``-th of their AI channels. ``daq_ni_start_trigger``
(a terminal such as ``"/cDAQ1/PFI0"``) makes the task start on that digital edge. **No simulated
twin**: tested here only up to opening (the one-line errors below); see the README.
"""

from __future__ import annotations

from typing import Any

from dimacq.backends.base import DeviceContext
from dimacq.errors import DeviceNotFoundError, SetupError

__all__ = ["import_nidaqmx", "open_daq"]

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


def open_daq(ctx: DeviceContext) -> Any:
    """The table entry ``"nidaqmx"``: a :class:`~dimacq.drivers.ni.task.NiDsaTask`."""
    from dimacq.drivers.ni.task import NiDsaTask

    ni = import_nidaqmx()
    rig = ctx.rig_file
    local = ni.system.System.local()
    present = [d.name for d in local.devices]
    units = list(rig.daq.units) or present[:1]
    missing = [u for u in units if u not in present]
    if not units or missing:
        raise DeviceNotFoundError(
            f"{_WHERE}: NI device(s) {', '.join(missing) or '(none)'} not found (NI-DAQmx sees "
            f"{', '.join(present) or 'none'}); name them in [daq] units of {rig.path}"
        )
    channels = [ch.name for u in units for ch in ni.system.Device(u).ai_physical_chans]
    return NiDsaTask(ni, channels, tuple(units), start_trigger=ctx.settings.daq_ni_start_trigger)
