"""Every value checked where it enters: each probe below passed the door and failed deeper
(a 500, a failed job, a device left disconnected); each is now a 4xx naming the field, and the
service still serves afterwards."""

from __future__ import annotations

import copy
import json
import tomllib
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from _api_support import Api

from dimacq.io.setup_file import dump_setup_dict, load_setup
from dimacq.io.uff import write_frf_uff
from dimacq.simulators.lab.forward import calibration_mass

ROOT = Path(__file__).resolve().parents[2]
CALIBRATIONS = ROOT / "config" / "rigs" / "calibrations"
EXAMPLE = ROOT / "config" / "examples" / "six_triax_setup.toml"
PLAN_SETUP = ROOT / "config" / "plans" / "calibration-mass-candidates.toml"
PLAN_PROPS = ROOT / "config" / "plans" / "calibration-mass-properties.json"
JSON = {"content-type": "application/json"}


def _serving(api: Api) -> None:
    r = api.client.get("/api/status")
    assert r.status_code == 200, r.text[:300]
    assert api.client.get("/api/setups").status_code == 200


def _refused(r: Any, *names: str, status: tuple[int, ...] = (400, 404, 422)) -> None:
    assert r.status_code in status, (r.status_code, r.text[:500])
    body = r.json()
    text = json.dumps(body)
    for n in names:
        assert n in text, (n, text[:500])


@pytest.fixture(scope="module")
def setup_doc() -> dict[str, Any]:
    return dump_setup_dict(load_setup(EXAMPLE))


def _plan(**kw: object) -> dict[str, Any]:
    props = json.loads(PLAN_PROPS.read_text())
    return {
        "setup": tomllib.loads(PLAN_SETUP.read_text()),
        "properties": {k: props[k] for k in ("mass_kg", "cg_m", "inertia_cg_kgm2")},
        "triaxes": 4,
        "inputs": 8,
        **kw,
    }


# -- setups: positions as strings, coerced values, text ----------------------------------------


@pytest.mark.slow
@pytest.mark.parametrize("value", ["nan", "-Infinity", "inf", "1e999", "1", True])
def test_setup_positions_as_strings_or_booleans_are_refused(
    api: Api, setup_doc: dict[str, Any], value: Any
) -> None:
    doc = copy.deepcopy(setup_doc)
    doc["responses"][0]["position_m"][1] = value
    for path, raw in (
        ("/api/setups", json.dumps(doc).encode()),
        ("/api/setups/import?format=json", json.dumps(doc).encode()),
    ):
        r = api.client.post(path, content=raw, headers=JSON)
        _refused(r, "position_m")
    text = EXAMPLE.read_text()
    at = text.index("position_m = [") + len("position_m = [")
    toml_value = json.dumps(value) if isinstance(value, str) else "true"
    raw = (text[:at] + toml_value + ", " + text[at:].split(",", 1)[1]).encode()
    _refused(api.client.post("/api/setups/import?format=toml", content=raw), "position_m")
    plan = _plan()
    plan["setup"]["responses"][0]["position_m"][0] = value
    _refused(api.client.post("/api/plans", json=plan), "position_m")
    _serving(api)


@pytest.mark.parametrize("ch", ["\x00", "\x85", "\u2028", "\u2029", "\n", "\x1b"])
def test_names_and_labels_are_one_line_of_printable_text(
    api: Api, setup_doc: dict[str, Any], ch: str
) -> None:
    doc = copy.deepcopy(setup_doc)
    doc["name"] = f"box{ch}1"
    _refused(api.client.post("/api/setups", json=doc), "body.name")
    doc = copy.deepcopy(setup_doc)
    doc["responses"][0]["label"] = f"a{ch}b"
    _refused(api.client.post("/api/setups", json=doc), "label")
    _refused(api.client.post("/api/tests", json={"article": f"a{ch}b"}), "body.article")
    _refused(api.client.post("/api/digitizer/points", json={"label": f"p{ch}"}), "body.label")
    doc = json.loads((CALIBRATIONS / "lc-3001.json").read_text())
    doc["serial_number"] = f"LC{ch}1"
    _refused(api.client.post("/api/calibrations", json=doc), "serial_number")
    r = api.client.put("/api/digitizer/reference-nodes", json={"nodes": {f"R{ch}": [0, 0, 0]}})
    _refused(r, "nodes")
    _serving(api)


def test_notes_hold_no_nul(api: Api) -> None:
    """PostgreSQL cannot store NUL in text: a 500 there; refused on every database."""
    _refused(api.client.post("/api/tests", json={"article": "a", "notes": "x\x00y"}), "notes")
    ok = api.client.post("/api/tests", json={"article": "a", "notes": "line 1\nline 2\ttab"})
    assert ok.status_code == 201, ok.text
    tid = ok.json()["id"]
    r = api.client.patch(f"/api/tests/{tid}", json={"notes": "\x00"})
    _refused(r, "body.notes")
    _serving(api)


