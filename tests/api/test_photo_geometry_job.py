"""``/api/photo-geometry``: photo folders filled by upload, and the job that runs the
from-photos chain on one with progress, stores its records as digitized geometry and the
photographed setup, or refuses a set that cannot fix every triax and input (nothing stored);
the job's geometry is the command's (``dimacq geometry from-photos``) on the same folder."""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest
from _api_support import Api
from _photo_support import PhotoSet, small_photo_set


@pytest.fixture(scope="module")
def photo_set(tmp_path_factory: pytest.TempPathFactory) -> PhotoSet:
    return small_photo_set(tmp_path_factory.mktemp("photos") / "set")


def _upload(c: httpx.Client, folder: str, src: Path) -> dict[str, Any]:
    last: dict[str, Any] = {}
    for p in sorted(src.iterdir()):
        r = c.post(
            "/api/photo-geometry/files",
            params={"folder": folder, "name": p.name},
            content=p.read_bytes(),
        )
        assert r.status_code == 201, r.text
        last = r.json()
    return last


def _follow(c: httpx.Client, job_id: str) -> tuple[dict[str, Any], list[str]]:
    """The job's final snapshot and every message seen while it ran."""
    seen: list[str] = []
    deadline = time.monotonic() + 1800  # a guard against a hung job only
    while time.monotonic() < deadline:
        snap = c.get(f"/api/jobs/{job_id}").json()
        if not seen or seen[-1] != snap["message"]:
            seen.append(snap["message"])
        if snap["state"] in ("succeeded", "failed", "cancelled", "interrupted"):
            return snap, seen
        time.sleep(0.05)
    raise AssertionError(f"job {job_id} did not end")


def test_requests_refused_naming_the_field(api: Api, tmp_path: Path) -> None:
    c = api.client
    r = c.post("/api/photo-geometry/jobs", json={"folder": "none-here", "setup_id": 1})
    assert r.status_code == 400 and "no such photo folder" in r.json()["detail"]
    r = c.post(
        "/api/photo-geometry/files", params={"folder": "../up", "name": "a.jpg"}, content=b"x"
    )
    assert r.status_code == 422
    r = c.post("/api/photo-geometry/files", params={"folder": "f1", "name": "run.sh"}, content=b"x")
    assert r.status_code == 422 and "tags.toml" in r.json()["detail"]
    r = c.post(
        "/api/photo-geometry/files", params={"folder": "f1", "name": "a.jpg"}, content=b"jpeg"
    )
    assert r.status_code == 201 and r.json()["photos"] == ["a.jpg"]
    assert not r.json()["tags_file"]
    r = c.post("/api/photo-geometry/jobs", json={"folder": "f1"})
    assert r.status_code == 422 and "setup_id" in r.text
    r = c.post("/api/photo-geometry/jobs", json={"folder": "f1", "setup_id": 999999})
    assert r.status_code == 422 and "setup_id 999999" in r.json()["detail"]
    sid = c.post("/api/setups", json=_one_setup()).json()["id"]
    r = c.post("/api/photo-geometry/jobs", json={"folder": "f1", "setup_id": sid})
    assert r.status_code == 422 and "tags_toml" in r.json()["detail"]
    # a tags file sent with the request that does not read leaves the folder's as it was
    r = c.post(
        "/api/photo-geometry/files", params={"folder": "f1", "name": "tags.toml"}, content=b"x=1"
    )
    assert r.status_code == 201 and r.json()["tags_file"]
    r = c.post(
        "/api/photo-geometry/jobs",
        json={"folder": "f1", "setup_id": sid, "tags_toml": "not [toml"},
    )
    assert r.status_code == 422 and "tags.toml" in r.json()["detail"], r.text
    assert ".part" not in r.json()["detail"]
    kept = api.settings.data_dir / "photos" / "f1" / "tags.toml"
    assert kept.read_text(encoding="utf-8") == "x=1"
    assert sorted(p.name for p in kept.parent.iterdir()) == ["a.jpg", "tags.toml"]
    assert c.delete("/api/photo-geometry/folders/f1").status_code == 204
    assert c.get("/api/photo-geometry/folders/f1").status_code == 404


