"""``dimacq devices list``: what this PC has, each with the setting that uses it (issue 23)."""

from __future__ import annotations

import json
from pathlib import Path

from dimacq.backends.inventory import inventory, serial_by_id
from dimacq.cli.main import main


def test_serial_ports_are_named_by_their_stable_link(tmp_path: Path) -> None:
    dev = tmp_path / "dev"
    dev.mkdir()
    (dev / "ttyUSB3").write_text("")
    by_id = tmp_path / "by-id"
    by_id.mkdir()
    link = by_id / "usb-FTDI_FT232R_USB_UART_A10K1234-if00-port0"
    link.symlink_to(dev / "ttyUSB3")
    assert serial_by_id(by_id) == {str((dev / "ttyUSB3").resolve()): str(link)}
    assert serial_by_id(tmp_path / "absent") == {}


def test_devices_list_names_the_settings(tmp_path: Path, capsys) -> None:
    out = tmp_path / "devices.json"
    assert main(["devices", "list", "--json", str(out)]) == 0
    printed = capsys.readouterr().out
    got = json.loads(out.read_text())
    assert set(got) == {"serial", "usb", "can", "notes", "ni"}
    assert f"serial ports ({len(got['serial'])})" in printed
    for s in got["serial"]:
        assert s["setting"].startswith("digitizer_url = ")
    for u in got["usb"]:
        assert len(u["vid"]) == 4 and u["setting"].startswith("daq = ")
    # python-can's virtual interface is the simulated lab's: asked for, it is found and named
    inv = inventory(can_interfaces=("virtual",))
    assert inv.can and inv.can[0]["interface"] == "virtual"
    assert inv.can[0]["setting"].startswith("loadcell_interface = 'virtual'")


def test_devices_list_says_why_no_ni_device_is_listed(monkeypatch, capsys) -> None:
    """nidaqmx installed without NI-DAQmx (as here and on CI), or not installed at all."""
    import sys

    from dimacq.backends.ni_daqmx import ni_devices

    _found, why = ni_devices()
    if why:  # no NI-DAQmx here: the note says so, nothing is listed
        inv = inventory(can_interfaces=())
        assert inv.ni == [] and f"NI devices: {why}" in inv.notes
    monkeypatch.setitem(sys.modules, "nidaqmx", None)
    assert main(["devices", "list"]) == 0
    printed = capsys.readouterr().out
    assert "NI devices (0):" in printed
    assert (
        "note: NI devices: daq = 'nidaqmx': the Python package nidaqmx is not installed" in printed
    )
