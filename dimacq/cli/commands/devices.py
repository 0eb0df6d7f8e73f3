"""``dimacq devices list [--json OUT]``: the serial ports, USB devices and CAN interfaces this PC
has, each with the setting that uses it (:mod:`dimacq.backends.inventory`; nothing is opened).

Serial ports are named by their stable ``/dev/serial/by-id`` link where udev made one; USB
devices by vendor and product id (hex: the ``daq_vendor_id`` / ``daq_product_id`` settings);
CAN channels by python-can interface and channel. What could not be looked at (no libusb, an
adapter library missing) is listed with the reason.
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
