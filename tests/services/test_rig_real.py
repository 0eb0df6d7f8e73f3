"""The real-device branch of the acquisition rig, end to end without hardware.

Configuration only: ``daq = "dimacq-usb"`` (implied by the older setting ``daq_backend``) with
``daq_backend`` naming a pyusb backend factory returning the USB DAQ simulator fed by a virtual
lab, ``loadcell = "dimacq-can"`` with ``loadcell_interface = "virtual"`` with the load cell amplifier
simulator listening on ``loadcell_channel``, and ``rig_file`` maps the cabling (hammer on DAQ
input 40, accelerometers on shuffled inputs, the amplifier on CAN node 3). The operator strikes
when the service asks "strike input N". Checks the FRFs against the article's model, every
average handed over before the next strike, and the errors naming the setting.
"""

from __future__ import annotations

import itertools
import re
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from _real_rig_support import VirtualWorld, installed

from dimacq.cli.simulated_lab import model_frf
from dimacq.config import load_settings
from dimacq.errors import DeviceNotFoundError, SetupError
from dimacq.io.rig_file import load_rig_file
from dimacq.services.acquisition import rig as rig_builder

FACTORY = "_real_rig_support:daq_backend"
INPUTS = (0, 9, 17)
PROMPT = re.compile(r"^strike input (\d+): ")


def _settings(tmp_path: Path, world: VirtualWorld, **kw: Any) -> Any:
    values: dict[str, Any] = {
        "data_dir": tmp_path / "data",
        "token": "t",
        "digitizer_url": "simdigitizer://realrig?seed=1",
        "daq_backend": FACTORY,
        "loadcell_interface": "virtual",
        "loadcell_virtual_ok": True,  # a simulator on python-can's in-process bus
        "loadcell_channel": world.channel,
        "rig_file": str(world.rig_file),
    }
    return load_settings(**{**values, **kw})


def _check_frfs(frf: Any, world: VirtualWorld, tau: float) -> tuple[float, float]:
    """Relative error against the article's model where coherence > 0.99, 20..400 Hz: the
    worst per-output median and the 95th percentile of all kept values (a wrong channel,
    sensitivity, node id or calibration is off by far more than that)."""
    f = frf.frequencies_hz
    band = (f >= 20) & (f <= 400)
    H_true = model_frf(world.lab.model, f[band], tau)[:, :, list(world.inputs)]
    keep = frf.coherence[band] > 0.99
    assert keep.mean() > 0.9
    rel = np.abs(frf.H[band] - H_true) / np.abs(H_true)
    med = max(float(np.median(rel[:, o][keep[:, o]])) for o in range(rel.shape[1]))
    return med, float(np.quantile(rel[keep], 0.95))


def test_real_branch_on_simulators_at_the_wire(tmp_path: Path) -> None:
    world = VirtualWorld("calibration-mass-ground", INPUTS, tmp_path / "rig")
    with installed(world):
        settings = _settings(tmp_path, world)
        assert (settings.daq, settings.loadcell) == ("dimacq-usb", "dimacq-can")
        cfg = {"averages_per_input": 2, "record_samples": 2048}
        rig = rig_builder.build_rig(settings, world.setup, cfg)
        assert rig.operator is None  # a person strikes
        events: list[tuple[str, Any]] = []

        def on_progress(fraction: float, message: str) -> None:
            m = PROMPT.match(message)
            if m:
                events.append(("ask", int(m.group(1)) - 1))
                world.strike(int(m.group(1)) - 1)  # the test operator, when asked

        def on_average(j: int, _number: int, ok: bool, reasons: Any, rec: Any) -> None:
            events.append(("average", (j, ok)))
            assert rec["outputs"].shape == (24 + 6, 2048)

        try:
            frf = rig_builder.run_impact_test(
                rig, world.setup, cfg, on_average=on_average, on_progress=on_progress
            )
        finally:
            rig.close()
    # every strike was asked for, and every average handed over before the next request
    kinds = [k for k, _ in events]
    assert kinds[0] == "ask" and all(a != b for a, b in itertools.pairwise(kinds))
    asks = [v for k, v in events if k == "ask"]
    avgs = [v for k, v in events if k == "average"]
    assert [j for j, _ in avgs] == asks == [j for j, _ in world.strikes]
    assert sum(ok for _, ok in avgs) == 2 * len(INPUTS)
    assert frf.H.shape[1:] == (24 + 6, len(INPUTS))
    tau = world.built.spec.acquisition.exponential_tau_s
    med, p95 = _check_frfs(frf, world, tau)
    assert med < 0.005 and p95 < 0.03, (med, p95)


