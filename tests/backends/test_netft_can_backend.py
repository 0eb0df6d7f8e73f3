"""``loadcell = "netft-can"`` / ``"netft-can-simulated"``: an ATI Net F/T on CAN, the requests
sent on the simulated DAQ's clock. The same impact test gives the load cell FRFs of the CAN FD
amplifier within the two calibrations' certificate errors (0.5 % the amplifier's file, 0.2 %
the sensor's own), the accelerometers' exactly; the rig file's missing items are named."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from dimacq.backends import BACKENDS, is_simulated, lookup
from dimacq.backends.base import DeviceContext
from dimacq.config import default_config_file, load_settings
from dimacq.drivers.netft.can_driver import NetFtCan
from dimacq.errors import SetupError
from dimacq.services.acquisition import rig as rig_builder
from dimacq.simulators.lab.scenarios import build_scenario


def test_entries_in_the_table() -> None:
    assert {"netft-can", "netft-can-simulated"} <= set(BACKENDS["loadcell"])
    assert is_simulated("loadcell", "netft-can-simulated")
    assert not is_simulated("loadcell", "netft-can")


def _impact(tmp_path: Path, loadcell: str, band_hz: float | None = None) -> Any:
    kw: dict[str, Any] = {}
    if band_hz is not None:  # the band its held values allow within the phase budget
        text = (default_config_file().parent / "rig.toml").read_text(encoding="utf-8")
        text = text.replace("# netft_band_hz = 100", f"netft_band_hz = {band_hz}")
        (tmp_path / "rig.toml").write_text(text, encoding="utf-8")
        kw["rig_file"] = str(tmp_path / "rig.toml")
    settings = load_settings(data_dir=tmp_path / loadcell, token="t", loadcell=loadcell, **kw)
    setup = build_scenario(settings.scenario).model.setup
    setup = setup.model_copy(update={"excitations": setup.excitations[:2]})
    cfg = {"averages_per_input": 2, "record_samples": 2048, "seed": 4}
    rig = rig_builder.build_rig(settings, setup, cfg)
    try:
        if loadcell.startswith("netft"):
            assert isinstance(rig.loadcells[0], NetFtCan)
        return rig_builder.run_impact_test(
            rig, setup, cfg, on_average=lambda *a: None, on_progress=lambda f, m: None
        )
    finally:
        rig.close()


def test_the_default_band_is_refused_for_its_held_values(tmp_path: Path) -> None:
    """At 0.32 x 2048 S/s = 655 Hz the held value's age (0..143 us) costs 9.7 deg: refused."""
    with pytest.raises(SetupError) as err:
        _impact(tmp_path, "netft-can-simulated")
    msg = str(err.value)
    assert "7000 S/s" in msg and "9.7 deg" in msg and "655.36 Hz" in msg and "up to 135 Hz" in msg


@pytest.mark.slow
def test_same_impact_test_through_the_net_ft(tmp_path: Path) -> None:
    amp = _impact(tmp_path, "simulated")
    ft = _impact(tmp_path, "netft-can-simulated", band_hz=100)
    assert ft.H.shape == amp.H.shape and ft.H.shape[1] == 24 + 6
    f = ft.frequencies_hz
    band = (f >= 20) & (f <= 100)
    np.testing.assert_allclose(ft.H[band, :24], amp.H[band, :24], rtol=1e-9)
    lc = slice(24, 30)
    rel = np.abs(ft.H[band, lc] - amp.H[band, lc]) / np.abs(amp.H[band, lc]).max(axis=0)
    assert np.median(rel) < 0.02, np.median(rel)


def test_devices_check(tmp_path: Path) -> None:
    settings = load_settings(data_dir=tmp_path, token="t", loadcell="netft-can-simulated")
    got = rig_builder.check_devices(settings, "loadcell")
    cell = got["load_cells"]["501"]
    assert got["backend"] == "netft-can-simulated" and cell["n_gauges"] == 6
    assert "Net F/T CAN base 0x20" in cell["firmware"]


@pytest.mark.parametrize(
    ("drop", "match"),
    [
        ("netft_base", r"needs the Net F/T's CAN base address; give netft_base"),
        ("netft_counts_per_force", r"needs the Net F/T's counts per unit"),
    ],
)
def test_rig_file_items_named(tmp_path: Path, drop: str, match: str) -> None:
    text = (default_config_file().parent / "rig.toml").read_text(encoding="utf-8")
    text = "\n".join(ln for ln in text.splitlines() if not ln.startswith(drop))
    (tmp_path / "rig.toml").write_text(text, encoding="utf-8")
    settings = load_settings(
        data_dir=tmp_path,
        token="t",
        loadcell="netft-can",
        loadcell_interface="virtual",
        loadcell_virtual_ok=True,
        loadcell_channel=f"netft-none-{tmp_path.name}",
        rig_file=str(tmp_path / "rig.toml"),
    )
    with DeviceContext(settings) as ctx, pytest.raises(SetupError, match=match):
        lookup("loadcell", "netft-can")(ctx, ctx.rig_file.load_cells[0])
