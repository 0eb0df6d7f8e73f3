"""``POST /api/digitizer/photo-geometry``: photographed records become the test's orientations
and lines of action, and a setup built from geometry states their uncertainty; a result with
unfixed items or another document is refused."""

from __future__ import annotations

import json

import numpy as np
import pytest
from _api_support import Api


def _doc(verdict: str = "ok") -> dict:
    r = np.eye(3)
    return {
        "schema_version": 1,
        "source": "photographs",
        "verdict": verdict,
        "unfixed": [] if verdict != "fail" else ["triax 9: seen in 1 photo(s); take 2 more"],
        "orientations": [
            {
                "node": n,
                "rotation": r.tolist(),
                "origin_m": [0.1 * n, 0.05 * (n % 3), 0.02 * (n % 2)],
                "method": "photos",
                "rods": [],
                "n_points": 40,
                "residual_rms_m": 2e-5,
                "angle_std_deg": [0.05, 0.05, 0.05],
                "uncertainty_deg": 0.09,
                "jig_uncertainty_deg": 0.08,
                "origin_std_m": 1.2e-4,
            }
            for n in (1, 2, 3)
        ],
        "lines_of_action": [
            {
                "node": 101 + k,
                "direction": d,
                "point_m": [0.3, 0.01 * k, -0.02],
                "method": "photos",
                "perpendicular_rms_m": 2e-5,
                "angle_std_deg": 0.14,
                "fit_angle_std_deg": 0.12,
                "point_std_m": 1.5e-4,
            }
            for k, d in enumerate(
                ([-1.0, 0, 0], [0, -1.0, 0], [0, 0, 1.0], [-1.0, 0, 0], [0, -1.0, 0], [0, 0, 1.0])
            )
        ],
    }


@pytest.mark.slow
def test_photographed_records_build_a_setup(api: Api) -> None:
    c = api.client
    r = c.post("/api/digitizer/photo-geometry", content=json.dumps(_doc()).encode())
    assert r.status_code == 201, r.text
    assert r.json()["orientations"] == 3 and r.json()["lines_of_action"] == 6
    r = c.post(
        "/api/setups/from-geometry",
        json={"name": "photos", "triaxes": [1, 2, 3], "inputs": list(range(101, 107))},
    )
    assert r.status_code == 201, r.text
    geo = r.json()["setup"]["geometry_uncertainty"]
    assert geo["source"] == "digitized"
    np.testing.assert_allclose(geo["sensor_position_m"], 1.2e-4)
    np.testing.assert_allclose(geo["sensor_orientation_deg"], 0.09 / np.sqrt(3))
    np.testing.assert_allclose(geo["line_of_action_deg"], 0.14 / np.sqrt(2))
    np.testing.assert_allclose(geo["input_position_m"], 1.5e-4)


def test_unfixed_or_foreign_documents_are_refused(api: Api) -> None:
    c = api.client
    r = c.post("/api/digitizer/photo-geometry", content=json.dumps(_doc("fail")).encode())
    assert r.status_code == 400 and "triax 9" in r.json()["detail"]
    r = c.post("/api/digitizer/photo-geometry", content=b'{"points": []}')
    assert r.status_code == 400 and "from-photos" in r.json()["detail"]
    r = c.post("/api/digitizer/photo-geometry", content=b"not json")
    assert r.status_code == 422
