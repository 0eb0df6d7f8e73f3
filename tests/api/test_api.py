"""REST API: access, errors naming the field, setups/FRFs/solutions, devices, digitizer, jobs."""

from __future__ import annotations

import io
import json
import threading
from pathlib import Path

import httpx
import numpy as np
import pytest
from _api_support import Api, make_settings

from dimacq.api import create_app
from dimacq.api.server import BackgroundServer
from dimacq.io.setup_file import dump_setup_dict, load_setup
from dimacq.io.uff import write_frf_uff
from dimacq.pipeline import dim
from dimacq.simulators.lab.forward import calibration_mass

EXAMPLE = Path(__file__).resolve().parents[2] / "config" / "examples" / "six_triax_setup.toml"


def _model_frf():
    model = calibration_mass(0, support="bungee")
    frf = model.frf(np.linspace(10.0, 120.0, 56))
    return model, frf


@pytest.mark.slow
def test_status_docs_and_openapi(api: Api) -> None:
    st = api.anon.get("/api/status")
    assert st.status_code == 200
    assert st.json()["devices"]["digitizer"]["connected"] is True
    spec = api.anon.get("/openapi.json").json()
    assert "/api/solutions" in spec["paths"]
    assert spec["paths"]["/api/setups"]["post"]["security"] == [{"bearer": []}]
    assert api.anon.get("/docs").status_code == 200


def test_status_shows_a_device_lost_by_its_worker_at_once(api: Api) -> None:
    """The status touches no device: it reports what the code using the device last saw. The
    acquisition's event of the DAQ dropping off the bus (the run restarts) makes the DAQ not
    connected, with the reason and since when, until the session reports it found again."""
    before = api.anon.get("/api/status").json()["devices"]["daq"]
    assert before["connected"] is True and before["simulated"] is True, before
    lab = api.lab
    try:
        lab.devices.on_acquisition_event({"device": "daq", "kind": "restart", "message": "x"})
        lost = api.anon.get("/api/status").json()["devices"]["daq"]
        assert lost["connected"] is False and "dropped off the bus" in lost["error"], lost
        assert lost["since"] >= before["since"]
        assert "dropped off the bus" in api.anon.get("/api/devices/daq").json()["lost"]
        lab.devices.on_acquisition_event({"device": "daq", "kind": "reconnected"})
        back = api.anon.get("/api/status").json()["devices"]["daq"]
        assert back["connected"] is True and back["error"] == "", back
        lab.devices.on_acquisition_event({"device": "daq", "kind": "lost", "message": "t/o"})
        gone = api.anon.get("/api/status").json()["devices"]["daq"]
        assert gone["connected"] is False and "stopped answering" in gone["error"], gone
        lab.devices.mark("digitizer", "port lost (gone); reconnecting")  # the session's call
        dig = api.anon.get("/api/status").json()["devices"]["digitizer"]
        assert dig["connected"] is False and "port lost" in dig["error"], dig
    finally:
        lab.devices.mark("daq", "")
        lab.devices.mark("digitizer", "")


def test_state_change_needs_token_checked_before_the_body(api: Api) -> None:
    # malformed JSON and a wrong schema: an anonymous caller still gets 401, not 400/422
    r = api.anon.post(
        "/api/setups", content=b"{not json", headers={"content-type": "application/json"}
    )
    assert r.status_code == 401 and r.json()["field"] == "Authorization"
    r = api.anon.post(
        "/api/setups", json={"responses": 3}, headers={"Authorization": "Bearer wrong"}
    )
    assert r.status_code == 401
    assert api.anon.post("/api/jobs/x/cancel").status_code == 401
    assert api.anon.put("/api/digitizer/reference-nodes", json={}).status_code == 401
    # the same call with the token reaches validation
    r = api.client.post("/api/setups", json={"responses": 3})
    assert r.status_code == 422
    # reads are open
    assert api.anon.get("/api/setups").status_code == 200


def test_cors_closed_unless_configured(api: Api, tmp_path: Path) -> None:
    pre = {"Origin": "http://evil.example", "Access-Control-Request-Method": "POST"}
    r = api.anon.options("/api/setups", headers=pre)
    assert "access-control-allow-origin" not in r.headers
    settings = make_settings(tmp_path, cors_origins=["http://ui.example"])
    with BackgroundServer(create_app(settings)) as srv, httpx.Client(base_url=srv.url) as c:
        ok = c.options(
            "/api/setups",
            headers={"Origin": "http://ui.example", "Access-Control-Request-Method": "POST"},
        )
        assert ok.headers.get("access-control-allow-origin") == "http://ui.example"
        bad = c.options("/api/setups", headers=pre)
        assert "access-control-allow-origin" not in bad.headers


