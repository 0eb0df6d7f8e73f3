"""``daq = "mcc-usb"`` / ``"mcc-usb-simulated"`` (Measurement Computing USB-1808X) and
``daq = "nidaqmx"`` on the backend table: opening, identity, and the one-line errors of a
missing unit, an unordered set of units, an unloaded FPGA, a missing NI package or runtime."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

from dimacq.backends import BACKENDS, is_simulated, lookup
from dimacq.backends.base import DeviceContext
from dimacq.config import default_config_file, load_settings
from dimacq.drivers.mcc import fpga
from dimacq.errors import DeviceNotFoundError, SetupError
from dimacq.services.acquisition import rig as rig_builder
from dimacq.simulators.daq.backend import DaqInput
from dimacq.simulators.lab.scenarios import build_scenario
from dimacq.simulators.mcc.backend import Mcc1808Backend, lab_fpga_image


class _Quiet:
    sample_rate_hz = 2048.0
    channel_names = ("x",)
    channel_units = ("V",)

    def read(self, channels, start, n):  # type: ignore[no-untyped-def]
        import numpy as np

        return np.zeros((len(channels), n))

    def excite(self, input_index: int, at_sample: int) -> None:
        return None


def no_units() -> Mcc1808Backend:
    return Mcc1808Backend(_Quiet(), {}, n_units=0)


def two_units() -> Mcc1808Backend:
    return Mcc1808Backend(_Quiet(), {0: DaqInput(0, 1.0)}, n_units=2, fpga_configured=True)


def one_unloaded() -> Mcc1808Backend:
    return Mcc1808Backend(_Quiet(), {}, n_units=1, serials=["01F2A000"])


def _rig(tmp_path: Path, units: str = "") -> str:
    text = (default_config_file().parent / "rig.toml").read_text(encoding="utf-8")
    if units:
        text = text.replace('serial_number = ""', f'serial_number = ""\nunits = [{units}]', 1)
    tmp_path.mkdir(parents=True, exist_ok=True)
    (tmp_path / "rig.toml").write_text(text, encoding="utf-8")
    return str(tmp_path / "rig.toml")


def _open(tmp_path: Path, factory: str, units: str = "", **kw: str) -> object:
    settings = load_settings(
        data_dir=tmp_path,
        token="t",
        daq="mcc-usb",
        daq_backend=f"test_mcc_backend:{factory}",
        rig_file=_rig(tmp_path, units),
        **kw,
    )
    with DeviceContext(settings) as ctx:
        task = lookup("daq", "mcc-usb")(ctx)
        return task.identify()


def test_entries_in_the_table() -> None:
    assert {"mcc-usb", "mcc-usb-simulated", "nidaqmx"} <= set(BACKENDS["daq"])
    assert is_simulated("daq", "mcc-usb-simulated")
    assert not is_simulated("daq", "mcc-usb") and not is_simulated("daq", "nidaqmx")
    # a simulated DAQ comes with the simulated load cell
    assert load_settings(daq="mcc-usb-simulated").loadcell == "simulated"


@pytest.mark.slow
def test_devices_check_through_the_simulated_units(tmp_path: Path) -> None:
    settings = load_settings(data_dir=tmp_path, token="t", daq="mcc-usb-simulated")
    got = rig_builder.check_devices(settings, "daq")
    # the shipped rig: hammer 0, accelerometers 1..24, the cell's bridges 25..36: five units
    assert got["backend"] == "mcc-usb-simulated" and got["model"] == "USB-1808X ×5"
    assert (
        len(got["units"]) == 5
        and got["n_channels"] == 40
        and got["units"][0] == got["serial_number"]
    )


def test_one_line_errors_of_the_real_backend(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(fpga, "library_paths", lambda extra=(): [])  # no libuldaq here
    with pytest.raises(DeviceNotFoundError, match=r"no USB-1808 unit .*udev rule") as e:
        _open(tmp_path / "a", "no_units")
    assert "\n" not in str(e.value)
    with pytest.raises(SetupError, match=r"2 USB-1808 units found .* as \[daq\] units in"):
        _open(tmp_path / "b", "two_units")
    with pytest.raises(DeviceNotFoundError, match=r"unit\(s\) 0BADBEEF of \[daq\] units"):
        _open(tmp_path / "c", "two_units", units='"01F2A001", "0BADBEEF"')
    ident = _open(tmp_path / "d", "two_units", units='"01F2A001", "01F2A000"')
    assert ident.units == ("01F2A001", "01F2A000")  # type: ignore[attr-defined]
    with pytest.raises(SetupError, match=r"FPGA is not loaded .*set daq_fpga_file") as e:
        _open(tmp_path / "e", "one_unloaded")
    assert "\n" not in str(e.value)
    rbf = tmp_path / "USB_1808.bin"
    rbf.write_bytes(lab_fpga_image())
    ident = _open(tmp_path / "f", "one_unloaded", daq_fpga_file=str(rbf))
    assert ident.serial_number == "01F2A000"  # type: ignore[attr-defined]


@pytest.mark.slow
def test_bridge_inputs_need_an_amplifier(tmp_path: Path) -> None:
    """The load cell's bridges on ±0.1 V inputs: the USB-1808X has no such range."""
    settings = load_settings(
        data_dir=tmp_path, token="t", daq="mcc-usb-simulated", loadcell="daq-channels"
    )
    setup = build_scenario(settings.scenario).model.setup
    with pytest.raises(SetupError, match=r"range_v = 0.1 V; the USB-1808X has ±10 V and ±5 V"):
        rig = rig_builder.build_rig(settings, setup, {})
        rig.close()


