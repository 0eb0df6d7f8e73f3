"""The API contract (issue 13): every route answers malformed JSON with 422 and unknown ids with
404 (walked from the spec, so a new route is checked without being listed here); timestamps,
paging and deletes of the stored resources; FRF values by node and direction over a band, with
units and layout; the solve options of ``dimacq solve`` (reference point, scale to mass)."""

from __future__ import annotations

import re
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from _api_support import Api

from dimacq.api.schemas import MAX_ID
from dimacq.io.setup_file import dump_setup_dict
from dimacq.io.uff import write_frf_uff
from dimacq.simulators.lab.forward import calibration_mass

JSON = {"content-type": "application/json"}


@pytest.fixture(scope="module")
def api_database_url() -> str:
    """This module on SQLite only: the routes' status codes do not depend on the database (the
    schemathesis run covers both backends)."""
    return ""


def _spec_operations(api: Api) -> list[tuple[str, str, dict[str, Any]]]:
    spec = api.client.get("/openapi.json").json()
    return [
        (path, method.upper(), op)
        for path, ops in spec["paths"].items()
        if path.startswith("/api")
        for method, op in ops.items()
    ]


def _fill(path: str, op: dict[str, Any], text: str) -> str:
    """``path`` with its parameters filled: integer ids with MAX_ID (in range, never stored),
    others with ``text``."""
    for name in re.findall(r"\{(\w+)\}", path):
        params = [p for p in op.get("parameters", []) if p["name"] == name]
        is_int = bool(params) and "integer" in str(params[0].get("schema"))
        path = path.replace("{" + name + "}", str(MAX_ID) if is_int else text, 1)
    return path


def _json_body(op: dict[str, Any]) -> bool:
    return "application/json" in op.get("requestBody", {}).get("content", {})


@pytest.mark.slow
def test_malformed_json_is_422_on_every_route_with_a_json_body(api: Api) -> None:
    walked = []
    for path, method, op in _spec_operations(api):
        if not _json_body(op):
            continue
        if "{job_id}" in path:
            continue  # an unknown job is 404 before its body is read (checked below)
        # the body is read before the id is looked up; a label is an upsert's key
        url = _fill(path, op, "R1")
        for bad in (b'{"oops', b"[1, 2", b"\xff\xfe", b"nul"):
            r = api.client.request(method, url, content=bad, headers=JSON)
            assert r.status_code == 422, (method, url, bad, r.status_code, r.text)
            assert r.json()["detail"], r.json()
        walked.append(f"{method} {path}")
    # the walk saw the JSON routes of every resource
    for must in (
        "POST /api/setups",
        "POST /api/solutions",
        "POST /api/acquisitions",
        "POST /api/calibrations",
        "POST /api/calibrations/runs",
        "POST /api/digitizer/points",
        "PUT /api/digitizer/reference-nodes/{label}",
        "POST /api/sensitivity",
        "POST /api/tests",
        "PATCH /api/tests/{test_id}",
    ):
        assert must in walked, (must, walked)


def test_unknown_ids_are_404_on_every_route(api: Api) -> None:
    walked = []
    for path, method, op in _spec_operations(api):
        if "{" not in path or (method == "PUT" and path.endswith("{label}")):
            continue  # PUT of a labelled reference node adds it: no unknown id there
        url = _fill(path, op, "no-such-item")
        body = b"{}" if _json_body(op) else None
        r = api.client.request(method, url, content=body, headers=JSON if body else None)
        assert r.status_code == 404, (method, url, r.status_code, r.text)
        assert "does not exist" in r.json()["detail"] or "no " in r.json()["detail"], r.text
        walked.append(f"{method} {path}")
    for must in (
        "DELETE /api/setups/{setup_id}",
        "DELETE /api/frfs/{frf_id}",
        "DELETE /api/solutions/{solution_id}",
        "DELETE /api/acquisitions/{acq_id}",
        "DELETE /api/digitizer/points/{point_id}",
        "DELETE /api/tests/{test_id}",
        "PATCH /api/tests/{test_id}",
        "DELETE /api/digitizer/reference-nodes/{label}",
        "GET /api/jobs/{job_id}",
        "POST /api/jobs/{job_id}/cancel",
        "POST /api/calibrations/runs/{job_id}/confirm",
    ):
        assert must in walked, (must, walked)


