"""What this PC has that dimacq can talk to: serial ports, USB devices, CAN interfaces and NI
devices.

The answers of ``dimacq devices list``: each entry names what to put in the settings to use it
(``digitizer_url``, ``daq``, ``loadcell_interface``/``loadcell_channel``); a USB device is offered
only to a backend that knows its vendor/product id (the others are counted in a note). Serial ports are named by their stable ``/dev/serial/by-id`` link where
there is one (the ``/dev/ttyUSB0`` number changes with the plugging order). Nothing is opened:
serial ports are listed by pyserial, USB devices by pyusb (descriptors only, no claim), CAN
interfaces by python-can's ``detect_available_configs`` (the real interfaces only; ``virtual``
is the simulated lab's), NI devices by NI-DAQmx (``nidaqmx.system.System.local().devices``;
where nidaqmx or NI-DAQmx is missing, the note says which).
"""

from __future__ import annotations

import logging
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

log = logging.getLogger(__name__)

__all__ = ["CAN_INTERFACES", "Inventory", "inventory", "serial_by_id", "usb_setting"]

#: python-can interfaces asked for their channels (those a lab's adapters use).
CAN_INTERFACES = ("socketcan", "pcan", "kvaser", "vector", "ixxat", "gs_usb", "slcan", "nican")


@dataclass(frozen=True)
class Inventory:
    """``serial``: ``port``, ``by_id``, ``description``, ``hwid``, ``setting``; ``usb``: ``vid``,
    ``pid`` (hex), ``bus``, ``address``, ``setting``; ``can``: ``interface``, ``channel``,
    ``setting``; ``ni``: ``name``, ``model``, ``serial``, ``chassis``, ``ai``, ``setting``;
    ``notes``: what could not be looked at, and why."""

    serial: list[dict[str, Any]]
    usb: list[dict[str, Any]]
    can: list[dict[str, Any]]
    notes: list[str]
    ni: list[dict[str, Any]] = field(default_factory=list)

    def to_json(self) -> dict[str, Any]:
        return asdict(self)


def serial_by_id(folder: Path = Path("/dev/serial/by-id")) -> dict[str, str]:
    """Device path → its ``/dev/serial/by-id`` link (the stable name), where udev made one."""
    out: dict[str, str] = {}
    if not folder.is_dir():
        return out
    for link in sorted(folder.iterdir()):
        try:
            out[str(link.resolve())] = str(link)
        except OSError:
            continue
    return out


def _serial(notes: list[str], by_id_folder: Path) -> list[dict[str, Any]]:
    try:
        from serial.tools import list_ports
    except ImportError as err:  # pragma: no cover - pyserial is a dependency
        notes.append(f"serial ports: pyserial unavailable ({err})")
        return []
    links = serial_by_id(by_id_folder)
    out = []
    for p in sorted(list_ports.comports(), key=lambda p: p.device):
        stable = links.get(str(Path(p.device).resolve()), "")
        out.append(
            {
                "port": p.device,
                "by_id": stable,
                "description": p.description if p.description != "n/a" else "",
                "hwid": p.hwid if p.hwid != "n/a" else "",
                "setting": f"digitizer_url = {stable or p.device!r}",
            }
        )
    return out


def _usb(notes: list[str]) -> list[dict[str, Any]]:
    try:
        import usb.core
    except ImportError as err:  # pragma: no cover - pyusb is a dependency
        notes.append(f"USB devices: pyusb unavailable ({err})")
        return []
    try:
        found = list(usb.core.find(find_all=True))
    except usb.core.NoBackendError:
        notes.append(
            "USB devices: no libusb backend found; install libusb-1.0 (Debian: apt-get install "
            "libusb-1.0-0)"
        )
        return []
    except usb.core.USBError as err:
        notes.append(f"USB devices: {err} (permissions: see the README's udev step)")
        return []
    out = []
    unknown = 0
    for d in found:
        setting = usb_setting(int(d.idVendor), int(d.idProduct))
        if setting is None:
            unknown += 1
            continue
        out.append(
            {
                "vid": f"{d.idVendor:04x}",
                "pid": f"{d.idProduct:04x}",
                "bus": int(d.bus) if d.bus is not None else None,
                "address": int(d.address) if d.address is not None else None,
                "setting": setting,
            }
        )
    if unknown:
        notes.append(
            f"USB devices: {unknown} other device(s) (hubs, keyboards, ...) whose vendor/product "
            "id no dimacq backend knows: not offered"
        )
    return out


