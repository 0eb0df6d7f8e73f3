"""``loadcell = "canopen"`` / ``"canopen-simulated"``: one more load cell entry of the backend
table. The same impact test through the CAN FD and the CANopen backends gives the same load cell
FRFs; the devices check names the node; a bench calibration on the configured CANopen cell is
downloaded and read back through SDO."""

from __future__ import annotations

import os
import uuid
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from _bench_rig_support import write_bench_rig

from dimacq.backends import BACKENDS, lookup
from dimacq.backends.base import DeviceContext
from dimacq.config import load_settings
from dimacq.errors import SetupError
from dimacq.io.loadcell_calibration import read_calibration
from dimacq.pipeline.loadcell_calibration import LoadCase
from dimacq.services.acquisition import rig as rig_builder
from dimacq.services.calibration.loadcell_calibration import calibrate_rig_cell
from dimacq.simulators.canopen_loadcell.amplifier import CanopenAmplifierSim
from dimacq.simulators.lab.bridge import strain_gauge_cell
from dimacq.simulators.lab.scenarios import build_scenario
from dimacq.simulators.loadcell.bench import DeadWeightBench


def test_canopen_entries_are_in_the_tables() -> None:
    assert {"canopen", "canopen-simulated"} <= set(BACKENDS["loadcell"])
    assert "canopen-simulated" in BACKENDS["loadcell-bench"]
    for name in ("canopen", "canopen-simulated"):
        assert callable(lookup("loadcell", name))


def _impact(tmp_path: Path, loadcell: str) -> Any:
    settings = load_settings(data_dir=tmp_path / loadcell, token="t", loadcell=loadcell)
    setup = build_scenario(settings.scenario).model.setup
    setup = setup.model_copy(update={"excitations": setup.excitations[:2]})
    cfg = {"averages_per_input": 2, "record_samples": 2048, "seed": 4}
    rig = rig_builder.build_rig(settings, setup, cfg)
    try:
        return rig_builder.run_impact_test(
            rig, setup, cfg, on_average=lambda *a: None, on_progress=lambda f, m: None
        )
    finally:
        rig.close()


def test_same_impact_test_same_load_cell_frfs_on_both_backends(tmp_path: Path) -> None:
    native = _impact(tmp_path, "simulated")
    co = _impact(tmp_path, "canopen-simulated")
    assert co.H.shape == native.H.shape and co.H.shape[1] == 24 + 6
    f = co.frequencies_hz
    band = (f >= 20) & (f <= 100)
    lc = slice(24, 30)  # the load cell's six reactions
    rel = np.abs(co.H[band, lc] - native.H[band, lc]) / np.abs(native.H[band, lc])
    # the same world, seed and 24-bit gauges: the same reactions to quantisation
    assert np.median(rel) < 1e-4, np.median(rel)
    np.testing.assert_allclose(co.H[band, :24], native.H[band, :24], rtol=1e-9)


def test_devices_check_names_the_nodes(tmp_path: Path) -> None:
    settings = load_settings(data_dir=tmp_path, token="t", loadcell="canopen-simulated")
    got = rig_builder.check_devices(settings, "loadcell")
    assert got["backend"] == "canopen-simulated"
    assert got["load_cells"]["501"]["node_id"] == 1
    assert got["load_cells"]["501"]["serial_number"] == 501
    other = load_settings(
        data_dir=tmp_path, token="t", loadcell="canopen-simulated", loadcell_canopen_node_ids=[4]
    )
    with pytest.raises(
        SetupError, match=r"node_id 1 .* not one of loadcell_canopen_node_ids \[4\]"
    ):
        rig_builder.check_devices(other, "loadcell")


@pytest.mark.slow
def test_bench_calibration_of_the_configured_canopen_cell(tmp_path: Path) -> None:
    """The real path (``calibrate_rig_cell``) with ``loadcell = "canopen"`` on a ``virtual``
    channel where a CANopen simulator reads the dead-weight bench: the matrix, its versioned
    file, and the download read back through SDO."""
    rig_dir = write_bench_rig(tmp_path, node_id=6)
    cell = strain_gauge_cell(501, creep_tau_s=1.5, swing_tau_s=0.8)
    bench = DeadWeightBench(cell, sample_rate_hz=10, seed=5)
    channel = f"dimacq-cocal-{os.getpid()}-{uuid.uuid4().hex[:8]}"
    settings = load_settings(
        data_dir=tmp_path / "data",
        token="t",
        daq_backend="libusb",
        loadcell="canopen",
        loadcell_interface="virtual",
        loadcell_virtual_ok=True,  # the documented way: a simulator on the in-process bus
        loadcell_channel=channel,
        rig_file=str(rig_dir / "rig.toml"),
    )

    def operator(case: LoadCase, sample: int) -> None:
        bench.place(case.mass_kg, np.array(case.position_m), np.array(case.gravity))

    eds = settings.loadcell_canopen_eds_path
    with CanopenAmplifierSim(
        channel, eds, bench, list(range(12)), node_id=6, serial_number=501, time_scale=200.0
    ) as sim:
        result = calibrate_rig_cell(settings, operator, download=True)
        C = result.run.matrix
        C_true = np.linalg.pinv(cell.sensitivity_mvv)
        assert np.linalg.norm(C - C_true) / np.linalg.norm(C_true) < 1e-3
        assert result.run.certificate.verdict == "ok", result.run.certificate.reasons
        assert result.download is not None and result.download.verified == 72
        np.testing.assert_array_equal(sim.matrix, C.astype("<f4").astype(float))
        assert read_calibration(rig_dir / "calibrations" / "lc-501.json").version == 1
        # what an acquisition opens from then on: the new file's matrix, serial checked
        with DeviceContext(settings) as ctx:
            amp = lookup("loadcell", "canopen")(ctx, ctx.rig_file.load_cells[0])
            np.testing.assert_allclose(amp.calibration_matrix, C, rtol=1e-12)