def test_service_acquisition_on_the_real_branch(tmp_path: Path) -> None:
    """Lab.start_acquisition (the service) with the real rig; the operator polls the job."""
    from dimacq.services.lab import Lab

    world = VirtualWorld("calibration-mass-ground", INPUTS[:2], tmp_path / "rig", pace=8.0)
    with installed(world):
        lab = Lab(_settings(tmp_path, world))
        try:
            assert lab.devices.require("daq").connected, lab.devices.require("daq").error
            assert lab.devices.require("loadcell").connected, lab.devices.require("loadcell").error
            assert (
                lab.devices.require("loadcell").identity["load_cells"]["501"]["serial_number"]
                == 501
            )
            sid = lab.store.save_setup(world.setup)
            acq = lab.acquisitions.start(
                {"setup_id": sid, "averages_per_input": 2, "record_samples": 2048}
            )
            seen: set[str] = set()
            deadline = time.monotonic() + 25
            while time.monotonic() < deadline:
                snap = lab.jobs.snapshot(acq.job_id)
                assert snap is not None
                msg = snap["message"]
                m = PROMPT.match(msg)
                if m and msg not in seen:
                    seen.add(msg)
                    world.strike(int(m.group(1)) - 1)
                if snap["state"] not in ("queued", "running"):
                    break
                time.sleep(0.005)
            a = lab.acquisitions.get(acq.id)
            assert a is not None and a.state == "succeeded", (a, snap)
            assert a.averages_accepted == 4
            assert len(a.averages) == len(world.strikes)
            assert a.frf_id is not None
            stored = lab.store.frf(a.frf_id)
            assert stored is not None
            frf = stored[0]
        finally:
            lab.close()
    med, p95 = _check_frfs(frf, world, world.built.spec.acquisition.exponential_tau_s)
    assert med < 0.005 and p95 < 0.03, (med, p95)


def test_libusb_without_device_names_the_setting(tmp_path: Path) -> None:
    world = VirtualWorld("calibration-mass-ground", INPUTS[:1], tmp_path / "rig")
    with installed(world):
        libusb = _settings(tmp_path, world, daq_backend="libusb")
        with pytest.raises(DeviceNotFoundError, match="daq_backend = 'libusb'"):
            rig_builder.check_devices(libusb, "daq")
        # a backend that has a USB device, but not the configured one
        other = _settings(tmp_path, world, daq_product_id=0x0001)
        with pytest.raises(DeviceNotFoundError, match="daq_product_id"):
            rig_builder.build_rig(other, world.setup, {})


def test_service_refuses_naming_the_setting(tmp_path: Path) -> None:
    """The service starts without the DAQ; starting an acquisition raises DeviceNotFoundError
    (the API's 503) naming the setting."""
    from dimacq.services.lab import Lab

    world = VirtualWorld("calibration-mass-ground", INPUTS[:1], tmp_path / "rig")
    with installed(world):
        lab = Lab(_settings(tmp_path, world, daq_backend="libusb"))
        try:
            assert not lab.devices.require("daq").connected
            assert "daq_backend" in lab.devices.require("daq").error
            assert lab.devices.require("loadcell").connected  # the amplifier is there
            sid = lab.store.save_setup(world.setup)
            with pytest.raises(DeviceNotFoundError, match="daq_backend"):
                lab.acquisitions.start({"setup_id": sid})
        finally:
            lab.close()


def test_rig_file_errors_name_item_and_fix(tmp_path: Path) -> None:
    p = tmp_path / "rig.toml"
    p.write_text(
        "schema_version = 1\n[daq]\nsample_rate_hz = 2048.0\n"
        "[[hammers]]\nphysical_channel = 0\nsensitivity_mv_per_n = 2.25\n"
        "[[responses]]\nnode = 1\ndirection = '+Q'\nphysical_channel = 0\n"
        "sensitivity_mv_per_g = 100.0\nrange_v = 3.0\n"
    )
    with pytest.raises(SetupError) as exc:
        load_rig_file(p)
    msg = str(exc.value)
    assert "responses.0.direction" in msg and "fix:" in msg
    p.write_text(
        "schema_version = 1\n[daq]\nsample_rate_hz = 2048.0\n"
        "[[hammers]]\nphysical_channel = 0\nsensitivity_mv_per_n = 2.25\n"
        "[[responses]]\nnode = 1\ndirection = 1\nphysical_channel = 0\nsensitivity_mv_per_g = 100.0\n"
    )
    with pytest.raises(SetupError, match=r"physical_channel 0 is already used by hammers\.0"):
        load_rig_file(p)
    with pytest.raises(SetupError, match="DIMACQ_RIG_FILE"):
        load_rig_file(tmp_path / "missing.toml")


