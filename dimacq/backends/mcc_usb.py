"""Backend ``daq = "mcc-usb"``: Measurement Computing USB-1808X units through pyusb.

The units are found on the pyusb backend ``daq_backend`` (``"libusb"`` or a factory, as for
``"dimacq-usb"``) by MCC's vendor id 0x09DB and the USB-1808 / USB-1808X product ids; the rig
file's ``[daq] units`` lists their serial numbers in channel order (inputs 0..7 on the first,
the clock master; 8..15 on the second; ...), ``[]`` takes the one unit found. A unit whose FPGA
is not loaded (after power-up) gets the binary Spartan-6 image (:mod:`dimacq.drivers.mcc.fpga`):
``daq_fpga_file`` when set (``USB_1808.bin``: ``dimacq devices mcc-fpga`` makes it from uldaq's
``src/usb/fw/Usb1808Fpga.c``), else the image inside an installed libuldaq.
The driver is :mod:`dimacq.drivers.mcc.driver`; the wiring of several units (master's ICLKO to
each slave's clock input) is described there.
"""

from __future__ import annotations

from typing import Any

from dimacq.backends.base import DeviceContext
from dimacq.backends.usb_daq import pyusb_backend
from dimacq.drivers.mcc import protocol as p
from dimacq.drivers.mcc.driver import MccTask, Usb1808
from dimacq.drivers.mcc.fpga import image_from_library, read_image
from dimacq.errors import DeviceNotFoundError, SetupError

__all__ = ["open_daq", "open_units"]


def open_units(
    ctx: DeviceContext,
    backend: Any,
    where: str,
    fpga_image: tuple[bytes, str] | None,
    cabled: list[str] | None = None,
) -> MccTask:
    """The rig file's units on ``backend``, FPGA loaded, as one task (closers to ``ctx``).

    ``cabled``: the units' order when the rig file gives none (the simulated lab's cabling).

    Raises
    ------
    DeviceNotFoundError
        No USB library, or a unit of ``[daq] units`` is not on the bus.
    SetupError
        Several units but no ``[daq] units``; an FPGA to load and no ``daq_fpga_file``.
    """
    import usb.core

    rig = ctx.rig_file
    timeout = rig.daq.timeout_s
    try:
        found = [
            d
            for d in usb.core.find(find_all=True, idVendor=p.VENDOR_ID, backend=backend) or []
            if int(d.idProduct) in p.PRODUCT_IDS
        ]
    except usb.core.NoBackendError as err:
        raise DeviceNotFoundError(
            f"{where}: pyusb finds no USB library ({err}); install libusb-1.0 (apt install "
            "libusb-1.0-0) or set daq (DIMACQ_DAQ) = 'mcc-usb-simulated'"
        ) from err
    opened = [Usb1808(d, timeout_s=timeout) for d in found]
    for u in opened:
        ctx.on_close(u.close)
    by_serial = {u.serial_number(): u for u in opened}
    wanted = list(rig.daq.units) or list(cabled or [])
    if not opened:
        raise DeviceNotFoundError(
            f"{where}: no USB-1808 unit (USB 09db:013d/013e) found; check the cable, the power "
            "and the udev rule (config/udev), or set daq (DIMACQ_DAQ) = 'mcc-usb-simulated'"
        )
    if not wanted:
        if len(opened) > 1:
            raise SetupError(
                f"{where}: {len(opened)} USB-1808 units found ({', '.join(sorted(by_serial))}); "
                f"list their serial numbers in channel order as [daq] units in {rig.path}"
            )
        wanted = list(by_serial)
    missing = [s for s in wanted if s not in by_serial]
    if missing:
        raise DeviceNotFoundError(
            f"{where}: USB-1808 unit(s) {', '.join(missing)} of [daq] units ({rig.path}) not on "
            f"the bus (found: {', '.join(sorted(by_serial)) or 'none'}); check cables and power"
        )
    units = [by_serial[s] for s in wanted]
    for u in units:
        if not u.status() & p.Status.FPGA_CONFIGURED:
            image, source = fpga_image if fpga_image is not None else _fpga_image(ctx, where)
            u.configure_fpga(image, source)
    task = MccTask(units, "impact")
    return task


def _fpga_image(ctx: DeviceContext, where: str) -> tuple[bytes, str]:
    """``daq_fpga_file``'s image, else the one in an installed libuldaq, form checked."""
    name = ctx.settings.daq_fpga_file
    if name:
        return read_image(name), name
    found = image_from_library()
    if found is None:
        raise SetupError(
            f"{where}: the USB-1808X's FPGA is not loaded (after power-up) and no libuldaq with "
            "its image is installed; set daq_fpga_file (DIMACQ_DAQ_FPGA_FILE) to USB_1808.bin "
            "(dimacq devices mcc-fpga Usb1808Fpga.c -o USB_1808.bin, from github.com/mccdaq/uldaq "
            "src/usb/fw) or install libuldaq"
        )
    return found


def open_daq(ctx: DeviceContext) -> MccTask:
    """The table entry ``"mcc-usb"``."""
    name = ctx.settings.daq_backend
    where = f"daq = 'mcc-usb', daq_backend = {name!r}"
    return open_units(ctx, pyusb_backend(name), where, None)
