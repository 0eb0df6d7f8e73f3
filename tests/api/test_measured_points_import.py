"""Geometry from any instrument: labelled points in a file (CSV, JSON) through the same
registration and orientation pipeline as the live digitizer (issue 23).

Independent answer: the simulated digitizer's own points, written to a file in the instrument's
frame (its array's), give the same registration, global points and jig orientation when
imported as when measured live; bad files are refused in one line naming the field."""

from __future__ import annotations

import csv
import io
import json

import numpy as np
import pytest
from _api_support import Api
from scipy.spatial.transform import Rotation
from test_registration_limits import REFS, digitize, new_test, register_refs

from dimacq.errors import SetupError
from dimacq.io.measured_points import read_measured_points
from dimacq.services.geometry.digitizer_config import load_jig


def _geometry(api: Api) -> tuple[dict, dict, dict]:
    """Registration of the current patch, global points, orientation of node 7."""
    c = api.client
    r = c.post("/api/digitizer/registrations", json={})
    assert r.status_code == 200, r.text
    o = c.post("/api/digitizer/orientations", json={"node": 7})
    assert o.status_code in (200, 201), o.text
    return r.json()["registration"], o.json(), {}


@pytest.mark.slow
def test_a_file_of_the_digitizers_points_gives_the_live_geometry(api: Api) -> None:
    c = api.client
    new_test(api)
    register_refs(api)
    c_true = Rotation.from_euler("zyx", [20, 10, -15], degrees=True).as_matrix()
    origin = np.array([0.2, 0.2, 0.1])
    jig = load_jig()
    for lab, xl in zip(jig.labels, jig.points_local_m, strict=True):
        digitize(api, f"jig7/{lab}", c_true @ xl + origin)
    reg_live, o_live, _ = _geometry(api)
    patch = reg_live["patch"] if "patch" in reg_live else None
    pts = [p for p in c.get("/api/digitizer/points", params={"limit": 500}).json()]
    live = {p["label"]: p for p in pts if patch is None or p["patch"] == patch}
    # the instrument's file: its frame (the array's), in mm, with the points' spread
    buf = io.StringIO()
    w = csv.writer(buf)
    w.writerow(["label", "x_mm", "y_mm", "z_mm"])
    for lab, p in live.items():
        w.writerow([lab, *(repr(1e3 * v) for v in p["position_array_m"])])
    # a new digitizing test: the same reference nodes, the points only from the file
    new_test(api)
    assert c.put("/api/digitizer/reference-nodes", json={"nodes": REFS}).status_code == 200
    r = c.post(
        "/api/digitizer/points/import",
        params={"format": "csv", "name": "CMM set-up 1"},
        content=buf.getvalue().encode(),
    )
    assert r.status_code == 201, r.text
    got = r.json()
    assert {p["label"] for p in got} == set(live) and len({p["patch"] for p in got}) == 1
    r = c.post("/api/digitizer/registrations", json={"patch": got[0]["patch"]})
    assert r.status_code == 200, r.text
    reg_file = r.json()["registration"]
    np.testing.assert_allclose(reg_file["matrix"], reg_live["matrix"], atol=1e-12)
    np.testing.assert_allclose(reg_file["offset_m"], reg_live["offset_m"], atol=1e-12)
    o_file = c.post("/api/digitizer/orientations", json={"node": 7}).json()
    np.testing.assert_allclose(o_file["rotation"], o_live["rotation"], atol=1e-12)
    # and both against the truth the test placed
    err = np.degrees(Rotation.from_matrix(np.array(o_file["rotation"]) @ c_true.T).magnitude())
    assert err < 3 * o_file["uncertainty_deg"]
    # the same points as JSON in metres
    doc = {
        "schema_version": 1,
        "kind": "dimacq.measured_points",
        "instrument": "laser tracker",
        "unit": "m",
        "points": [{"label": k, "xyz": p["position_array_m"]} for k, p in live.items()],
    }
    r = c.post("/api/digitizer/points/import", params={"format": "json"}, content=json.dumps(doc))
    assert r.status_code == 201, r.text
    r = c.post("/api/digitizer/registrations", json={"patch": r.json()[0]["patch"]})
    np.testing.assert_allclose(r.json()["registration"]["matrix"], reg_live["matrix"], atol=1e-12)