def usb_setting(vid: int, pid: int) -> str | None:
    """The backend that knows a USB device by its vendor/product id, or None: our DAQ
    (``"dimacq-usb"``, pid.codes 1209:da64), MCC's USB-1808(X) (``"mcc-usb"``, or ``"uldaq"``),
    the other devices MCC's uldaq drives (``"uldaq"``: its analogue-input DAQs, the DT9837)."""
    from dimacq.drivers.mcc import protocol as mcc
    from dimacq.drivers.mcc.uldaq_task import ULDAQ_USB_IDS

    if (vid, pid) == (0x1209, 0xDA64):
        return f"daq = 'dimacq-usb' (daq_vendor_id = 0x{vid:04x}, daq_product_id = 0x{pid:04x})"
    if vid == mcc.VENDOR_ID and pid in mcc.PRODUCT_IDS:
        return (
            f"daq = 'mcc-usb' ({mcc.PRODUCT_IDS[pid]}: its serial number in [daq] units), "
            "or daq = 'uldaq'"
        )
    if (vid, pid) in ULDAQ_USB_IDS:
        return f"daq = 'uldaq' ({ULDAQ_USB_IDS[vid, pid]}: its serial number in [daq] units)"
    return None


def _can(notes: list[str], interfaces: tuple[str, ...]) -> list[dict[str, Any]]:
    try:
        import can
    except ImportError as err:  # pragma: no cover - python-can is a dependency
        notes.append(f"CAN interfaces: python-can unavailable ({err})")
        return []
    out = []
    quiet = logging.getLogger("can")
    level = quiet.level
    quiet.setLevel(logging.ERROR)  # "library not found" of every absent adapter: not news here
    try:
        found = []
        for name in interfaces:
            try:
                found.append((name, can.detect_available_configs(interfaces=[name])))
            except Exception as err:  # an adapter library's own failure: note it, go on
                notes.append(f"CAN interface {name}: {type(err).__name__}: {err}")
    finally:
        quiet.setLevel(level)
    for name, configs in found:
        for c in configs:
            out.append(
                {
                    "interface": str(c.get("interface", name)),
                    "channel": str(c.get("channel", "")),
                    "setting": f"loadcell_interface = {c.get('interface', name)!r}, "
                    f"loadcell_channel = {str(c.get('channel', ''))!r}",
                }
            )
    return out


def inventory(
    *,
    by_id_folder: Path = Path("/dev/serial/by-id"),
    can_interfaces: tuple[str, ...] = CAN_INTERFACES,
) -> Inventory:
    """Serial ports, USB devices and CAN channels found now (nothing is opened)."""
    notes: list[str] = []
    serial = _serial(notes, by_id_folder)
    usb = _usb(notes)
    can = _can(notes, can_interfaces)
    ni = _ni(notes)
    return Inventory(serial=serial, usb=usb, can=can, notes=notes, ni=ni)


def _ni(notes: list[str]) -> list[dict[str, Any]]:
    """NI devices through NI-DAQmx, each with the rig file entry that uses it."""
    from dimacq.backends.ni_daqmx import ni_devices

    found, why = ni_devices()
    if why:
        notes.append(f"NI devices: {why}")
    for d in found:
        d["setting"] = (
            f"daq = 'nidaqmx'; [[daq.modules]] name = {d['name']!r}, model = {d['model']!r}"
        )
    return found
