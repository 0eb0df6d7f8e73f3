"""The rig's channel map through the API (issue 13): read it, check an edit, replace it with the
token; a wrong edit is refused naming the item and the file is left as it was."""

from __future__ import annotations

import shutil
from pathlib import Path

import httpx
import pytest
from _api_support import TOKEN, make_settings

from dimacq.api import create_app
from dimacq.api.server import BackgroundServer
from dimacq.config import default_config_file
from dimacq.io.rig_file import load_rig_file


@pytest.mark.slow
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


@pytest.mark.slow
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


def _rig_copy(tmp_path: Path) -> Path:
    src = default_config_file().parent
    rig_path = tmp_path / "rig" / "rig.toml"
    rig_path.parent.mkdir()
    shutil.copy(src / "rig.toml", rig_path)
    shutil.copytree(src / "calibrations", rig_path.parent / "calibrations")
    return rig_path


@pytest.mark.slow
def test_daq_inputs_the_daq_does_not_have_are_refused_naming_the_item(tmp_path: Path) -> None:
    """A DAQ input past the DAQ's count (its identity: 64 on the simulated USB DAQ) in a load
    cell's ``daq_channels`` or a transducer's ``physical_channel`` is refused by the check and
    the PUT (422 naming the item and the inputs there are); the file is left as it was."""
    rig_path = _rig_copy(tmp_path)
    settings = make_settings(tmp_path / "data", rig_file=str(rig_path), database_url="")
    auth = {"Authorization": f"Bearer {TOKEN}"}
    with BackgroundServer(create_app(settings)) as srv, httpx.Client(base_url=srv.url) as c:
        daq = next(d for d in c.get("/api/devices").json() if d["name"] == "daq")
        assert daq["connected"] and daq["identity"]["n_channels"] == 64, daq
        text = c.get("/api/rig").json()["text"]
        current = "daq_channels = [25, 26, 27, 28, 29, 30, 31, 32, 33, 34, 35, 36]"
        assert current in text
        cases = [
            (
                text.replace(current, "daq_channels = [250, 251, 252, 253, 254, 255]").replace(
                    'daq_signals = "gauges"', 'daq_signals = "outputs"'
                ),
                "load_cells.0.daq_channels.0",
                "= 250",
            ),
            (
                text.replace(current, current.replace("36]", "64]")),
                "load_cells.0.daq_channels.11",
                "= 64",
            ),
            (
                text.replace("physical_channel = 1\n", "physical_channel = 200\n", 1),
                "responses.0.physical_channel",
                "= 200",
            ),
        ]
        for edited, item, value in cases:
            assert edited != text
            for method, path in (("POST", "/api/rig/check"), ("PUT", "/api/rig")):
                r = c.request(method, path, json={"text": edited}, headers=auth)
                assert r.status_code == 422, (item, r.text)
                detail = r.json()["detail"]
                assert f"item '{item}' {value}" in detail and "the DAQ has 64 inputs" in detail
                assert "give an input 0..63" in detail
                assert r.json()["field"] == f"body.{item}", r.json()
        assert rig_path.read_text(encoding="utf-8") == text
        # the last input the DAQ has is accepted
        ok = text.replace(current, current.replace("36]", "63]"))
        assert c.post("/api/rig/check", json={"text": ok}, headers=auth).status_code == 200


@pytest.mark.slow
def test_a_load_cell_a_bad_rig_left_disconnected_is_back_once_the_rig_is_right(
    tmp_path: Path,
) -> None:
    """A load cell whose calibration file cannot be read is not connected (the device list and
    an acquisition say why); once ``PUT /api/rig`` names a good calibration file the cell is
    opened again and the next acquisition runs with it."""
    import json
    import time

    rig_path = _rig_copy(tmp_path)
    cal = rig_path.parent / "calibrations"
    good = (cal / "lc-501.json").read_text(encoding="utf-8")
    (cal / "lc-501.json").write_text(good[: len(good) // 2], encoding="utf-8")  # truncated
    settings = make_settings(tmp_path / "data", rig_file=str(rig_path), database_url="")
    auth = {"Authorization": f"Bearer {TOKEN}"}
    with (
        BackgroundServer(create_app(settings)) as srv,
        httpx.Client(base_url=srv.url, headers=auth, timeout=300) as c,
    ):
        cell = next(d for d in c.get("/api/devices").json() if d["name"] == "loadcell")
        assert not cell["connected"] and "lc-501.json" in cell["error"], cell
        art = c.get("/api/simulation/article").json()
        sid = c.post("/api/setups", json=art["setup"]).json()["id"]
        body = {"setup_id": sid, "averages_per_input": 1, "min_averages": 1, "seed": 1}
        r = c.post("/api/acquisitions", json=body)
        assert r.status_code == 503, r.text  # the device is unavailable, not the request wrong
        assert "loadcell is not connected" in r.text and "lc-501.json" in r.text, r.text
        # put right: the calibration as it should be, under a new name the rig file now gives
        (cal / "lc-501-fixed.json").write_text(good, encoding="utf-8")
        text = c.get("/api/rig").json()["text"]
        fixed = text.replace(
            'calibration_file = "calibrations/lc-501.json"',
            'calibration_file = "calibrations/lc-501-fixed.json"',
        )
        assert fixed != text
        assert c.put("/api/rig", json={"text": fixed}).status_code == 200
        cell = next(d for d in c.get("/api/devices").json() if d["name"] == "loadcell")
        assert cell["connected"] and cell["error"] == "", cell
        r = c.post("/api/acquisitions", json=body)
        assert r.status_code in (201, 202), r.text
        job = r.json()["job_id"]
        deadline = time.monotonic() + 600
        while (snap := c.get(f"/api/jobs/{job}").json())["state"] in ("pending", "running"):
            assert time.monotonic() < deadline, snap
            time.sleep(0.2)
        assert snap["state"] == "succeeded", json.dumps(snap)[:500]