@pytest.mark.parametrize("value", ["1", True, 1.5])
def test_node_numbers_are_not_coerced(api: Api, setup_doc: dict[str, Any], value: Any) -> None:
    doc = copy.deepcopy(setup_doc)
    doc["responses"][0]["node"] = value
    _refused(api.client.post("/api/setups", json=doc), "node")


# -- the rig file ------------------------------------------------------------------------------


def _rig_text(api: Api) -> str:
    return api.settings.rig_path.read_text()


def _replace(text: str, key: str, value: str, nth: int = 0) -> str:
    lines = text.splitlines()
    hits = [i for i, ln in enumerate(lines) if ln.split("=")[0].strip() == key]
    assert hits, key
    i = hits[nth]
    lines[i] = f"{key} = {value}"
    return "\n".join(lines) + "\n"


@pytest.mark.parametrize(
    ("key", "value"),
    [
        ("sample_rate_hz", '"inf"'),
        ("sample_rate_hz", "1e308"),
        ("sensitivity_mv_per_n", '"1e999"'),
        ("sensitivity_mv_per_n", "1e-300"),
        ("timeout_s", "1e308"),
        ("iepe_current_ma", "1e308"),
        ("sensitivity_mv_per_g", "true"),
        ("calibration_file", '"."'),
        ("calibration_file", '"calibrations"'),
        ("calibration_file", '"rig.toml"'),
        ("calibration_file", '"calibrations/lc-501.json\\u0000"'),
        ("trigger_level_n", "1e-300"),
    ],
)
def test_rig_values_that_broke_later_are_refused_by_the_check(
    api: Api, key: str, value: str
) -> None:
    base = _rig_text(api)
    text = _replace(base, key, value)
    for method, path in (("POST", "/api/rig/check"), ("PUT", "/api/rig")):
        r = api.client.request(method, path, json={"text": text})
        _refused(r, key)
        assert str(api.settings.rig_path.parent) not in r.text, r.text[:300]
    assert _rig_text(api) == base  # nothing written
    _serving(api)


# -- files -------------------------------------------------------------------------------------


def _cal_setup(api: Api) -> tuple[int, Any]:
    model = calibration_mass(0, support="bungee")
    sid = api.client.post("/api/setups", json=dump_setup_dict(model.setup)).json()["id"]
    return sid, model


@pytest.mark.parametrize("kind", ["huge", "negative-axis", "far-axis"])
def test_frf_files_with_unusable_numbers_are_refused(api: Api, tmp_path: Path, kind: str) -> None:
    sid, model = _cal_setup(api)
    f = np.linspace(10.0, 120.0, 24)
    frf = model.frf(f)
    # written as a hostile file would hold them (the model refuses them: set behind its back)
    if kind == "huge":
        object.__setattr__(frf, "H", np.full_like(frf.H, 1e308))
    elif kind == "negative-axis":
        object.__setattr__(frf, "frequencies_hz", f - 1010.0)
    else:
        object.__setattr__(frf, "frequencies_hz", f * 1e299)
    write_frf_uff(tmp_path / "f.uff", frf)
    r = api.client.post(
        "/api/frfs/import", params={"setup_id": sid}, content=(tmp_path / "f.uff").read_bytes()
    )
    _refused(r, "frequenc" if kind != "huge" else "FRF")
    _serving(api)


def test_a_csv_field_of_200000_characters_is_refused(api: Api) -> None:
    raw = b"label,x_m,y_m,z_m\n" + b"P1," + b"1" * 200_000 + b",0,0\n"
    r = api.client.post("/api/digitizer/points/import?format=csv", content=raw)
    _refused(r, "line 2")
    _serving(api)


def test_a_calibration_with_a_short_last_row_is_refused(api: Api) -> None:
    doc = json.loads((CALIBRATIONS / "lc-3001.json").read_text())
    doc["matrix"][-1] = doc["matrix"][-1][:11]
    r = api.client.post("/api/calibrations", json=doc)
    _refused(r, "matrix")
    _serving(api)


# -- requests ---------------------------------------------------------------------------------


@pytest.mark.parametrize("axis", [[1e-300, 0, 0], [1e-200, 1e-200, 0]])
def test_a_simulated_probe_axis_must_have_a_usable_length(api: Api, axis: list[float]) -> None:
    body = {"label": "p", "sim_probe": {"tip_m": [0.1, 0.2, 0.3], "axis": axis}}
    r = api.client.post("/api/digitizer/points", json=body)
    _refused(r, "sim_probe.axis")
    _serving(api)


def test_plan_noise_must_be_usable(api: Api) -> None:
    r = api.client.post("/api/plans", json=_plan(noise=5e-324))
    _refused(r, "body.noise")


def test_calibration_run_averages_within_a_test(api: Api) -> None:
    r = api.client.post("/api/calibrations/runs", json={"averages_per_input": 1000})
    _refused(r, "averages_per_input")
    _serving(api)


