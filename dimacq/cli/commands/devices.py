"""``dimacq devices list [--json OUT]``: the serial ports, USB devices and CAN interfaces this PC
has, each with the setting that uses it (:mod:`dimacq.backends.inventory`; nothing is opened).

Serial ports are named by their stable ``/dev/serial/by-id`` link where udev made one; USB
devices by vendor and product id (hex: the ``daq_vendor_id`` / ``daq_product_id`` settings);
CAN channels by python-can interface and channel. What could not be looked at (no libusb, an
adapter library missing) is listed with the reason.

``dimacq devices mcc-fpga [SOURCE] -o USB_1808.bin``: the USB-1808(X)'s binary FPGA image (the
``daq_fpga_file`` of ``daq = "mcc-usb"``) from the C array MCC publishes it as (uldaq's
``src/usb/fw/Usb1808Fpga.c``, or Warren Jasper's ``usb-1808.rbf``), from a ``libuldaq.so`` file,
or, without SOURCE, from the installed libuldaq; its form is checked before it is written.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from dimacq.cli.progress import plain


def register(subparsers: Any) -> None:
    p = subparsers.add_parser(
        "devices",
        help="the serial ports, USB devices and CAN interfaces found on this PC",
        description=plain(__doc__),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    sub = p.add_subparsers(dest="devices_command", metavar="ACTION")
    sub.required = True
    ls = sub.add_parser("list", help="list them, each with the setting that uses it")
    ls.add_argument("--json", type=Path, default=None, metavar="OUT", help="write them as JSON")
    ls.set_defaults(func=run)
    fw = sub.add_parser(
        "mcc-fpga",
        help="write the USB-1808(X) FPGA image (binary) from uldaq's C source or libuldaq",
    )
    fw.add_argument(
        "source",
        nargs="?",
        type=Path,
        default=None,
        help="Usb1808Fpga.c, usb-1808.rbf or libuldaq.so (default: the installed libuldaq)",
    )
    fw.add_argument("-o", "--output", type=Path, required=True, metavar="OUT")
    fw.set_defaults(func=run_mcc_fpga)


def run_mcc_fpga(args: argparse.Namespace) -> int:
    """Extract, check and write the image; 0, or 2 with a one-line error."""
    import hashlib

    from dimacq.drivers.mcc import fpga
    from dimacq.drivers.mcc import protocol as p

    src: Path | None = args.source
    try:
        if src is None:
            found = fpga.image_from_library()
            if found is None:
                raise ValueError(
                    "no installed libuldaq holds a USB-1808 image; give uldaq's "
                    "src/usb/fw/Usb1808Fpga.c as SOURCE"
                )
            image, where = found
        else:
            raw = src.read_bytes()
            if raw[:4] == b"\x7fELF" or src.suffix in (".so", ".dylib"):
                hit = fpga.image_from_library([src])
                if hit is None:
                    raise ValueError(f"{src} holds no USB-1808 image we know")
                image, where = hit
            elif b"\x00" not in raw[:4096]:
                image, where = fpga.c_array_bytes(raw.decode("utf-8", "replace")), str(src)
            else:
                image, where = raw, str(src)
        p.check_fpga_image(image, where)
    except (OSError, ValueError) as err:
        sys.stderr.write(f"dimacq devices mcc-fpga: error: {err}\n")
        return 2
    args.output.parent.mkdir(parents=True, exist_ok=True)
    args.output.write_bytes(image)
    digest = hashlib.sha256(image).hexdigest()
    known = fpga.KNOWN_IMAGES.get(digest, "form checked; not one of the images we know")
    sys.stdout.write(
        f"{args.output}: {len(image)} bytes from {where}\nsha256 {digest} ({known})\n"
        f"set daq_fpga_file (DIMACQ_DAQ_FPGA_FILE) = {str(args.output)!r}\n"
    )
    return 0


def run(args: argparse.Namespace) -> int:
    from dimacq.backends.inventory import inventory

    inv = inventory()
    out = sys.stdout
    out.write(f"serial ports ({len(inv.serial)}):\n")
    for s in inv.serial:
        name = s["by_id"] or s["port"]
        desc = f"  {s['description']}" if s["description"] else ""
        out.write(f"  {name}{desc}\n    {s['setting']}\n")
    out.write(f"USB devices ({len(inv.usb)}):\n")
    for u in inv.usb:
        out.write(f"  {u['vid']}:{u['pid']} (bus {u['bus']}, address {u['address']})\n")
        out.write(f"    {u['setting']}\n")
    out.write(f"CAN channels ({len(inv.can)}):\n")
    for c in inv.can:
        out.write(f"  {c['interface']} {c['channel']}\n    {c['setting']}\n")
    for n in inv.notes:
        out.write(f"note: {n}\n")
    if args.json is not None:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(inv.to_json(), indent=2) + "\n", encoding="utf-8")
    return 0