def test_nidaqmx_package_missing(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "nidaqmx", None)
    monkeypatch.setitem(sys.modules, "nidaqmx.system", None)
    settings = load_settings(data_dir=tmp_path, token="t", daq="nidaqmx")
    with pytest.raises(
        SetupError, match=r"package nidaqmx is not installed; pip install 'dimacq\[ni\]'"
    ) as e:
        rig_builder.check_devices(settings, "daq")
    assert "\n" not in str(e.value)


def test_nidaqmx_runtime_missing(tmp_path: Path) -> None:
    """With the package (extra [ni]) and no NI-DAQmx on the machine, as on CI."""
    nidaqmx = pytest.importorskip("nidaqmx")
    try:
        nidaqmx.system.System.local().driver_version  # noqa: B018
    except nidaqmx.errors.DaqNotFoundError:
        pass
    else:
        pytest.skip("NI-DAQmx is installed here")
    settings = load_settings(data_dir=tmp_path, token="t", daq="nidaqmx")
    with pytest.raises(
        DeviceNotFoundError, match=r"NI-DAQmx \(the driver runtime\) is not installed"
    ) as e:
        rig_builder.check_devices(settings, "daq")
    assert "\n" not in str(e.value)


def test_cli_names_the_fix_without_a_traceback(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    from dimacq.cli.main import main

    monkeypatch.setitem(sys.modules, "nidaqmx", None)
    monkeypatch.setenv("DIMACQ_DAQ", "nidaqmx")
    argv = ["demo", "--no-chain-calibration", "--quiet", "--data-dir", str(tmp_path)]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err
    (line,) = [ln for ln in err.splitlines() if ln.startswith("dimacq demo: error:")]
    assert "pip install 'dimacq[ni]'" in line and "DIMACQ_DAQ" in line


def test_devices_list_offers_a_usb_device_only_to_a_backend_that_knows_it(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    import usb.core

    from dimacq.backends.inventory import inventory, usb_setting

    assert usb_setting(0x09DB, 0x013E) == (
        "daq = 'mcc-usb' (USB-1808X: its serial number in [daq] units), or daq = 'uldaq'"
    )
    assert usb_setting(0x1209, 0xDA64) == (
        "daq = 'dimacq-usb' (daq_vendor_id = 0x1209, daq_product_id = 0xda64)"
    )
    assert usb_setting(0x0867, 0x3998) == (
        "daq = 'uldaq' (DT9837A/B/C: its serial number in [daq] units)"
    )
    assert usb_setting(0x09DB, 0x0133) is None  # MCC's USB-DIO32HS: no analogue input
    assert usb_setting(0x046D, 0xC52B) is None  # a mouse receiver
    assert usb_setting(0x1D6B, 0x0002) is None  # a root hub

    class Dev:
        def __init__(self, vid: int, pid: int, address: int) -> None:
            self.idVendor, self.idProduct, self.bus, self.address = vid, pid, 1, address

    found = [Dev(0x1D6B, 0x0002, 1), Dev(0x046D, 0xC52B, 2), Dev(0x09DB, 0x013E, 3)]
    monkeypatch.setattr(usb.core, "find", lambda **kw: iter(found))
    inv = inventory(can_interfaces=())
    assert [(u["vid"], u["pid"]) for u in inv.usb] == [("09db", "013e")]
    assert any("2 other device(s)" in n and "not offered" in n for n in inv.notes)