def test_acquisition_trigger_level_must_be_usable(api: Api) -> None:
    r = api.client.post("/api/acquisitions", json={"setup_id": 1, "trigger_level_n": 1e-300})
    _refused(r, "trigger_level_n")


@pytest.mark.parametrize("path", ["/api/setups/", "/api/tests/", "/api/frfs/"])
def test_ids_in_canonical_form_only(api: Api, setup_doc: dict[str, Any], path: str) -> None:
    sid = api.client.post("/api/setups", json=setup_doc).json()["id"]
    tid = api.client.post("/api/tests", json={"article": "a"}).json()["id"]
    item = {"/api/setups/": sid, "/api/tests/": tid, "/api/frfs/": 1}[path]
    for digits in ("0" * 5000 + str(item), "0" + str(item), "00" + str(item)):
        r = api.client.get(path + digits)
        assert r.status_code == 404, (path, r.status_code, r.text[:200])


# -- the page's headers on every HTML response -------------------------------------------------


@pytest.mark.parametrize("path", ["/", "/report", "/static/index.html", "/static/report.html"])
def test_every_html_response_has_the_page_headers(api: Api, path: str) -> None:
    r = api.anon.get(path)
    assert r.status_code == 200 and r.headers["content-type"].startswith("text/html")
    assert "frame-ancestors 'none'" in r.headers["content-security-policy"]
    assert r.headers["x-frame-options"] == "DENY"
    assert r.headers["referrer-policy"] == "no-referrer"


# -- big inputs: bounded, paged, deleted in bulk ------------------------------------------------


def test_point_imports_are_bounded_and_points_deleted_in_bulk(api: Api) -> None:
    from dimacq.io.measured_points import MAX_POINTS, MAX_POINTS_BYTES

    rows = "".join(f"Q{i},{i},0,0\n" for i in range(MAX_POINTS + 1))
    r = api.client.post(
        "/api/digitizer/points/import?format=csv", content=b"label,x_mm,y_mm,z_mm\n" + rows.encode()
    )
    _refused(r, "MAX_POINTS")
    r = api.client.post(
        "/api/digitizer/points/import?format=csv", content=b"x" * (MAX_POINTS_BYTES + 1)
    )
    assert r.status_code == 413 and "MAX_POINTS_BYTES" in r.json()["detail"], r.text[:300]
    ok = "".join(f"B{i},{i},0,0\n" for i in range(30))
    r = api.client.post(
        "/api/digitizer/points/import?format=csv", content=b"label,x_mm,y_mm,z_mm\n" + ok.encode()
    )
    assert r.status_code == 201, r.text[:300]
    patch = r.json()[0]["patch"]
    page = api.client.get("/api/digitizer/points?limit=10")
    assert len(page.json()) == 10 and int(page.headers["x-total-count"]) >= 30
    r = api.client.delete(f"/api/digitizer/points?patch={patch}")
    assert r.status_code == 200 and r.json() == {"deleted": 30}, r.text
    left = api.client.get("/api/digitizer/points").json()
    assert not [p for p in left if p["patch"] == patch]
    _serving(api)


# -- start-up refusals ------------------------------------------------------------------------


@pytest.mark.slow
@pytest.mark.parametrize("kind", ["file", "unreadable"])
def test_a_bad_data_dir_is_refused_in_one_line_exit_2(tmp_path: Path, kind: str) -> None:
    import os
    import subprocess
    import sys

    from dimacq.api.server import free_port

    target = tmp_path / "data"
    if kind == "file":
        target.write_text("not a folder")
    else:
        target.mkdir()
        (target / "inner").mkdir()
        target = target / "inner"
        target.chmod(0)
        if os.geteuid() == 0:
            pytest.skip("root reads any folder")
    env = {k: v for k, v in os.environ.items() if not k.startswith("DIMACQ_")}
    env["DIMACQ_DATA_DIR"] = str(target)
    try:
        out = subprocess.run(
            [sys.executable, "-m", "dimacq.cli.main", "serve", "--port", str(free_port())],
            env=env,
            capture_output=True,
            text=True,
            timeout=120,
        )
    finally:
        target.chmod(0o700)
    assert out.returncode == 2, (out.returncode, out.stderr[-2000:])
    lines = [ln for ln in out.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and "data_dir" in lines[0] and "DIMACQ_DATA_DIR" in lines[0], lines


def test_a_full_data_dir_is_refused(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import shutil

    from dimacq.config import load_settings
    from dimacq.errors import SetupError

    settings = load_settings(data_dir=tmp_path / "d", token="t")
    assert settings.check_data_dir() == tmp_path / "d"
    monkeypatch.setattr(shutil, "disk_usage", lambda _p: shutil._ntuple_diskusage(10, 10, 1000))  # type: ignore[attr-defined]
    with pytest.raises(SetupError, match=r"0 MiB free, less than 64 MiB \(MIN_FREE_BYTES\)"):
        settings.check_data_dir()
