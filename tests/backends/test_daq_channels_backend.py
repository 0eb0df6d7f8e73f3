"""``loadcell = "daq-channels"``: the load cell's bridges as inputs of the rig's DAQ (the thesis's
set-up). On the simulated lab the simulated USB DAQ carries the cell's bridge outputs, from the
same physics the CAN amplifier simulator reads: the same impact test through both backends gives
the same load cell FRFs (same seed, 24-bit gauges on ±0.1 V = the amplifier's 24 bits on
±10 mV/V at 10 V excitation); the rig file's errors name the item."""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from dimacq.backends import BACKENDS, is_simulated, lookup
from dimacq.backends.base import DeviceContext
from dimacq.config import default_config_file, load_settings
from dimacq.drivers.daq_loadcell import DaqChannelLoadCell, DaqSplitter
from dimacq.errors import SetupError
from dimacq.services.acquisition import rig as rig_builder
from dimacq.simulators.lab.scenarios import build_scenario


def test_entry_in_the_table() -> None:
    assert BACKENDS["loadcell"]["daq-channels"] == "dimacq.backends.daq_channels:open_loadcell"
    assert callable(lookup("loadcell", "daq-channels"))
    assert not is_simulated("loadcell", "daq-channels")  # simulated when the DAQ is


def _impact(tmp_path: Path, loadcell: str, rig_file: str = "") -> Any:
    settings = load_settings(
        data_dir=tmp_path / loadcell, token="t", loadcell=loadcell, rig_file=rig_file
    )
    setup = build_scenario(settings.scenario).model.setup
    setup = setup.model_copy(update={"excitations": setup.excitations[:2]})
    cfg = {"averages_per_input": 2, "record_samples": 2048, "seed": 4}
    rig = rig_builder.build_rig(settings, setup, cfg)
    try:
        assert len(rig.daq.channel_names) == 1 + 24  # the hammer and the responses only
        assert rig.daq_units == ("N",) + ("m/s^2",) * 24
        if loadcell == "daq-channels":
            assert isinstance(rig.daq, DaqSplitter)
            assert isinstance(rig.loadcells[0], DaqChannelLoadCell)
        return rig_builder.run_impact_test(
            rig, setup, cfg, on_average=lambda *a: None, on_progress=lambda f, m: None
        )
    finally:
        rig.close()


def test_same_impact_test_same_load_cell_frfs_as_the_can_amplifier(tmp_path: Path) -> None:
    can = _impact(tmp_path, "simulated")
    daq = _impact(tmp_path, "daq-channels")
    assert daq.H.shape == can.H.shape and daq.H.shape[1] == 24 + 6
    f = daq.frequencies_hz
    band = (f >= 20) & (f <= 100)
    # one physics, one seed, the same resolution: the same reactions
    np.testing.assert_allclose(daq.H[band, 24:30], can.H[band, 24:30], rtol=1e-9, atol=0)
    np.testing.assert_allclose(daq.H[band, :24], can.H[band, :24], rtol=1e-9)


def test_devices_check_opens_the_daq_itself(tmp_path: Path) -> None:
    settings = load_settings(data_dir=tmp_path, token="t", loadcell="daq-channels")
    got = rig_builder.check_devices(settings, "loadcell")
    assert got["backend"] == "daq-channels"
    cell = got["load_cells"]["501"]
    assert cell["n_gauges"] == 12 and cell["serial_number"] == 501
    assert "LC501 g01" in cell["firmware"]


def _rig_text(extra: str, drop: str = "") -> str:
    text = (default_config_file().parent / "rig.toml").read_text(encoding="utf-8")
    if drop:
        text = "\n".join(ln for ln in text.splitlines() if not ln.startswith(drop))
    return text.replace('daq_signals = "gauges"', 'daq_signals = "gauges"\n' + extra)


@pytest.mark.parametrize(
    ("extra", "drop", "match"),
    [
        ("", "daq_channels", r"load cell 501 .* no daq_channels; list the DAQ inputs"),
        ("", "excitation_v", r"calibration is in mV/V; give the bridges' excitation_v"),
    ],
)
def test_rig_file_errors_name_the_item(tmp_path: Path, extra: str, drop: str, match: str) -> None:
    rig = tmp_path / "rig.toml"
    shutil.copytree(default_config_file().parent / "calibrations", tmp_path / "calibrations")
    rig.write_text(_rig_text(extra, drop), encoding="utf-8")
    settings = load_settings(
        data_dir=tmp_path, token="t", loadcell="daq-channels", rig_file=str(rig)
    )
    with DeviceContext(settings) as ctx, pytest.raises(SetupError, match=match):
        lookup("loadcell", "daq-channels")(ctx, ctx.rig_file.load_cells[0])


def test_gauge_count_must_match_the_calibration(tmp_path: Path) -> None:
    rig = tmp_path / "rig.toml"
    shutil.copytree(default_config_file().parent / "calibrations", tmp_path / "calibrations")
    text = _rig_text("").replace(
        "daq_channels = [25, 26, 27, 28, 29, 30, 31, 32, 33, 34, 35, 36]",
        "daq_channels = [25, 26, 27, 28, 29, 30, 31, 32, 33, 34]",
    )
    rig.write_text(text, encoding="utf-8")
    settings = load_settings(
        data_dir=tmp_path, token="t", loadcell="daq-channels", rig_file=str(rig)
    )
    with (
        DeviceContext(settings) as ctx,
        pytest.raises(
            SetupError, match=r"lc-501.json has 12 gauge columns but daq_channels lists 10 inputs"
        ),
    ):
        lookup("loadcell", "daq-channels")(ctx, ctx.rig_file.load_cells[0])


def test_can_backends_need_a_node_id(tmp_path: Path) -> None:
    rig = tmp_path / "rig.toml"
    shutil.copytree(default_config_file().parent / "calibrations", tmp_path / "calibrations")
    rig.write_text(_rig_text("", drop="node_id"), encoding="utf-8")
    settings = load_settings(data_dir=tmp_path, token="t", rig_file=str(rig))
    with (
        DeviceContext(settings) as ctx,
        pytest.raises(
            SetupError, match=r"load cell 501: .* needs its amplifier's CAN node id; give node_id"
        ),
    ):
        lookup("loadcell", "dimacq-can")(ctx, ctx.rig_file.load_cells[0])


def test_status_calls_it_simulated_when_its_daq_is(tmp_path: Path) -> None:
    from dimacq.services.lab.devices import DeviceService

    settings = load_settings(data_dir=tmp_path, token="t", loadcell="daq-channels")
    info = DeviceService(settings, lambda driver: None).get("loadcell")  # type: ignore[arg-type,return-value]
    assert info is not None and info.simulated