def test_bad_requests_get_4xx_naming_the_field(api: Api) -> None:
    body = dump_setup_dict(load_setup(EXAMPLE))
    body["responses"][2]["direction_gcs"] = [1.0, 1.0, 0.0]
    r = api.client.post("/api/setups", json=body)
    assert r.status_code == 422
    assert "responses[2]" in r.json()["detail"] and "direction_gcs" in r.json()["detail"]
    r = api.client.post("/api/solutions", json={"frf_id": 0})
    assert r.status_code == 422 and r.json()["field"] == "body.frf_id"
    r = api.client.post("/api/solutions", json={"frf_id": 1, "band_hz": [50, 10], "extra": 1})
    assert r.status_code == 422 and "extra" in r.json()["detail"]
    assert api.client.get("/api/setups/999999").status_code == 404
    r = api.client.post("/api/setups/import?format=json", content=b"{oops")
    assert r.status_code == 422 and "not valid JSON" in r.json()["detail"]
    r = api.client.post("/api/setups/import?format=toml", content=b"[[responses]\n")
    assert r.status_code == 422 and "not valid TOML" in r.json()["detail"]
    r = api.client.post("/api/setups/import?format=json", content=b"[1, 2]")
    assert r.status_code == 422 and "must be a JSON object" in r.json()["detail"]
    r = api.client.post("/api/setups/import?format=uff", content=b"garbage\n-1\n")
    assert r.status_code in (400, 422)
    r = api.client.post("/api/frfs/import?setup_id=999999", content=b"x")
    assert r.status_code == 422 and "setup_id" in r.json()["detail"]
    # device state: identify a device that is not connected → 409 naming it
    api.lab.devices.require("daq").connected = False
    r = api.client.post("/api/devices/daq/identify")
    assert r.status_code == 409 and "daq" in r.json()["detail"]
    assert api.client.post("/api/devices/nope/connect").status_code == 404


@pytest.mark.slow
def test_setup_frf_solution_round_trip(api: Api) -> None:
    model, frf = _model_frf()
    r = api.client.post("/api/setups", json=dump_setup_dict(model.setup))
    assert r.status_code == 201, r.text
    sid = r.json()["id"]
    toml_text = api.client.get(f"/api/setups/{sid}/export", params={"format": "toml"})
    assert toml_text.status_code == 200 and b"responses" in toml_text.content
    again = api.client.post(
        "/api/setups/import", params={"format": "toml"}, content=toml_text.content
    )
    assert again.status_code == 201
    # FRFs as UFF, matched to the setup
    buf = Path(api.settings.data_dir) / "upload.uff"
    write_frf_uff(buf, frf)
    r = api.client.post("/api/frfs/import", params={"setup_id": sid}, content=buf.read_bytes())
    assert r.status_code == 201, r.text
    fid = r.json()["id"]
    assert r.json()["n_responses"] == frf.H.shape[1] and r.json()["n_inputs"] == 24
    data = api.client.get(f"/api/frfs/{fid}/data", params={"response": 0, "input": 0}).json()
    h = np.array(data["real"])[:, 0, 0] + 1j * np.array(data["imag"])[:, 0, 0]
    np.testing.assert_allclose(h, frf.H[:, 0, 0], rtol=1e-12)
    # whole-test UFF export → import gives a new setup + FRF set
    uff = api.client.get(f"/api/frfs/{fid}/uff")
    assert uff.status_code == 200
    imp = api.client.post(
        "/api/setups/import", params={"format": "uff"}, content=uff.content
    ).json()
    assert imp["frf_id"] is not None
    # solve through the API = solve directly
    # (the equation-error estimate, as dim.solve; the default output error agrees to ~1e-11)
    r = api.client.post(
        "/api/solutions",
        json={"frf_id": fid, "band_hz": [20, 100], "unbiased": False, "refine_geometry": False},
    )
    assert r.status_code == 201, r.text
    sol = r.json()
    direct = dim.solve(frf, model.setup, band_hz=(20, 100)).to_json()
    assert sol["result"]["mass_kg"] == pytest.approx(direct["mass_kg"], rel=1e-12)
    assert sol["result"]["mass_kg"] == pytest.approx(model.properties.mass_kg, rel=1e-6)
    assert set(direct) <= set(sol["result"])
    got = api.client.get(f"/api/solutions/{sol['id']}").json()
    assert got["result"]["cg_m"] == sol["result"]["cg_m"]
    diags = api.client.get(f"/api/solutions/{sol['id']}/diagnostics").json()
    assert diags == direct["diagnostics"] and {d["code"] for d in diags} >= {
        "mass_positive",
        "inertia_cg_positive_definite",
        "triangle_inequality",
        "cg_inside_hull",
    }
    assert all(d["ok"] for d in diags)
    assert sol["result"]["verdict"] == "ok" and sol["result"]["verdict_reasons"]
    # no band, no flags: the defaults (automatic band, selections, intervals, verdict)
    r = api.client.post("/api/solutions", json={"frf_id": fid})
    assert r.status_code == 201, r.text
    sel = r.json()["result"]
    for key in (
        "excluded_responses",
        "excluded_inputs",
        "uncertainty",
        "verdict",
        "verdict_reasons",
    ):
        assert key in sel
    assert sel["band_selection"]["automatic"] and sel["verdict"] in ("ok", "warn")
    assert sel["mass_kg"] == pytest.approx(model.properties.mass_kg, rel=1e-3)
    lo, hi = sel["uncertainty"]["m"]["ci95"]
    assert lo <= model.properties.mass_kg <= hi
    png = api.client.get(f"/api/solutions/{sol['id']}/figure")
    assert png.status_code == 200 and png.content[:4] == b"\x89PNG"
    # the parameters against frequency behind it (the page's plot): in the band, the per-line
    # masses scatter about the joint estimate
    spec = api.client.get(f"/api/solutions/{sol['id']}/spectrum").json()
    f_sp = np.asarray(spec["frequencies_hz"])
    per_line = np.asarray(spec["per_line"], float)
    assert spec["parameters"][0] == "m" and per_line.shape == (f_sp.size, 10)
    in_band = (f_sp >= spec["band_hz"][0]) & (f_sp <= spec["band_hz"][1])
    assert np.median(per_line[in_band, 0]) == pytest.approx(spec["headline"][0], rel=0.02)