def test_a_range_the_daq_lacks_is_refused_naming_the_rig_file_item(tmp_path: Path) -> None:
    """Which ranges exist is the DAQ's business (not the rig file's): building the rig refuses
    ±3 V naming the item of the rig file."""
    world = VirtualWorld("calibration-mass-ground", INPUTS[:1], tmp_path / "rig")
    text = world.rig_file.read_text(encoding="utf-8")
    world.rig_file.write_text(text.replace("range_v = 10.0", "range_v = 3.0", 1), encoding="utf-8")
    assert load_rig_file(world.rig_file).responses[0].range_v == 3.0
    with installed(world):
        with pytest.raises(SetupError, match=r"responses\.0: .*range ±3\.0 V is not supported"):
            rig_builder.build_rig(_settings(tmp_path, world), world.setup, {})


@pytest.mark.parametrize("interface", ["kvaser", "nosuchbus"])
def test_can_bus_that_cannot_open_names_the_setting_in_one_line(
    tmp_path: Path, interface: str
) -> None:
    """Kvaser without CANlib raises NameError inside python-can, an unknown interface its own
    error: both are the one-line DeviceNotFoundError naming loadcell_interface, and the service
    starts without the load cells instead of dying."""
    from dimacq.services.lab import Lab

    world = VirtualWorld("calibration-mass-ground", INPUTS[:1], tmp_path / "rig")
    with installed(world):
        # Kvaser channels are numbers: channel 0 reaches the missing library
        settings = _settings(tmp_path, world, loadcell_interface=interface, loadcell_channel="0")
        with pytest.raises(DeviceNotFoundError, match="loadcell_interface") as err:
            rig_builder.check_devices(settings, "loadcell")
        assert "\n" not in str(err.value) and interface in str(err.value)
        if interface == "kvaser":
            assert "vendor library" in str(err.value)
        lab = Lab(settings)
        try:
            cell = lab.devices.require("loadcell")
            assert not cell.connected and "loadcell_interface" in cell.error
        finally:
            lab.close()


def test_can_fd_bit_timing_from_the_settings_reaches_the_bus(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import can

    from dimacq.backends.can_loadcell import bit_timing

    world = VirtualWorld("calibration-mass-ground", INPUTS[:1], tmp_path / "rig")
    opened: list[dict[str, Any]] = []
    real_bus = can.Bus

    def recording_bus(**kw: Any) -> Any:
        opened.append(kw)
        return real_bus(**kw)

    monkeypatch.setattr(can, "Bus", recording_bus)
    with installed(world):
        settings = _settings(
            tmp_path, world, loadcell_bitrate=500_000, loadcell_data_bitrate=2_000_000
        )
        rig_builder.check_devices(settings, "loadcell")
    (kw,) = opened
    t = kw["timing"]
    assert kw["fd"] and (t.nom_bitrate, t.data_bitrate, t.f_clock) == (500_000, 2_000_000, 80e6)
    assert t.nom_sample_point == pytest.approx(80.0, abs=1.0)
    bad = _settings(tmp_path, world, loadcell_data_bitrate=3_000_001)
    with pytest.raises(SetupError, match="loadcell_data_bitrate"):
        bit_timing(bad)


def test_can_fd_bit_timing_of_a_rig_file_entry_wins_over_the_settings(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Each load cell's ``[[load_cells]]`` entry may give its own bus's bit timing (one adapter
    per cell on a mixed rig); what it leaves out comes from the settings."""
    import can

    world = VirtualWorld("calibration-mass-ground", INPUTS[:1], tmp_path / "rig")
    text = world.rig_file.read_text(encoding="utf-8")
    world.rig_file.write_text(
        text.replace(
            "[[load_cells]]\n",
            "[[load_cells]]\ndata_bitrate = 2_000_000\ndata_sample_point = 70.0\n",
            1,
        ),
        encoding="utf-8",
    )
    opened: list[dict[str, Any]] = []
    real_bus = can.Bus

    def recording_bus(**kw: Any) -> Any:
        opened.append(kw)
        return real_bus(**kw)

    monkeypatch.setattr(can, "Bus", recording_bus)
    with installed(world):
        rig_builder.check_devices(_settings(tmp_path, world, loadcell_bitrate=500_000), "loadcell")
        (kw,) = opened
        t = kw["timing"]
        assert (t.nom_bitrate, t.data_bitrate) == (500_000, 2_000_000)
        assert t.data_sample_point == pytest.approx(70.0, abs=1.0)
        world.rig_file.write_text(
            text.replace("[[load_cells]]\n", "[[load_cells]]\ndata_bitrate = 3_000_001\n", 1),
            encoding="utf-8",
        )
        with pytest.raises(SetupError, match=r"rig file \(data_bitrate\)"):
            rig_builder.check_devices(_settings(tmp_path, world), "loadcell")
