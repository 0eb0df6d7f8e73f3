"""The real static-calibration path, end to end by configuration against the simulators.

``loadcell_interface = "virtual"`` with the amplifier simulator (on its own clock, 200× real
time) listening on ``loadcell_channel`` and reading the simulated dead-weight bench; ``rig_file``
names the cell's amplifier (CAN node 3) and its calibration file; the bench file beside it gives
the plan and timing. The test plays the operator: when asked, it sets up the load case on the
bench. Checks the matrix, the versioned files, the download and read-back from the amplifier, and
that the acquisition's amplifier opens with the new calibration.
"""

from __future__ import annotations

import os
import uuid
from pathlib import Path

import numpy as np
import pytest
from _bench_rig_support import RIG, write_bench_rig

from dimacq.backends.base import DeviceContext
from dimacq.backends.can_loadcell import open_loadcell
from dimacq.config import load_settings
from dimacq.io.loadcell_calibration import (
    LoadCellCalibration,
    read_calibration,
    write_calibration_json,
)
from dimacq.io.rig_file import load_rig_file
from dimacq.pipeline.loadcell_calibration import LoadCase
from dimacq.services.calibration.loadcell_calibration import calibrate_rig_cell
from dimacq.simulators.lab.bridge import strain_gauge_cell
from dimacq.simulators.loadcell.amplifier import LoadCellAmplifierSim
from dimacq.simulators.loadcell.bench import DeadWeightBench

POINTS = """[[points]]
name = "arm +x"
position_m = [0.1, 0.0, 0.05]
"""


@pytest.mark.slow
def test_static_calibration_of_the_configured_cell(tmp_path: Path) -> None:
    rig_dir = write_bench_rig(tmp_path, node_id=3, points=POINTS)
    cell = strain_gauge_cell(501, creep_tau_s=1.5, swing_tau_s=0.8)
    C_true = np.linalg.pinv(cell.sensitivity_mvv)
    old = LoadCellCalibration("501", "2025-01-01", 1.05 * C_true, method="inertial")
    write_calibration_json(old, rig_dir / "calibrations" / "lc-501.json")
    bench = DeadWeightBench(cell, sample_rate_hz=10, seed=5)
    channel = f"dimacq-lccal-{os.getpid()}-{uuid.uuid4().hex[:8]}"
    settings = load_settings(
        data_dir=tmp_path / "data",
        token="t",
        loadcell_interface="virtual",
        loadcell_virtual_ok=True,  # a simulator on python-can's in-process bus
        loadcell_channel=channel,
        rig_file=str(rig_dir / "rig.toml"),
        daq_backend="libusb",
    )
    asked: list[str] = []

    def operator(case: LoadCase, sample: int) -> None:
        asked.append(case.prompt())
        bench.place(case.mass_kg, np.array(case.position_m), np.array(case.gravity))

    with LoadCellAmplifierSim(
        channel, bench, list(range(12)), node_id=3, serial_number=501, time_scale=200.0
    ) as sim:
        result = calibrate_rig_cell(settings, operator, download=True)
        C = result.run.matrix
        cert = result.run.certificate
        assert np.linalg.norm(C - C_true) / np.linalg.norm(C_true) < 1e-3
        np.testing.assert_allclose(cert.nonlinearity_pct_fs, 100 * cell.nonlinearity, rtol=0.1)
        np.testing.assert_allclose(cert.hysteresis_pct_fs, 100 * cell.hysteresis, rtol=0.1)
        assert cert.verdict == "ok", cert.reasons
        assert not result.run.unsettled.any()
        # downloaded and read back: the amplifier holds the float32 matrix, all 72 verified
        assert result.download is not None and result.download.verified == 72
        np.testing.assert_array_equal(sim.matrix, C.astype("<f4").astype(float))
        # versioned: the old file was version 1, the new one is version 2 in JSON and XML
        assert result.installed.version == 2
        for p in (result.installed.json_path, result.installed.xml_path):
            kept = read_calibration(p)
            assert kept.version == 2 and kept.method == "static"
            np.testing.assert_allclose(kept.matrix, C, rtol=1e-12)
        current = read_calibration(rig_dir / "calibrations" / "lc-501.json")
        assert current.version == 2 and current.gauge_unit == "mV/V"
        assert current.certificate["verdict"] == "ok"
        assert len(current.certificate["nonlinearity_pct_fs"]) == 6
        # what the acquisition opens from then on
        rig = load_rig_file(settings.rig_path)
        with DeviceContext(settings) as ctx:
            amp = open_loadcell(ctx, rig.load_cells[0])
            np.testing.assert_allclose(amp.calibration_matrix, C, rtol=1e-12)
    assert len(asked) == len(result.run.plan.cases)
    assert "arm +x (100.0, 0.0, 50.0 mm)" in " ".join(asked)
    assert result.to_json()["download_verified"] == 72


def test_unknown_load_cell_and_missing_bench_file_are_named(tmp_path: Path) -> None:
    from dimacq.errors import SetupError

    rig_dir = tmp_path / "rig"
    rig_dir.mkdir()
    (rig_dir / "rig.toml").write_text(RIG.format(node_id=3), encoding="utf-8")
    settings = load_settings(
        data_dir=tmp_path / "data", token="t", rig_file=str(rig_dir / "rig.toml")
    )
    with pytest.raises(SetupError, match="load cell 7 is not in"):
        calibrate_rig_cell(settings, lambda c, k: None, node=7)
    with pytest.raises(SetupError, match=r"loadcell_bench\.toml"):
        calibrate_rig_cell(settings, lambda c, k: None)