@pytest.mark.slow
def test_digitizer_chain_to_setup(api: Api) -> None:
    """Reference nodes → registration → jig orientation → line of action → setup."""
    from scipy.spatial.transform import Rotation

    from dimacq.services.geometry.digitizer_config import load_jig

    c = api.client
    rot = Rotation.from_euler("xyz", [10, -5, 30], degrees=True)
    off = np.array([0.1, -0.2, 1.1])  # DACS = rot(GCS) + off

    def to_dacs(p):
        return (rot.apply(np.asarray(p)) + off).tolist()

    def put(label, gcs):
        r = c.post(
            "/api/digitizer/points",
            json={"label": label, "sim_probe": {"tip_m": to_dacs(gcs), "axis": [0, 0, 1]}},
        )
        assert r.status_code == 201, r.text

    refs = {
        f"R{i}": p
        for i, p in enumerate([[0, 0, 0], [0.3, 0, 0], [0, 0.3, 0], [0, 0, 0.3], [0.3, 0.3, 0.2]])
    }
    assert c.put("/api/digitizer/reference-nodes", json={"nodes": refs}).status_code == 200
    for k, v in refs.items():
        put(k, v)
    reg = c.post("/api/digitizer/registrations", json={}).json()
    assert reg["registration"]["rms_m"] < 1e-3
    jig = load_jig()
    c_true = Rotation.from_euler("zyx", [20, 10, -15], degrees=True).as_matrix()
    origin = np.array([0.05, 0.1, 0.05])
    for lab, xl in zip(jig.labels, jig.points_local_m, strict=True):
        put(f"jig7/{lab}", c_true @ xl + origin)
    ori = c.post("/api/digitizer/orientations", json={"node": 7}).json()
    err = Rotation.from_matrix(np.array(ori["rotation"]) @ c_true.T).magnitude()
    assert np.degrees(err) < 0.5
    d = np.array([0.0, 0.6, -0.8])
    p_in = np.array([0.1, 0.0, 0.2])
    put("in101", p_in)
    for k, s in enumerate((0.05, 0.1, 0.15)):
        put(f"loa101/{k}", p_in - s * d)
    loa = c.post(
        "/api/digitizer/lines-of-action",
        json={"node": 101, "input_label": "in101", "labels": ["loa101/0", "loa101/1", "loa101/2"]},
    ).json()
    assert np.degrees(np.arccos(np.clip(np.dot(loa["direction"], d), -1, 1))) < 1.0
    pts = c.get("/api/digitizer/points").json()
    assert len(pts) == 5 + 24 + 4 and all(p["position_m"] is not None for p in pts)
    r = c.post("/api/setups/from-geometry", json={"name": "geo", "triaxes": [7], "inputs": [101]})
    assert r.status_code == 201, r.text
    s = r.json()["setup"]
    assert s["responses"][0]["node"] == 7 and len(s["responses"]) == 3
    # unknown node refused, naming it
    r = c.post("/api/setups/from-geometry", json={"triaxes": [8]})
    assert r.status_code == 422 and "[8]" in r.json()["detail"]
    sos = c.post("/api/digitizer/speed-of-sound").json()["speed_of_sound_m_s"]
    assert sos == pytest.approx(343.2, abs=2)
    assert c.get("/api/digitizer/speed-of-sound").json()["speed_of_sound_m_s"] == sos