def test_every_response_has_a_schema(api: Api) -> None:
    """Every JSON answer of a route is described in the spec (a model, not a bare object), and
    every list says how it pages."""
    loose = []
    for path, method, op in _spec_operations(api):
        ok = op.get("responses", {})
        code = next((c for c in ("200", "201", "202") if c in ok), None)
        if code is None:
            assert "204" in ok, (method, path)
            continue
        schema = ok[code].get("content", {}).get("application/json", {}).get("schema")
        if schema is None:
            continue  # files, figures, event streams: their media types are documented
        if schema.get("type") == "array" and method == "GET":
            assert "limit" in {p["name"] for p in op.get("parameters", [])}, (method, path)
            assert "X-Total-Count" in ok[code].get("headers", {}), (method, path)
            schema = schema["items"]
        if "$ref" not in schema and schema.get("type") != "array":
            loose.append(f"{method} {path}")
    # what is still a free-form object: documents whose keys the docstring names
    assert set(loose) <= {
        "POST /api/calibrations/runs",
        "GET /api/calibrations/runs/{job_id}/prompt",
        "POST /api/calibrations/runs/{job_id}/confirm",
        "POST /api/devices/{name}/identify",
        # the simulator's truth: the scenario's own JSON (properties, band), shown beside answers
        "GET /api/simulation/truth",
    }, sorted(loose)


# ------------------------------------------------------------------ stored resources
def _model_frf() -> tuple[Any, Any]:
    model = calibration_mass(0, support="free")
    return model, model.frf(np.linspace(10.0, 120.0, 56))


