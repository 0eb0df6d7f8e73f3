"""A calibration document whose ``diagnostics`` or ``certificate`` is not a table is refused with
the field named (it used to pass the door and fail with an internal error)."""

from __future__ import annotations

import pytest

from dimacq.errors import DataError
from dimacq.io.loadcell_calibration import parse_calibration_json


@pytest.mark.parametrize("key", ["diagnostics", "certificate"])
@pytest.mark.parametrize("value", ["zz", [1, 2], 3.0])
def test_tables_must_be_objects(key: str, value: object) -> None:
    doc = {
        "kind": "dimacq.loadcell_calibration",
        "schema_version": 1,
        "serial_number": "LC501",
        "date": "2026-11-29",
        "matrix": [[1.0] * 12] * 6,
        key: value,
    }
    with pytest.raises(DataError, match=f"calibration: {key} must be a table"):
        parse_calibration_json(doc, "calibration")