def _one_setup() -> dict[str, Any]:
    from _page_support import two_input_setup

    return two_input_setup()


@pytest.mark.slow
def test_job_stores_the_commands_geometry(api: Api, photo_set: PhotoSet, tmp_path: Path) -> None:
    from dimacq.cli.main import main

    c = api.client
    have = _upload(c, "cm-two", photo_set.folder)
    assert have["tags_file"] and len(have["photos"]) == 18
    # a set that leaves triaxes and inputs of the setup unfixed: refused, nothing stored
    r = c.post("/api/photo-geometry/jobs", json={"folder": "cm-two", "setup": photo_set.full_setup})
    assert r.status_code == 202, r.text
    snap, _ = _follow(c, r.json()["id"])
    assert snap["state"] == "succeeded", snap
    res = snap["result"]
    assert res["verdict"] == "fail" and res["stored"] is None and res["setup_id"] is None
    missing = [
        n for n in (3, 4) if any(u.startswith(f"triax {n}: no tags") for u in res["unfixed"])
    ]
    assert missing == [3, 4], res["unfixed"]
    assert c.get("/api/digitizer/orientations").json() == []
    # the setup of the photographed triaxes and input: stored
    r = c.post(
        "/api/photo-geometry/jobs",
        json={"folder": "cm-two", "setup": photo_set.setup, "name": "photographed"},
    )
    assert r.status_code == 202, r.text
    snap, seen = _follow(c, r.json()["id"])
    assert snap["state"] == "succeeded", snap
    assert any(m.startswith("photo ") for m in seen), seen
    res = snap["result"]
    assert res["verdict"] in ("ok", "warn"), res["unfixed"]
    assert res["stored"] == {"orientations": 2, "lines_of_action": 1, "verdict": res["verdict"]}
    geo = res["geometry"]
    # the records are the test's orientations and lines of action, as digitized ones are
    ori = {o["node"]: o for o in c.get("/api/digitizer/orientations").json()}
    assert sorted(ori) == photo_set.nodes and ori[photo_set.nodes[0]]["method"] == "photos"
    for o in ori.values():
        _r, p_true = photo_set.truth[f"triax {o['node']}"]
        assert np.linalg.norm(np.array(o["origin_m"]) - p_true) < 1e-3
    # the stored setup is the command's: the photographed positions and their uncertainty
    st = c.get(f"/api/setups/{res['setup_id']}").json()
    assert st["name"] == "photographed"
    by = {(ch["node"], ch["direction"]): ch for ch in st["setup"]["responses"]}
    for n in photo_set.nodes:
        np.testing.assert_allclose(by[(n, 1)]["position_m"], ori[n]["origin_m"], atol=1e-12)
    assert st["setup"]["geometry_uncertainty"] == geo["setup"]["geometry_uncertainty"]
    # the command on the same folder gives the same geometry
    (tmp_path / "setup.json").write_text(json.dumps(photo_set.setup), encoding="utf-8")
    out = tmp_path / "GEOMETRY.json"
    code = main(
        ["geometry", "from-photos", str(photo_set.folder), "--setup", str(tmp_path / "setup.json")]
        + ["--out", str(out), "--quiet"]
    )
    assert code == 0
    cli = json.loads(out.read_text(encoding="utf-8"))
    for a, b in zip(cli["orientations"], geo["orientations"], strict=True):
        assert a["node"] == b["node"]
        np.testing.assert_allclose(a["origin_m"], b["origin_m"], atol=1e-9)
        np.testing.assert_allclose(a["angle_std_deg"], b["angle_std_deg"], rtol=1e-6)
    assert cli["setup"]["responses"] == geo["setup"]["responses"]
    # each tag of the triaxes, the input and the scale bar placed on its body, with its 1σ,
    # none off its place
    placed = cli["adjustment"]["tag_placements"]
    assert {p["body"] for p in placed} == {f"triax {n}" for n in photo_set.nodes} | {
        f"input {n}" for n in photo_set.inputs
    } | {"scale bar"}
    for p in placed:
        assert len(p["shift_mm"]) == 2 and len(p["angle_std_deg"]) == 3 and not p["freed"]
        assert 0 < max(p["shift_std_mm"]) <= 0.05 + 1e-9 and p["z"] < 4.5
