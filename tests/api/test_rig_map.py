"""The rig's channel map through the API (issue 13): read it, check an edit, replace it with the
token; a wrong edit is refused naming the item and the file is left as it was."""

from __future__ import annotations

import shutil
from pathlib import Path

import httpx
from _api_support import TOKEN, make_settings

from dimacq.api import create_app
from dimacq.api.server import BackgroundServer
from dimacq.config import default_config_file
from dimacq.io.rig_file import load_rig_file


def test_rig_file_read_checked_and_replaced(tmp_path: Path) -> None:
    src = default_config_file().parent
    rig_path = tmp_path / "rig" / "rig.toml"
    rig_path.parent.mkdir()
    shutil.copy(src / "rig.toml", rig_path)
    shutil.copytree(src / "calibrations", rig_path.parent / "calibrations")
    settings = make_settings(tmp_path / "data", rig_file=str(rig_path), database_url="")
    with BackgroundServer(create_app(settings)) as srv, httpx.Client(base_url=srv.url) as c:
        got = c.get("/api/rig").json()
        assert got["error"] == "" and got["path"] == str(rig_path)
        first = got["rig"]["responses"][0]
        assert first["sensitivity_mv_per_g"] > 0 and first["key"]
        old = f"sensitivity_mv_per_g = {first['sensitivity_mv_per_g']:.3f}"
        assert old in got["text"]
        new_text = got["text"].replace(old, "sensitivity_mv_per_g = 101.250", 1)
        auth = {"Authorization": f"Bearer {TOKEN}"}
        # the token guards the change
        assert c.put("/api/rig", json={"text": new_text}).status_code == 401
        # a wrong edit: two transducers on one DAQ input → 422 naming the item, file unchanged
        clash = got["text"].replace("physical_channel = 2\n", "physical_channel = 1\n", 1)
        r = c.post("/api/rig/check", json={"text": clash}, headers=auth)
        assert r.status_code == 422 and "physical_channel 1" in r.json()["detail"], r.text
        assert c.put("/api/rig", json={"text": clash}, headers=auth).status_code == 422
        assert c.put("/api/rig", json={"text": "[daq\n"}, headers=auth).status_code == 422
        assert rig_path.read_text(encoding="utf-8") == got["text"]
        ok = c.put("/api/rig", json={"text": new_text}, headers=auth)
        assert ok.status_code == 200, ok.text
        assert ok.json()["rig"]["responses"][0]["sensitivity_mv_per_g"] == 101.25
    # what an acquisition reads next; comments kept; the old file kept beside it
    assert load_rig_file(rig_path).responses[0].sensitivity_mv_per_g == 101.25
    assert rig_path.read_text(encoding="utf-8") == new_text
    assert (rig_path.parent / "rig.toml.previous").read_text(encoding="utf-8") == got["text"]


def test_a_rig_file_cannot_point_the_service_at_files_outside_its_folder(tmp_path: Path) -> None:
    """Issue 24: ``PUT /api/rig`` with a load cell's ``calibration_file`` set to an absolute path,
    then a calibration run, replaced that file (any file the service could write) with a
    calibration JSON. Absolute and ``..`` paths are now refused by the rig check (422 naming the
    item); a path inside the folder that is not the cell's calibration is never replaced."""
    import time

    src = default_config_file().parent
    rig_path = tmp_path / "rig" / "rig.toml"
    rig_path.parent.mkdir()
    shutil.copy(src / "rig.toml", rig_path)
    shutil.copytree(src / "calibrations", rig_path.parent / "calibrations")
    victim = tmp_path / "victim.txt"
    victim.write_text("precious\n")
    (rig_path.parent / "notes.json").write_text('{"mine": true}\n')
    settings = make_settings(tmp_path / "data", rig_file=str(rig_path), database_url="")
    auth = {"Authorization": f"Bearer {TOKEN}"}
    with BackgroundServer(create_app(settings)) as srv, httpx.Client(base_url=srv.url) as c:
        text = c.get("/api/rig").json()["text"]
        current = 'calibration_file = "calibrations/lc-501.json"'
        assert current in text
        for bad, words in (
            (str(victim), "absolute path"),
            ("../victim.txt", "leaves the rig file's folder"),
            ("calibrations/../../victim.txt", "leaves the rig file's folder"),
            ("~/victim.txt", "absolute path"),
        ):
            edited = text.replace(current, f"calibration_file = {bad!r}")
            for method, path in (("post", "/api/rig/check"), ("put", "/api/rig")):
                r = c.request(method.upper(), path, json={"text": edited}, headers=auth)
                assert r.status_code == 422, (bad, r.text)
                assert "calibration_file" in r.json()["detail"] and words in r.json()["detail"]
        assert rig_path.read_text(encoding="utf-8") == text
        # inside the folder but not a calibration: the run fails, the file stays as it was
        edited = text.replace(current, 'calibration_file = "notes.json"')
        assert c.put("/api/rig", json={"text": edited}, headers=auth).status_code == 200
        r = c.post(
            "/api/calibrations/runs", json={"method": "static", "plan": "minimal"}, headers=auth
        )
        assert r.status_code == 202, r.text
        job = r.json()["job_id"]
        deadline = time.monotonic() + 300
        while (snap := c.get(f"/api/jobs/{job}").json())["state"] in ("pending", "running"):
            assert time.monotonic() < deadline
            time.sleep(0.2)
        assert snap["state"] == "failed" and "notes.json" in snap["message"], snap
    assert victim.read_text() == "precious\n"
    assert (rig_path.parent / "notes.json").read_text() == '{"mine": true}\n'
    assert not list(tmp_path.glob("victim*-v*")) and not list(rig_path.parent.glob("notes-v*"))