def test_jobs_progress_cancel_and_events(api: Api) -> None:
    gate = threading.Event()

    def work(ctx):
        for i in range(100):
            ctx.check_cancelled()
            ctx.progress(i / 100, f"step {i}")
            if gate.wait(0.01):
                break
        return {"steps": i}

    job = api.lab.jobs.submit("test", work)
    with api.anon.stream("GET", f"/api/jobs/{job.id}/events", params={"poll_s": 0.02}) as r:
        assert r.headers["content-type"].startswith("text/event-stream")
        events = []
        for line in r.iter_lines():
            if line.startswith("event:"):
                events.append(line.split(":", 1)[1].strip())
            if len(events) == 3:
                assert api.client.post(f"/api/jobs/{job.id}/cancel").status_code == 200
            if line.startswith("data:") and events and events[-1] == "end":
                final = json.loads(line[5:])
                break
    assert events[0] == "status" and events[-1] == "end"
    assert final["state"] == "cancelled"
    assert api.client.get(f"/api/jobs/{job.id}").json()["state"] == "cancelled"
    assert api.anon.get("/api/jobs/nope/events").status_code == 404
    gate.set()


def test_calibrations(api: Api) -> None:
    body = {
        "schema_version": 1,
        "kind": "dimacq.loadcell_calibration",
        "serial_number": "LC501",
        "date": "2026-11-21",
        "method": "inertial",
        "gauge_unit": "V",
        "force_unit": "N",
        "moment_unit": "N*m",
        "matrix": np.eye(6, 12).tolist(),
    }
    r = api.client.post("/api/calibrations", json=body)
    assert r.status_code == 201, r.text
    assert api.client.get(f"/api/calibrations/{r.json()['id']}").json()["serial_number"] == "LC501"
    body["matrix"] = [[1, 2]]
    bad = api.client.post("/api/calibrations", json=body)
    assert 400 <= bad.status_code < 500 and "matrix" in bad.json()["detail"]


_ = io


def test_sensitivity_study_job(api: Api) -> None:
    body = {"half_size_m": 0.02, "sensors": 1, "max_angle_deg": 1.0, "trials": 200, "seed": 1}
    r = api.client.post("/api/sensitivity", json=body)
    assert r.status_code == 202, r.text
    snap = api.lab.jobs.wait(r.json()["job_id"], 30)
    assert snap["state"] == "succeeded", snap
    study = api.client.get(f"/api/sensitivity/{r.json()['id']}").json()
    from dimacq.pipeline.sensitivity import cube_study

    direct = cube_study(0.02, n_sensors=1, max_angle_deg=1.0, n_trials=200, seed=1).to_json()
    assert study["result"] == json.loads(json.dumps(direct))
    bad = api.client.post("/api/sensitivity", json={**body, "sensors": 9})
    assert bad.status_code == 422 and "sensors" in bad.json()["detail"]


_EXAMPLES = Path(__file__).resolve().parents[2] / "config" / "examples"


def _store_example(api: Api, test_id: int | None) -> tuple[int, int]:
    params = {"format": "toml"} | ({"test_id": test_id} if test_id else {})
    setup = api.client.post(
        "/api/setups/import",
        params=params,
        content=(_EXAMPLES / "six_triax_setup.toml").read_bytes(),
    )
    assert setup.status_code == 201, setup.text
    sid = setup.json()["id"]
    frf = api.client.post(
        "/api/frfs/import",
        params={"setup_id": sid},
        content=(_EXAMPLES / "six_triax_frf.uff").read_bytes(),
    )
    assert frf.status_code == 201, frf.text
    return sid, frf.json()["id"]


