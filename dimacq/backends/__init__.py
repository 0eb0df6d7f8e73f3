"""Device backend tables: which code opens each kind of device, chosen by a settings name.

Like python-can's ``BACKENDS`` (``can/interfaces/__init__.py``, looked up by ``can/interface.py``):
one table per device kind maps the name a setting gives to the factory that opens the device
and returns its :mod:`dimacq.devices` protocol type. The simulator is one more entry, reached
through its wire (a pyusb backend, a python-can ``virtual`` channel, a pyserial URL handler).

========== =================== ==================================================================
setting    name                what opens the device
========== =================== ==================================================================
``daq``    ``"dimacq-usb"``    :func:`dimacq.backends.usb_daq.open_daq`: the USB DAQ through pyusb
                               (``daq_backend``: ``"libusb"`` or a pyusb backend factory)
``daq``    ``"simulated"``     :func:`dimacq.backends.simulated.open_daq`: the same driver on the
                               virtual lab's pyusb backend (scenario ``scenario``)
``daq``    ``"mcc-usb"``       :func:`dimacq.backends.mcc_usb.open_daq`: Measurement Computing
                               USB-1808X unit(s) through pyusb (rig file ``[daq] units``)
``daq``    ``"mcc-usb-simulated"`` :func:`dimacq.backends.mcc_simulated.open_daq`: the same driver
                               on simulated USB-1808X units carrying the virtual lab
``daq``    ``"nidaqmx"``       :func:`dimacq.backends.ni_daqmx.open_daq`: NI DSA devices through
                               the ``nidaqmx`` API (extra ``[ni]``); no simulated twin
``daq``    ``"uldaq"``         :func:`dimacq.backends.mcc_uldaq.open_daq`: MCC devices (DT9837
                               IEPE DAQs, USB-1808X) through MCC's ``uldaq`` package (extra
                               ``[mcc]``, needs libuldaq); no simulated twin
``loadcell`` ``"dimacq-can"``  :func:`dimacq.backends.can_loadcell.open_loadcell`: the CAN FD
                               amplifier on ``can.Bus(interface=loadcell_interface, ...)``
``loadcell`` ``"simulated"``   :func:`dimacq.backends.simulated.open_loadcell`: the same driver on
                               a python-can ``virtual`` channel to the amplifier simulator
``loadcell`` ``"canopen"``     :func:`dimacq.backends.canopen_loadcell.open_loadcell`: a CANopen
                               amplifier (EDS ``loadcell_canopen_eds``) through ``canopen`` on
                               ``can.Bus(interface=loadcell_interface, bitrate=...)``
``loadcell`` ``"canopen-simulated"`` :func:`dimacq.backends.canopen_simulated.open_loadcell`: the
                               same driver on a ``virtual`` channel to CANopen simulators
``loadcell`` ``"daq-channels"`` :func:`dimacq.backends.daq_channels.open_loadcell`: the cell's
                               gauges (or six conditioned outputs) as inputs of the ``daq``
                               (the rig file's ``daq_channels``), on the DAQ's clock; simulated
                               when the DAQ is
``loadcell`` ``"netft-can"``   :func:`dimacq.backends.netft_can.open_loadcell`: an ATI Net F/T
                               on ``can.Bus(interface=loadcell_interface, ...)`` (rig file
                               ``netft_base`` and counts per unit)
``loadcell`` ``"netft-can-simulated"`` :func:`dimacq.backends.netft_simulated.open_loadcell`:
                               the same driver on a ``virtual`` channel to Net F/T simulators
``loadcell`` ``"netft-udp"``   :func:`dimacq.backends.netft_udp.open_loadcell`: an ATI Net F/T's
                               RDT over UDP (rig file ``netft_host``): identification and
                               readings only, refuses an acquisition on the DAQ's clock
``loadcell`` ``"netft-udp-simulated"`` :func:`dimacq.backends.netft_simulated.open_udp_loadcell`:
                               the same driver on loopback to an RDT simulator
``loadcell`` ``"cia404"``      :func:`dimacq.backends.cia404.open_loadcell`: generic CiA 404
                               amplifiers (EDS ``loadcell_cia404_eds``): process values mapped
                               into synchronous TPDOs by SDO, one shared ``can.Bus`` per channel
``loadcell`` ``"cia404-simulated"`` :func:`dimacq.backends.cia404_simulated.open_loadcell`: the
                               same code on a ``virtual`` channel to ``canopen.LocalNode``
                               simulators of the generic EDS and a SYNC producer on the DAQ's clock
``digitizer`` ``"serial"``     :func:`dimacq.backends.serial_digitizer.open_digitizer`: pyserial
                               URL ``digitizer_url``
``digitizer`` ``"simulated"``  :func:`dimacq.backends.simulated.open_digitizer`: the same driver on
                               the ``simdigitizer://`` URL handler
========== =================== ==================================================================

Any other name of the form ``"package.module:factory"`` is imported and called the same way
(:func:`lookup`): **adding a device kind is one entry here (or a setting naming the factory) and
one driver module**. Factories take a :class:`~dimacq.backends.base.DeviceContext` (settings, rig
file, what closes the devices) and, for load cells, the rig file's entry of the cell:

- DAQ: ``factory(ctx) -> dimacq.devices.daq.Daq`` (a task with no channels yet);
- load cell: ``factory(ctx, entry) -> dimacq.devices.loadcell.LoadCell`` (calibrated from the
  entry's calibration file);
- digitizer: ``factory(ctx) -> dimacq.devices.digitizer.Digitizer``.

Only this package (and command-line tools that are simulators by nature, e.g. ``dimacq
simulate``) imports :mod:`dimacq.simulators`; an import-linter contract in ``pyproject.toml``
says so.
"""