@pytest.fixture(scope="module")
def stored(api: Api, tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    model, frf = _model_frf()
    r = api.client.post("/api/setups", json=dump_setup_dict(model.setup))
    assert r.status_code == 201, r.text
    setup = r.json()
    path = Path(tmp_path_factory.mktemp("frf")) / "model.uff"
    write_frf_uff(path, frf)
    r = api.client.post(
        "/api/frfs/import", params={"setup_id": setup["id"]}, content=path.read_bytes()
    )
    assert r.status_code == 201, r.text
    return {"model": model, "frf": frf, "setup": setup, "frf_set": r.json()}


def _recent(stamp: str) -> bool:
    t = datetime.fromisoformat(stamp)
    return t.tzinfo is not None and abs(datetime.now(UTC) - t) < timedelta(minutes=10)


def test_created_resources_carry_their_id_and_time(api: Api, stored: dict[str, Any]) -> None:
    assert stored["setup"]["id"] >= 1 and _recent(stored["setup"]["created_at"])
    assert stored["setup"]["n_inputs"] == len(stored["model"].setup.excitations)
    fs = stored["frf_set"]
    assert _recent(fs["created_at"]) and fs["n_responses"] == stored["frf"].H.shape[1]
    got = api.client.get(f"/api/setups/{stored['setup']['id']}").json()
    assert got["created_at"] == stored["setup"]["created_at"]


def test_lists_page_with_limit_offset_and_total(api: Api, stored: dict[str, Any]) -> None:
    model = stored["model"]
    ids = [
        api.client.post("/api/setups", json=dump_setup_dict(model.setup)).json()["id"]
        for _ in range(3)
    ]
    full = api.client.get("/api/setups")
    total = int(full.headers["X-Total-Count"])
    assert total == len(full.json()) >= 4
    page = api.client.get("/api/setups", params={"limit": 2, "offset": total - 3})
    assert page.status_code == 200 and page.headers["X-Total-Count"] == str(total)
    assert [s["id"] for s in page.json()] == ids[:2]
    assert api.client.get("/api/setups", params={"offset": total}).json() == []
    for bad in ({"limit": 0}, {"limit": 10_001}, {"offset": -1}):
        r = api.client.get("/api/setups", params=bad)
        assert r.status_code == 422 and r.json()["field"].startswith("query."), r.text
    for i in ids:
        assert api.client.delete(f"/api/setups/{i}").status_code == 204


def test_frf_values_by_node_direction_and_band(api: Api, stored: dict[str, Any]) -> None:
    frf, fid = stored["frf"], stored["frf_set"]["id"]
    out, inp = frf.outputs[4], frf.inputs[2]
    r = api.client.get(
        f"/api/frfs/{fid}/data",
        params={
            "response_node": out.node,
            "response_direction": out.direction,
            "input_node": inp.node,
            "input_direction": inp.direction,
            "f_min_hz": 30.0,
            "f_max_hz": 60.0,
        },
    )
    assert r.status_code == 200, r.text
    d = r.json()
    assert d["layout"] == "[line][response][input]"
    f = np.asarray(d["frequencies_hz"])
    keep = (frf.frequencies_hz >= 30.0) & (frf.frequencies_hz <= 60.0)
    np.testing.assert_array_equal(f, frf.frequencies_hz[keep])
    h = np.asarray(d["real"]) + 1j * np.asarray(d["imag"])
    assert h.shape == (keep.sum(), 1, 1)
    np.testing.assert_allclose(h[:, 0, 0], frf.H[keep, 4, 2], rtol=1e-12)
    assert d["responses"] == [
        {"node": out.node, "direction": out.direction, "kind": "acceleration", "unit": "(m/s²)/N"}
    ]
    assert d["inputs"][0]["unit"] == "N"
    # a node without direction: all its channels
    r = api.client.get(f"/api/frfs/{fid}/data", params={"response_node": out.node, "input": 0})
    n_node = sum(c.node == out.node for c in frf.outputs)
    assert len(r.json()["responses"]) == n_node > 1
    # a node the set does not have: 422 naming it and what the set has
    r = api.client.get(f"/api/frfs/{fid}/data", params={"input_node": 999_999})
    assert r.status_code == 422 and "999999" in r.json()["detail"], r.text
    r = api.client.get(f"/api/frfs/{fid}/data", params={"f_min_hz": 60, "f_max_hz": 30})
    assert r.status_code == 422 and "f_min_hz" in r.json()["detail"]


def test_solve_options_of_the_cli(api: Api, stored: dict[str, Any]) -> None:
    """``reference_point_m`` and ``scale_to_mass_kg`` answer what ``dimacq solve
    --reference-point --scale-to-mass`` does; checked against the model's truth."""
    model, frf = stored["model"], stored["frf"]
    truth = model.properties
    # FRFs 8 % too large (a force transducer sensitivity error): scaling to the known mass
    # restores every parameter
    path = api.settings.data_dir / "scaled.uff"
    write_frf_uff(path, frf.scaled(1.08))
    scaled = api.client.post(
        "/api/frfs/import", params={"setup_id": stored["setup"]["id"]}, content=path.read_bytes()
    ).json()
    p = [0.05, -0.02, 0.1]
    fast = {
        "band_hz": [20, 100],
        "select_responses": False,
        "select_inputs": False,
        "geometry_uncertainty": False,
    }
    r = api.client.post(
        "/api/solutions",
        json={
            "frf_id": scaled["id"],
            "reference_point_m": p,
            "scale_to_mass_kg": truth.mass_kg,
            "length_unit": "cm",
            **fast,
        },
    )
    assert r.status_code == 201, r.text
    res = r.json()["result"]
    assert res["frf_scale_factor"] == pytest.approx(1 / 1.08, rel=1e-6)
    assert res["mass_kg"] == pytest.approx(truth.mass_kg, rel=1e-6)
    assert res["reference_point_m"] == pytest.approx(p)
    assert res["length_unit"] == "cm"
    np.testing.assert_allclose(
        res["inertia_p_kgm2"], truth.inertia_about(np.asarray(p)), rtol=1e-5, atol=1e-9
    )
    # the figure of the stored solution uses the same point and scale
    sid = r.json()["id"]
    assert (
        api.client.get(f"/api/solutions/{sid}/figure", params={"format": "svg"}).status_code == 200
    )
    # options are checked before solving
    for bad, field in (
        ({"scale_to_mass_kg": -1.0}, "body.scale_to_mass_kg"),
        ({"reference_point_m": [0, 0]}, "body.reference_point_m"),
    ):
        r = api.client.post("/api/solutions", json={"frf_id": scaled["id"], **bad})
        assert r.status_code == 422 and r.json()["field"].startswith(field), r.text


def test_deletes(api: Api, stored: dict[str, Any]) -> None:
    model, frf = stored["model"], stored["frf"]
    sid = api.client.post("/api/setups", json=dump_setup_dict(model.setup)).json()["id"]
    path = api.settings.data_dir / "del.uff"
    write_frf_uff(path, frf)
    fid = api.client.post("/api/frfs/import", params={"setup_id": sid}, content=path.read_bytes())
    fid = fid.json()["id"]
    solve = {
        "frf_id": fid,
        "band_hz": [20, 100],
        "select_responses": False,
        "select_inputs": False,
        "geometry_uncertainty": False,
    }
    sol = api.client.post("/api/solutions", json=solve).json()
    # a setup in use is kept, with the reason
    r = api.client.delete(f"/api/setups/{sid}")
    assert r.status_code == 409 and f"FRF sets [{fid}]" in r.json()["detail"], r.text
    # a solution alone
    assert api.client.delete(f"/api/solutions/{sol['id']}").status_code == 204
    assert api.client.get(f"/api/solutions/{sol['id']}").status_code == 404
    # an FRF set with its solutions
    sol2 = api.client.post("/api/solutions", json=solve).json()
    assert api.client.get("/api/solutions", params={"frf_id": fid}).json()[0]["id"] == sol2["id"]
    assert api.client.delete(f"/api/frfs/{fid}").status_code == 204
    assert api.client.get(f"/api/frfs/{fid}").status_code == 404
    assert api.client.get(f"/api/solutions/{sol2['id']}").status_code == 404
    assert api.client.delete(f"/api/setups/{sid}").status_code == 204
    assert api.client.get(f"/api/setups/{sid}").status_code == 404
    assert api.client.delete(f"/api/setups/{sid}").status_code == 404


def test_labels_are_printable_text(api: Api) -> None:
    """A control character in a label is 422 naming the field (PostgreSQL cannot store NUL: it
    was a 500 there, found by schemathesis)."""
    for body, field in (
        ({"label": "a\u0000b"}, "body.label"),
        ({"label": "\u001f"}, "body.label"),
        ({"node": 1, "input_label": "x\u0007", "labels": ["a", "b"]}, "body.input_label"),
    ):
        path = "/api/digitizer/points" if "label" in body else "/api/digitizer/lines-of-action"
        r = api.client.post(path, json=body)
        assert r.status_code == 422 and r.json()["field"] == field, r.text
    r = api.client.put("/api/digitizer/reference-nodes", json={"nodes": {"a\u0000": [0, 0, 0]}})
    assert r.status_code == 422, r.text
    assert api.client.delete("/api/digitizer/reference-nodes/a%00b").status_code == 404


def test_a_digitized_point_can_be_deleted(api: Api) -> None:
    r = api.client.post(
        "/api/digitizer/points",
        json={"label": "mistake", "shots": 2, "sim_probe": {"tip_m": [0.1, 0.2, 1.2]}},
    )
    assert r.status_code == 201, r.text
    pt = r.json()
    assert pt["id"] >= 1 and _recent(pt["created_at"])
    listed = api.client.get("/api/digitizer/points")
    assert pt["id"] in [p["id"] for p in listed.json()]
    assert api.client.delete(f"/api/digitizer/points/{pt['id']}").status_code == 204
    assert pt["id"] not in [p["id"] for p in api.client.get("/api/digitizer/points").json()]


def test_tests_create_list_open_archive_delete(api: Api, stored: dict[str, Any]) -> None:
    r = api.client.post(
        "/api/tests",
        json={
            "article": "bracket B-12",
            "operator": "A. Engineer",
            "date": "2026-11-23",
            "notes": "bungee, 8 triaxes",
        },
    )
    assert r.status_code == 201, r.text
    t = r.json()
    assert t["id"] >= 1 and t["date"] == "2026-11-23" and t["archived"] is False
    assert _recent(t["created_at"]) and t["setup_ids"] == []
    today = api.client.post("/api/tests", json={"article": "cube"}).json()
    assert today["date"] == datetime.now(UTC).date().isoformat()
    # a setup joins the test; the test lists it and the setups filter by it
    body = dump_setup_dict(stored["model"].setup)
    sid = api.client.post("/api/setups", params={"test_id": t["id"]}, json=body).json()["id"]
    assert api.client.get(f"/api/tests/{t['id']}").json()["setup_ids"] == [sid]
    listed = api.client.get("/api/setups", params={"test_id": t["id"]})
    assert [s["id"] for s in listed.json()] == [sid] and listed.headers["X-Total-Count"] == "1"
    assert listed.json()[0]["test_id"] == t["id"]
    r = api.client.post("/api/setups", params={"test_id": MAX_ID}, json=body)
    assert r.status_code == 422 and f"test_id {MAX_ID} does not exist" in r.json()["detail"]
    # change and archive: updated_at moves, archived tests are listed apart
    r = api.client.patch(f"/api/tests/{t['id']}", json={"notes": "redo input 3", "archived": True})
    assert r.status_code == 200, r.text
    t2 = r.json()
    assert t2["notes"] == "redo input 3" and t2["archived"] and t2["operator"] == "A. Engineer"
    assert t2["updated_at"] >= t["updated_at"]
    open_ids = [x["id"] for x in api.client.get("/api/tests", params={"archived": False}).json()]
    archived = [x["id"] for x in api.client.get("/api/tests", params={"archived": True}).json()]
    assert t["id"] in archived and t["id"] not in open_ids and today["id"] in open_ids
    same = api.client.patch(f"/api/tests/{t['id']}", json={"article": None, "notes": None})
    assert same.status_code == 200 and same.json()["notes"] == "redo input 3"  # null: unchanged
    for bad in ({"article": ""}, {"date": "23/11/2026"}, {"archived": "yes"}, {"colour": 1}):
        r = api.client.patch(f"/api/tests/{t['id']}", json=bad)
        assert r.status_code == 422, (bad, r.text)
    # a test with setups is not deleted (nothing measured is lost by a click)
    r = api.client.delete(f"/api/tests/{t['id']}")
    assert r.status_code == 409 and f"setups [{sid}]" in r.json()["detail"]
    assert api.client.delete(f"/api/setups/{sid}").status_code == 204
    assert api.client.delete(f"/api/tests/{t['id']}").status_code == 204
    assert api.client.get(f"/api/tests/{t['id']}").status_code == 404
