"""``dimacq devices list [--json OUT]``: the serial ports, USB devices, CAN interfaces and NI
devices this PC has, each with the setting that uses it (:mod:`dimacq.backends.inventory`;
nothing is opened). ``dimacq devices plan --daq nidaqmx [--rig-file PATH]``: the NI cDAQ task
the rig file asks for (modules, channels, IEPE currents, excitation, the rate the modules run
at, each module's input delay) from NI's published figures, without hardware, nidaqmx or
NI-DAQmx; exit status 1 when the hardware would refuse part of it (each item named with its fix).

Serial ports are named by their stable ``/dev/serial/by-id`` link where udev made one; USB
devices by vendor and product id (hex: the ``daq_vendor_id`` / ``daq_product_id`` settings);
CAN channels by python-can interface and channel; NI devices by NI-DAQmx. What could not be
looked at (no libusb, an adapter library missing, no nidaqmx or NI-DAQmx) is listed with the
reason.

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
        help="the serial ports, USB devices, CAN interfaces and NI devices found on this PC; "
        "the NI cDAQ plan of the rig file",
        description=plain(__doc__),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    sub = p.add_subparsers(dest="devices_command", metavar="ACTION")
    sub.required = True
    ls = sub.add_parser("list", help="list them, each with the setting that uses it")
    ls.add_argument("--json", type=Path, default=None, metavar="OUT", help="write them as JSON")
    ls.set_defaults(func=run)
    pl = sub.add_parser(
        "plan",
        help="the DAQ task the rig file asks for, from the vendor's published figures (no "
        "hardware needed)",
    )
    pl.add_argument("--daq", choices=["nidaqmx"], default="nidaqmx", help="the DAQ backend")
    pl.add_argument(
        "--rig-file", type=Path, default=None, metavar="PATH", help="default: the settings' rig"
    )
    pl.add_argument(
        "--no-loadcells",
        action="store_true",
        help="leave the load cells' daq_channels out (cells on CAN)",
    )
    pl.add_argument("--json", type=Path, default=None, metavar="OUT", help="write it as JSON")
    pl.set_defaults(func=run_plan)
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
    out.write(f"NI devices ({len(inv.ni)}):\n")
    for d in inv.ni:
        where = f" in {d['chassis']}" if d["chassis"] else ""
        out.write(f"  {d['name']}: {d['model']}{where}, {d['ai']} AI, serial {d['serial']}\n")
        out.write(f"    {d['setting']}\n")
    for n in inv.notes:
        out.write(f"note: {n}\n")
    if args.json is not None:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(inv.to_json(), indent=2) + "\n", encoding="utf-8")
    return 0


def run_plan(args: argparse.Namespace) -> int:
    from dimacq.backends.ni_daqmx import plan_rig
    from dimacq.config import load_settings
    from dimacq.io.rig_file import load_rig_file

    path = args.rig_file if args.rig_file is not None else load_settings().rig_path
    rf = load_rig_file(path)
    plan, proposed = plan_rig(rf, with_loadcells=not args.no_loadcells)
    out = sys.stdout
    for line in plan_lines(plan, proposed, str(rf.path)):
        out.write(line + "\n")
    if args.json is not None:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(plan_json(plan, proposed), indent=2) + "\n", "utf-8")
    return 0 if plan.ok else 1


def plan_lines(plan: Any, proposed: bool, rig: str) -> list[str]:
    """The plan as the dry run prints it."""
    lines = [
        f"NI cDAQ plan of {rig} (dry run: NI's published figures, no hardware)",
        "modules"
        + (
            " (proposed from the catalogue: the rig file has no [[daq.modules]]):"
            if proposed
            else ":"
        ),
    ]
    for s in plan.slots:
        used = [c for c in plan.channels if c.slot == s]
        spec = s.spec
        delay = next((c.delay_s for c in used if c.delay_s is not None), None)
        d = (
            f", input delay {spec.delay_samples:g}/fs + {spec.analog_delay_s * 1e6:g} us = "
            f"{delay * 1e3:.4f} ms"
            if spec is not None and delay is not None
            else ""
        )
        lines.append(
            f"  {s.device}: {s.model}, {_on_ai(s.describe_inputs(), len(s.inputs))} "
            f"(of {s.n_channels} AI){d}"
        )
    if plan.rate_hz is not None and plan.timebase_hz is not None:
        lines.append(
            f"rate: asked {plan.asked_rate_hz:g} Hz -> {plan.rate_hz:.6g} Hz (fM "
            f"{plan.timebase_hz / 1e6:g} MHz of {plan.timebase_device} / 256 / "
            f"{round(plan.timebase_hz / 256 / plan.rate_hz)}); every block and FRF line uses it"
        )
    else:
        lines.append(f"rate: asked {plan.asked_rate_hz:g} Hz -> not known (see the refusals)")
    lines.append("channels:")
    for c in plan.channels:
        r = c.request
        if c.refusal:
            what = "REFUSED (below)"
        elif r.kind == "bridge":
            what = f"full bridge, mV/V, internal excitation {c.excitation_v:g} V"
        elif c.iepe_current_a > 0:
            what = f"IEPE {c.iepe_current_a * 1e3:g} mA, {r.coupling}"
        else:
            what = f"IEPE off, {r.coupling}"
        d = f", delay {c.delay_s * 1e3:.4f} ms" if c.delay_s is not None else ""
        lines.append(f"  {r.input:3d} {r.name:<14} {c.physical:<15} {r.kind:<7} {what}{d}")
    spread = plan.delay_spread_s()
    if spread is not None and plan.rate_hz is not None:
        band = 0.32 * plan.rate_hz
        lines.append(
            f"delays: the modules' input delays differ by {spread * 1e6:.2f} us "
            f"({360.0 * band * spread:.1f} deg at {band:g} Hz, the band's top) before "
            "compensation; the task removes each channel's (NI-DAQmx ai_remove_filter_delay "
            "+ ai_filter_delay_adjustment up to the published figure)"
        )
    lines.append(
        "sample clock: exported to daq_ni_sample_clock_out when set (export_signals."
        "samp_clk_output_term); start trigger: daq_ni_start_trigger"
    )
    if plan.refusals:
        lines.append(f"refused ({len(plan.refusals)}):")
        groups: dict[str, list[str]] = {}
        for r in plan.refusals:
            item, _, why = r.partition(": ")
            for part in why.split("; and "):  # one line per field refused, its inputs together
                groups.setdefault(part, []).append(item)
        for why, items in groups.items():
            who = items[0] if len(items) == 1 else f"{items[0]} .. {items[-1]} ({len(items)})"
            lines.append(f"  {who}: {why}")
    else:
        lines.append("ok: nothing in the plan is refused")
    return lines


def _on_ai(inputs: str, n: int) -> str:
    return f"input {inputs} on ai0" if n == 1 else f"inputs {inputs} on ai0..ai{n - 1}"


def plan_json(plan: Any, proposed: bool) -> dict[str, Any]:
    return {
        "proposed_modules": proposed,
        "asked_rate_hz": plan.asked_rate_hz,
        "rate_hz": plan.rate_hz,
        "timebase_hz": plan.timebase_hz,
        "timebase_device": plan.timebase_device,
        "modules": [
            {"name": s.device, "model": s.model, "inputs": list(s.inputs), "ai": s.n_channels}
            for s in plan.slots
        ],
        "channels": [
            {
                "input": c.request.input,
                "name": c.request.name,
                "kind": c.request.kind,
                "physical": c.physical,
                "iepe_current_a": c.iepe_current_a,
                "excitation_v": c.excitation_v,
                "delay_s": c.delay_s,
            }
            for c in plan.channels
        ],
        "refusals": list(plan.refusals),
    }
