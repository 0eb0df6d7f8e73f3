"""Files of a load cell read as DAQ inputs: a calibration of N gauges (6 conditioned outputs,
or a cell with other than 12 bridges) in JSON and ATI-style XML, and the rig file's
``daq_channels`` checked against every other DAQ input."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from dimacq.errors import DataError, SetupError
from dimacq.io.acquisition_hdf5 import AcquisitionWriter
from dimacq.io.loadcell_calibration import (
    LoadCellCalibration,
    read_calibration,
    write_calibration_json,
    write_calibration_xml,
)
from dimacq.io.rig_file import parse_rig_text

RIG = """schema_version = 1
[daq]
sample_rate_hz = 2048.0
[[hammers]]
physical_channel = 0
sensitivity_mv_per_n = 2.25
[[responses]]
node = 1
direction = "+X"
physical_channel = 1
sensitivity_mv_per_g = 100.0
[[load_cells]]
node = 9
calibration_file = "lc-9.json"
"""


@pytest.mark.parametrize("n", [6, 8, 12])
@pytest.mark.parametrize("suffix", [".json", ".xml"])
def test_calibration_of_n_gauges_round_trips(tmp_path: Path, n: int, suffix: str) -> None:
    C = np.random.default_rng(n).normal(size=(6, n))
    cal = LoadCellCalibration("9", "2026-11-26", C, method="certificate", gauge_unit="V")
    path = tmp_path / f"lc{suffix}"
    (write_calibration_json if suffix == ".json" else write_calibration_xml)(cal, path)
    back = read_calibration(path)
    assert back.n_gauges == n and back.gauge_unit == "V"
    np.testing.assert_allclose(back.matrix, C, rtol=1e-15)
    if suffix == ".xml":
        assert f'NumGages="{n}"' in path.read_text(encoding="utf-8")


def test_fewer_than_six_columns_is_refused() -> None:
    with pytest.raises(DataError, match=r"6xN matrix, N >= 6"):
        LoadCellCalibration("9", "2026-11-26", np.ones((6, 5)))


def test_rig_file_daq_channels() -> None:
    rf = parse_rig_text(RIG + "daq_channels = [2, 3, 4, 5, 6, 7]\ndaq_signals = 'outputs'\n", "r")
    (lc,) = rf.load_cells
    assert lc.node_id is None and lc.daq_channels == [2, 3, 4, 5, 6, 7]
    assert lc.daq_coupling == "DC" and lc.daq_range_v == 10.0
    with pytest.raises(SetupError, match=r"load_cells.0.daq_channels: physical_channel 1 is "):
        parse_rig_text(RIG + "daq_channels = [1, 2, 3, 4, 5, 6]\n", "r")
    with pytest.raises(SetupError, match=r"daq_signals = 'outputs' with 5 daq_channels"):
        parse_rig_text(RIG + "daq_channels = [2, 3, 4, 5, 6]\ndaq_signals = 'outputs'\n", "r")
    with pytest.raises(SetupError, match=r"lists a DAQ input twice"):
        parse_rig_text(RIG + "daq_channels = [2, 2, 4, 5, 6, 7]\n", "r")


def test_acquisition_file_keeps_the_cells_rows(tmp_path: Path) -> None:
    import h5py

    with AcquisitionWriter(
        tmp_path / "a.h5",
        sample_rate_hz=2048.0,
        daq_channels=("h",),
        daq_units=("N",),
        n_loadcells=2,
    ) as w:
        w.append_loadcell(0, np.ones((6, 10)), np.ones(10, bool))
        w.append_loadcell(0, np.ones((6, 5)), np.ones(5, bool))
        w.append_loadcell(1, np.ones((12, 10)), np.ones(10, bool))
    with h5py.File(tmp_path / "a.h5") as f:
        assert f["loadcell0/gauges_v"].shape == (6, 15)
        assert f["loadcell1/gauges_v"].shape == (12, 10)