@pytest.mark.parametrize(
    ("text", "fmt", "match"),
    [
        ("label,x,y,z\nA,1,2,3\n", "csv", r"x_m,y_m,z_m or x_mm"),
        (
            "label,x_mm,y_mm,z_mm\nA,1,2,oops\n",
            "csv",
            r"row 2 coordinate 2: 'oops' is not a number",
        ),
        ("label,x_mm,y_mm,z_mm\nA,1,2,3\nA,1,2,3\n", "csv", r"label 'A' appears twice"),
        (
            '{"kind": "dimacq.measured_points", "schema_version": 1, "points": []}',
            "json",
            r"unit None; give \"unit\": \"m\" or \"mm\"",
        ),
        ('{"kind": "x"}', "json", r"kind"),
        ("[" * 100 + "]" * 100, "json", r"levels deep"),
        ('{"a": 1' + "0" * 5000 + "}", "json", r"digits"),
        (b"label,x_mm\xff".decode("latin-1"), "csv", r"x_m,y_m,z_m or x_mm"),
    ],
)
def test_bad_files_refused_in_one_line(text: str, fmt: str, match: str) -> None:
    with pytest.raises(SetupError, match=match) as err:
        read_measured_points(text.encode(), fmt)  # type: ignore[arg-type]
    assert "\n" not in str(err.value)


def test_units_and_sigma_read() -> None:
    got = read_measured_points("# CMM\nlabel,x_mm,y_mm,z_mm,sigma_mm\nP1,1000,-2,3.5,0.02\n", "csv")
    (p,) = got.points
    assert p.label == "P1" and p.xyz_m == pytest.approx((1.0, -0.002, 0.0035))
    assert p.sigma_m == pytest.approx(2e-5)


def test_refused_over_http_naming_the_field(api: Api) -> None:
    r = api.client.post(
        "/api/digitizer/points/import", params={"format": "csv"}, content=b"label,x,y,z\nA,1,2,3\n"
    )
    assert 400 <= r.status_code < 500 and "x_mm" in r.text, r.text


@pytest.mark.parametrize("n", [0, 1, 2, 3, 5, 7])
def test_json_array_in_chunks_is_the_response_model_json(n: int) -> None:
    """The big answers (imports, the points list) are built off the event loop a few items per
    pydantic call; the bytes are those of the whole list turned into the model at once,
    whatever the chunk boundaries (chunks of 2 and 3: empty, partial and exact last chunks)."""
    from pydantic import TypeAdapter

    from dimacq.api.routers._common import json_array
    from dimacq.api.schemas import PointOut
    from dimacq.services.geometry.records import StoredPoint

    items = [
        StoredPoint(
            id=i + 1,
            label=f"P{i}\u00e9",
            patch=1 + i % 2,
            position_array_m=[0.1 * i, -2.5e-7, 1e3],
            spread_m=[0.0, 1e-5, 2e-5],
            n_shots=1,
            n_used=1,
            position_m=None if i % 2 else [1.0, 2.0, 3.0 + i],
            created_at="2026-01-02T03:04:05Z",
        )
        for i in range(n)
    ]
    whole = TypeAdapter(list[PointOut])
    expected = whole.dump_json(whole.validate_python(items, from_attributes=True))
    for chunk in (2, 3, 256):
        got = json_array(PointOut, items, chunk=chunk)
        assert got == expected
        assert [p["id"] for p in json.loads(got)] == list(range(1, n + 1))


def test_import_answer_is_the_stored_points(api: Api) -> None:
    """The import's answer (built in the worker) is the stored points as the list sends them,
    and the list's total count is in X-Total-Count."""
    c = api.client
    new_test(api)
    rows = "".join(f"Q{i},{i}.5,{2 * i},-{i}\n" for i in range(600))  # more than one chunk
    r = c.post(
        "/api/digitizer/points/import",
        params={"format": "csv"},
        content=("label,x_mm,y_mm,z_mm\n" + rows).encode(),
    )
    assert r.status_code == 201, r.text[:300]
    assert r.headers["content-type"] == "application/json"
    got = r.json()
    assert [p["label"] for p in got] == [f"Q{i}" for i in range(600)]
    assert got[3]["position_array_m"] == pytest.approx([3.5e-3, 6e-3, -3e-3])
    listed = c.get("/api/digitizer/points", params={"offset": 0, "limit": 10_000})
    assert listed.status_code == 200
    total = int(listed.headers["x-total-count"])
    assert listed.json()[total - 600 :] == got
    page = c.get("/api/digitizer/points", params={"offset": total - 2, "limit": 5})
    assert [p["label"] for p in page.json()] == ["Q598", "Q599"]
    assert page.headers["x-total-count"] == str(total)
