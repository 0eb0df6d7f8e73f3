"""Backend ``daq = "dimacq-usb"``: the dimacq USB DAQ through pyusb.

The pyusb backend is ``daq_backend``: ``"libusb"`` (pyusb's default: libusb1, libusb0 or openusb,
whichever is installed) or ``"package.module:factory"``, a function returning a pyusb backend
object. The device is found by ``daq_vendor_id``/``daq_product_id`` and, when the rig file's
``[daq] serial_number`` is given, by its serial number.
"""

from __future__ import annotations

from typing import Any

from dimacq.backends import import_factory
from dimacq.backends.base import DeviceContext
from dimacq.drivers.daq.driver import DaqDevice, DaqTask
from dimacq.errors import DeviceNotFoundError, SetupError

__all__ = ["open_daq", "open_on_backend", "pyusb_backend"]


def pyusb_backend(name: str) -> Any:
    """The pyusb backend ``daq_backend`` names: None for ``"libusb"``, else what the factory
    ``"package.module:factory"`` returns.

    Raises
    ------
    SetupError
        The factory cannot be imported, or returns None.
    """
    if name == "libusb":
        return None
    backend = import_factory(name, setting="daq_backend")()
    if backend is None:
        raise SetupError(
            f"daq_backend = {name!r}: the factory returned None; it must return a pyusb backend "
            "object (usb.backend.IBackend)"
        )
    return backend


def open_on_backend(ctx: DeviceContext, backend: Any, where: str) -> DaqTask:
    """Find the DAQ on ``backend`` (the rig file's serial number if given), open it, return an
    empty task on it; the device's closer goes to ``ctx``.

    Raises
    ------
    DeviceNotFoundError
        No USB library or no such device; the message starts with ``where`` (the settings).
    """
    import usb.core

    settings, rig_file = ctx.settings, ctx.rig_file
    vid, pid = settings.daq_vendor_id, settings.daq_product_id
    where = f"{where}, USB {vid:04x}:{pid:04x} (daq_vendor_id/daq_product_id)"
    try:
        devices = list(
            usb.core.find(find_all=True, idVendor=vid, idProduct=pid, backend=backend) or []
        )
    except usb.core.NoBackendError as err:
        raise DeviceNotFoundError(
            f"{where}: pyusb finds no USB library on this machine ({err}); install libusb-1.0 "
            "(e.g. apt install libusb-1.0-0) or set daq (DIMACQ_DAQ) to 'simulated' or "
            "daq_backend to a backend factory"
        ) from err
    timeout = rig_file.daq.timeout_s
    serial = rig_file.daq.serial_number
    daq = _first(devices, serial, timeout)
    if daq is not None:
        # re-enumerated (a new address, maybe another bus): found again by its serial number
        ident = serial or daq.identify().serial_number

        def reopen() -> DaqDevice:
            found = usb.core.find(find_all=True, idVendor=vid, idProduct=pid, backend=backend)
            again = _first(list(found or []), ident, timeout)
            if again is None:
                raise DeviceNotFoundError(f"{where}: DAQ {ident!r} is not on the bus")
            return again

        task = DaqTask(daq, "impact", reopen=reopen)
        ctx.on_close(lambda: task.device.close())
        return task
    wanted = (
        f" with serial number {serial!r} ([daq] serial_number of {rig_file.path})" if serial else ""
    )
    seen = f" ({len(devices)} other DAQ found)" if devices else ""
    raise DeviceNotFoundError(
        f"{where}: no DAQ{wanted} found{seen}; check the cable, the power and the USB "
        "permissions (udev rule), correct daq_vendor_id/daq_product_id, or set daq "
        "(DIMACQ_DAQ) = 'simulated'"
    )


def _first(devices: list[Any], serial: str, timeout_s: float) -> DaqDevice | None:
    """The first of ``devices`` with serial number ``serial`` ("" : any), opened."""
    for dev in devices:
        daq = DaqDevice(dev, timeout_s=timeout_s)
        try:
            if serial and daq.identify().serial_number != serial:
                daq.close()
                continue
        except BaseException:
            daq.close()
            raise
        return daq
    return None


def open_daq(ctx: DeviceContext) -> DaqTask:
    """The table entry ``"dimacq-usb"``."""
    name = ctx.settings.daq_backend
    return open_on_backend(ctx, pyusb_backend(name), f"daq = 'dimacq-usb', daq_backend = {name!r}")