@pytest.mark.slow
def test_envelope_and_the_lists_of_one_test(api: Api) -> None:
    """``GET /api/frfs/{id}/envelope`` (what the report and plots fetch instead of the whole
    set) against ``/data``; the lists of one test (``?test_id=``) of FRF sets and solutions."""
    test = api.client.post("/api/tests", json={"article": "envelope frame"}).json()
    _, fid = _store_example(api, test["id"])
    _, other = _store_example(api, None)
    data = api.client.get(f"/api/frfs/{fid}/data", params={"input": 1}).json()
    env = api.client.get(f"/api/frfs/{fid}/envelope", params={"input": 1, "points": 7})
    assert env.status_code == 200, env.text
    e = env.json()
    mag = np.hypot(np.array(data["real"]), np.array(data["imag"]))  # (lines, responses, 1)
    groups = np.array_split(np.arange(mag.shape[0]), 7)  # sizes differ by at most one line
    assert e["n_lines"] == mag.shape[0] and e["layout"] == "[point][response][input]"
    assert e["lines_per_point"] == max(len(g) for g in groups)
    assert sorted(len(g) for g in groups) == sorted(
        round((k + 1) * mag.shape[0] / 7) - round(k * mag.shape[0] / 7) for k in range(7)
    )
    f = np.array(data["frequencies_hz"])
    lo = np.array(e["f_lo_hz"])
    hi = np.array(e["f_hi_hz"])
    for k in range(7):
        rows = (f >= lo[k]) & (f <= hi[k])
        np.testing.assert_allclose(e["magnitude_max"][k], mag[rows].max(axis=0), rtol=1e-12)
        np.testing.assert_allclose(e["magnitude_min"][k], mag[rows].min(axis=0), rtol=1e-12)
    assert e["responses"] == data["responses"] and e["inputs"] == data["inputs"]
    # several inputs in one call, in the order asked
    two = api.client.get(f"/api/frfs/{fid}/envelope", params={"input": [2, 1], "points": 7}).json()
    assert [i["node"] for i in two["inputs"]][1] == data["inputs"][0]["node"]
    np.testing.assert_allclose(
        np.array(two["magnitude_max"])[:, :, 1], np.array(e["magnitude_max"])[:, :, 0]
    )
    far = api.client.get(f"/api/frfs/{fid}/envelope", params={"input": [0, 99]})
    assert far.status_code == 422 and "input index 99" in far.json()["detail"]
    # the band's mean coherence: what the report's data quality table shows
    band = {"f_min_hz": 20, "f_max_hz": 60, "points": 1}
    b = api.client.get(f"/api/frfs/{fid}/envelope", params=band).json()
    d = api.client.get(f"/api/frfs/{fid}/data", params={"f_min_hz": 20, "f_max_hz": 60}).json()
    assert b["n_lines"] == len(d["frequencies_hz"]) and len(b["frequencies_hz"]) == 1
    if d["coherence"] is None:
        assert b["coherence_mean"] is None
    else:
        c = np.array(d["coherence"], dtype=float)
        np.testing.assert_allclose(b["coherence_mean"], np.nanmean(c, axis=0), rtol=1e-12)
    # refused: unknown set 404, bad points / band 422
    assert api.client.get("/api/frfs/999999/envelope").status_code == 404
    assert api.client.get(f"/api/frfs/{fid}/envelope", params={"points": 0}).status_code == 422
    bad = api.client.get(f"/api/frfs/{fid}/envelope", params={"f_min_hz": 9, "f_max_hz": 1})
    assert bad.status_code == 422 and "f_min_hz" in bad.json()["detail"]
    # lists of one test: its FRF sets and their solutions only
    ids = [x["id"] for x in api.client.get("/api/frfs", params={"test_id": test["id"]}).json()]
    assert ids == [fid] and other not in ids
    quick = {"unbiased": False, "refine_geometry": False, "band_hz": [10, 100]}
    s1 = api.client.post("/api/solutions", json={"frf_id": fid, **quick})
    assert s1.status_code == 201, s1.text
    api.client.post("/api/solutions", json={"frf_id": other, **quick})
    sols = api.client.get("/api/solutions", params={"test_id": test["id"]})
    assert [x["id"] for x in sols.json()] == [s1.json()["id"]]
    assert sols.headers["X-Total-Count"] == "1"
