"""Load cell calibration files: JSON and ATI-style XML round trips and refusals."""

from __future__ import annotations

import json

import numpy as np
import pytest

from dimacq.errors import DataError
from dimacq.io.loadcell_calibration import (
    LoadCellCalibration,
    read_calibration,
    write_calibration_json,
    write_calibration_xml,
)


def cal():
    m = np.random.default_rng(0).standard_normal((6, 12)) * 1e3
    return LoadCellCalibration(
        "LC501", "2026-11-21", m, method="inertial", diagnostics={"residual_rel": 1e-3}
    )


def test_json_round_trip_is_lossless(tmp_path):
    c = cal()
    write_calibration_json(c, tmp_path / "c.json")
    back = read_calibration(tmp_path / "c.json")
    np.testing.assert_array_equal(back.matrix, c.matrix)
    assert (back.serial_number, back.date, back.method) == ("LC501", "2026-11-21", "inertial")
    assert back.diagnostics == {"residual_rel": 1e-3}


def test_xml_round_trip_and_ati_layout(tmp_path):
    c = cal()
    write_calibration_xml(c, tmp_path / "c.xml")
    text = (tmp_path / "c.xml").read_text()
    assert "<FTSensor" in text and 'NumGages="12"' in text and 'Name="Tz"' in text
    back = read_calibration(tmp_path / "c.xml")
    np.testing.assert_array_equal(back.matrix, c.matrix)
    assert back.serial_number == "LC501"


def test_moment_units_in_mm_are_converted(tmp_path):
    c = cal()
    d = c.to_json()
    d["moment_unit"] = "N-mm"
    (tmp_path / "mm.json").write_text(json.dumps(d))
    back = read_calibration(tmp_path / "mm.json")
    np.testing.assert_allclose(back.matrix[3:], c.matrix[3:] * 1e-3)
    np.testing.assert_allclose(back.matrix[:3], c.matrix[:3])


def test_bad_files_are_refused(tmp_path):
    # 6 x N (N >= 6 gauges or conditioned outputs): 6 x 11 is a cell of 11 gauges, 5 rows none
    with pytest.raises(DataError, match="6xN"):
        LoadCellCalibration("LC1", "2026-01-01", np.zeros((5, 12)))
    with pytest.raises(DataError, match="ISO"):
        LoadCellCalibration("LC1", "21/11/2026", np.zeros((6, 12)))
    d = cal().to_json()
    d["schema_version"] = 99
    (tmp_path / "v.json").write_text(json.dumps(d))
    with pytest.raises(DataError, match="schema_version"):
        read_calibration(tmp_path / "v.json")
    (tmp_path / "x.xml").write_text(
        "<FTSensor><Calibration><Axis Name='Fx' values='1 2'/></Calibration></FTSensor>"
    )
    with pytest.raises(DataError, match="missing"):
        read_calibration(tmp_path / "x.xml")
    with pytest.raises(DataError, match="unknown calibration file type"):
        read_calibration(tmp_path / "c.txt")


def test_lbf_and_lbf_in_read_and_the_gauge_count_taken_from_the_file(tmp_path):
    """An ATI-style file of a US-calibrated cell: ForceUnits="lbf", TorqueUnits="lbf-in", and
    NumGages="6" (a cell read through six conditioned outputs). Independent answer: the
    definitions 1 lbf = 0.45359237 kg × 9.80665 m/s² = 4.4482216152605 N, 1 in = 0.0254 m."""
    m = np.random.default_rng(3).standard_normal((6, 6))
    c = LoadCellCalibration("FT9", "2026-11-27", m, gauge_unit="V")
    write_calibration_xml(c, tmp_path / "ft.xml")
    text = (tmp_path / "ft.xml").read_text()
    assert 'NumGages="6"' in text
    text = text.replace('ForceUnits="N"', 'ForceUnits="lbf"').replace(
        'TorqueUnits="N-m"', 'TorqueUnits="lbf-in"'
    )
    (tmp_path / "lbf.xml").write_text(text)
    back = read_calibration(tmp_path / "lbf.xml")
    assert back.n_gauges == 6
    np.testing.assert_allclose(back.matrix[:3], m[:3] * 4.4482216152605, rtol=1e-13)
    np.testing.assert_allclose(back.matrix[3:], m[3:] * 4.4482216152605 * 0.0254, rtol=1e-13)
    d = c.to_json()
    d["force_unit"], d["moment_unit"] = "lbf", "lbf-ft"
    (tmp_path / "lbf.json").write_text(json.dumps(d))
    back = read_calibration(tmp_path / "lbf.json")
    np.testing.assert_allclose(back.matrix[3:], m[3:] * 4.4482216152605 * 0.3048, rtol=1e-13)
    d["force_unit"] = "kip"
    (tmp_path / "kip.json").write_text(json.dumps(d))
    with pytest.raises(DataError, match=r"units 'kip'/'lbf-ft' unknown; use one of \[.*'lbf'"):
        read_calibration(tmp_path / "kip.json")
    for bad in ([], {"a": 1}, 3.0, None):  # not a unit name: refused, never a crash
        d["force_unit"] = bad
        (tmp_path / "odd.json").write_text(json.dumps(d))
        with pytest.raises(DataError, match=r"units .* unknown; use one of"):
            read_calibration(tmp_path / "odd.json")