from __future__ import annotations

import importlib
from typing import Any, Literal

from dimacq.errors import SetupError

__all__ = ["BACKENDS", "DeviceKind", "is_simulated", "lookup"]

DeviceKind = Literal["daq", "loadcell", "digitizer", "loadcell-bench"]

#: kind → settings name → ``"module:factory"`` (imported when first used).
BACKENDS: dict[str, dict[str, str]] = {
    "daq": {
        "dimacq-usb": "dimacq.backends.usb_daq:open_daq",
        "simulated": "dimacq.backends.simulated:open_daq",
        "mcc-usb": "dimacq.backends.mcc_usb:open_daq",
        "mcc-usb-simulated": "dimacq.backends.mcc_simulated:open_daq",
        "nidaqmx": "dimacq.backends.ni_daqmx:open_daq",
        "uldaq": "dimacq.backends.mcc_uldaq:open_daq",
    },
    "loadcell": {
        "dimacq-can": "dimacq.backends.can_loadcell:open_loadcell",
        "simulated": "dimacq.backends.simulated:open_loadcell",
        "canopen": "dimacq.backends.canopen_loadcell:open_loadcell",
        "canopen-simulated": "dimacq.backends.canopen_simulated:open_loadcell",
        "daq-channels": "dimacq.backends.daq_channels:open_loadcell",
        "netft-can": "dimacq.backends.netft_can:open_loadcell",
        "netft-can-simulated": "dimacq.backends.netft_simulated:open_loadcell",
        "netft-udp": "dimacq.backends.netft_udp:open_loadcell",
        "netft-udp-simulated": "dimacq.backends.netft_simulated:open_udp_loadcell",
        "cia404": "dimacq.backends.cia404:open_loadcell",
        "cia404-simulated": "dimacq.backends.cia404_simulated:open_loadcell",
    },
    "digitizer": {
        "serial": "dimacq.backends.serial_digitizer:open_digitizer",
        "simulated": "dimacq.backends.simulated:open_digitizer",
    },
    # a load cell on the dead-weight calibration bench: the simulated one only (a real bench is
    # the configured amplifier, dimacq.backends.can_loadcell.open_amplifier, and a person)
    "loadcell-bench": {
        "simulated": "dimacq.backends.simulated:open_dead_weight_bench",
        "canopen-simulated": "dimacq.backends.canopen_simulated:open_dead_weight_bench",
    },
}


#: the modules whose factories open a simulator of the virtual lab, not a device
_SIMULATED_MODULES = frozenset(
    {
        "dimacq.backends.simulated",
        "dimacq.backends.canopen_simulated",
        "dimacq.backends.netft_simulated",
        "dimacq.backends.mcc_simulated",
        "dimacq.backends.cia404_simulated",
    }
)


def is_simulated(kind: DeviceKind, name: str) -> bool:
    """Whether the backend ``name`` of ``kind`` opens a simulator (``"simulated"``,
    ``"canopen-simulated"``): its factory (the table entry's, or the one a
    ``"package.module:factory"`` name gives) is in a simulated backend module."""
    path = BACKENDS[kind].get(name, name)
    return path.partition(":")[0] in _SIMULATED_MODULES


def import_factory(path: str, *, setting: str) -> Any:
    """``"package.module:attr.attr"`` → the callable it names.

    Raises
    ------
    SetupError
        Malformed, not importable or not callable; the message names ``setting``.
    """
    module_name, sep, attr = path.partition(":")
    if not sep or not module_name or not attr:
        raise SetupError(f"{setting} = {path!r}: give 'package.module:factory'")
    try:
        obj: Any = importlib.import_module(module_name)
        for part in attr.split("."):
            obj = getattr(obj, part)
    except (ImportError, AttributeError) as err:
        raise SetupError(
            f"{setting} = {path!r}: cannot import {attr!r} from module {module_name!r} ({err}); "
            "give the import path 'package.module:factory' of an installed module"
        ) from err
    if not callable(obj):
        raise SetupError(f"{setting} = {path!r}: {attr!r} is not callable; give a factory")
    return obj


def lookup(kind: DeviceKind, name: str) -> Any:
    """The factory of backend ``name`` for device ``kind``: a table entry, or
    ``"package.module:factory"``.

    Raises
    ------
    SetupError
        Unknown name (the message lists the table's names and names the setting).
    """
    table = BACKENDS[kind]
    if name in table:
        return import_factory(table[name], setting=kind)
    if ":" in name:
        return import_factory(name, setting=kind)
    raise SetupError(
        f"{kind} = {name!r} is not a known {kind} backend; give one of "
        f"{', '.join(repr(n) for n in table)} or 'package.module:factory' "
        f"(DIMACQ_{kind.upper()})"
    )
