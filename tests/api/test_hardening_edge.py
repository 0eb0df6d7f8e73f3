"""API hardening, second pass (issue 24, "no 500"): every probe below answered 500 (or reset the
connection) before its fix; each now gets a 4xx whose message names the field or the limit."""

from __future__ import annotations

import json
import os
import re
import stat
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from _api_support import Api, make_settings

from dimacq.config import load_settings
from dimacq.io.documents import MAX_DEPTH, MAX_DOCUMENT_BYTES, MAX_VALUES
from dimacq.io.setup_file import dump_setup_dict, load_setup
from dimacq.io.uff import write_frf_uff
from dimacq.persistence import models as m
from dimacq.persistence import open_database
from dimacq.services.lab import store
from dimacq.simulators.lab.forward import calibration_mass

ROOT = Path(__file__).resolve().parents[2]
CALIBRATIONS = ROOT / "config" / "rigs" / "calibrations"
EXAMPLE = ROOT / "config" / "examples" / "six_triax_setup.toml"
LONG_ID = "9" * 5000  # past Python's 4,300-digit int() limit (Starlette's int convertor raised)


@pytest.fixture(scope="module")
def api_database_url() -> str:
    """SQLite only: nothing probed here reaches the database's own limits."""
    return ""


# -- 1. path ids of any length ------------------------------------------------------------------


@pytest.mark.parametrize(
    "digits",
    [LONG_ID, "0" * 4999 + "7", "1" * 4301, "12345678901234567890"],
    ids=["5000-nines", "5000-leading-zeros", "4301-ones", "20-digits"],
)
def test_path_ids_of_any_length_are_404(api: Api, digits: str) -> None:
    for method, path in (
        ("GET", f"/api/setups/{digits}"),
        ("DELETE", f"/api/setups/{digits}"),
        ("GET", f"/api/setups/{digits}/export"),
        ("GET", f"/api/tests/{digits}"),
        ("GET", f"/api/acquisitions/{digits}"),
        ("GET", f"/api/acquisitions/1/averages/{digits}"),
        ("POST", f"/api/acquisitions/{digits}/stop"),
        ("GET", f"/api/frfs/{digits}/envelope"),
        ("GET", f"/api/calibrations/{digits}"),
        ("GET", f"/api/sensitivity/{digits}"),
        ("GET", f"/api/solutions/{digits}/figure"),
        ("DELETE", f"/api/digitizer/points/{digits}"),
    ):
        r = api.client.request(method, path)
        assert r.status_code == 404, (method, path[:40], r.status_code, r.text[:300])
        assert "does not exist" in r.json()["detail"], r.text[:300]
        assert len(r.json()["detail"]) < 300  # the id is shortened in the message


def test_query_ids_of_any_length_are_422_naming_the_field(api: Api) -> None:
    r = api.client.get(f"/api/frfs?test_id={LONG_ID}")
    assert r.status_code == 422 and r.json()["field"] == "query.test_id", r.text[:300]


# -- 2. JSON and TOML bodies within limits ------------------------------------------------------

DEEP_JSON = b"[" * 100_000 + b"]" * 100_000
DEEP_OBJECT = b'{"a": ' + b"[" * 100_000 + b"]" * 100_000 + b"}"
HUGE_NUMBER = b'{"a": ' + b"9" * 5000 + b"}"


@pytest.mark.parametrize(
    ("path", "raw", "limit"),
    [
        ("/api/calibrations", DEEP_JSON, f"more than {MAX_DEPTH} levels deep"),
        ("/api/calibrations", DEEP_OBJECT, f"more than {MAX_DEPTH} levels deep"),
        ("/api/calibrations", HUGE_NUMBER, "more than 4300 digits"),
        ("/api/calibrations/runs", DEEP_OBJECT, f"more than {MAX_DEPTH} levels deep"),
        ("/api/calibrations/runs", HUGE_NUMBER, "more than 4300 digits"),
        ("/api/acquisitions/1/review", DEEP_OBJECT, f"more than {MAX_DEPTH} levels deep"),
        ("/api/setups", DEEP_JSON, "recursion limit"),
        ("/api/setups/from-geometry", HUGE_NUMBER, "number out of range"),
        ("/api/setups/import?format=json", DEEP_JSON, f"more than {MAX_DEPTH} levels deep"),
        ("/api/setups/import?format=json", HUGE_NUMBER, "more than 4300 digits"),
    ],
    ids=lambda v: v if isinstance(v, str) and len(v) < 40 else "",
)
def test_json_bodies_deep_or_with_huge_numbers_are_422(
    api: Api, path: str, raw: bytes, limit: str
) -> None:
    r = api.client.post(path, content=raw, headers={"Content-Type": "application/json"})
    assert r.status_code == 422, (path, r.status_code, r.text[:300])
    assert limit in r.json()["detail"], r.text[:300]
    if "import" not in path:  # an upload names its file ("uploaded setup"), a body the body
        assert r.json()["field"] == "body", r.json()


TOML_BOMBS = {
    "deep arrays": "a = " + "[" * 50_000 + "]" * 50_000,
    "deep inline tables": "a = " + "{b=" * 5000 + "1" + "}" * 5000,
    "deep dotted keys": "a" + ".a" * 5000 + " = 1",
    "deep table header": "[" + ".".join(["t"] * 5000) + "]\nx = 1",
    "huge number": "a = " + "9" * 5000,
    "many values": "a = [" + "1," * (MAX_VALUES + 10) + "]",
    "huge string": 'a = "' + "x" * (MAX_DOCUMENT_BYTES + 10) + '"',
}


@pytest.mark.slow
@pytest.mark.parametrize("name", list(TOML_BOMBS))
def test_toml_bombs_are_422_naming_the_limit(api: Api, name: str) -> None:
    text = TOML_BOMBS[name]
    limits = ("MAX_DEPTH", "MAX_VALUES", "MAX_DOCUMENT_BYTES", "4300 digits")
    r = api.client.post("/api/setups/import?format=toml", content=text.encode())
    assert r.status_code == 422, (name, r.status_code, r.text[:300])
    assert any(k in r.json()["detail"] for k in limits), r.text[:300]
    if len(text) < 1_000_000:  # the rig text itself is limited to 1,000,000 characters
        for method, path in (("POST", "/api/rig/check"), ("PUT", "/api/rig")):
            r = api.client.request(method, path, json={"text": text})
            assert r.status_code == 422, (name, path, r.status_code, r.text[:300])
            assert any(k in r.json()["detail"] for k in limits), r.text[:300]


def test_real_documents_pass_the_limits(api: Api) -> None:
    """The limits leave real documents alone: a calibration (6×12 matrix), the example setup."""
    doc = (CALIBRATIONS / "lc-3001.json").read_bytes()
    r = api.client.post("/api/calibrations", content=doc)
    assert r.status_code == 201, r.text[:300]
    r = api.client.post("/api/setups/import?format=toml", content=EXAMPLE.read_bytes())
    assert r.status_code == 201, r.text[:300]


# -- 3. finite numbers only ---------------------------------------------------------------------

JSON = {"content-type": "application/json"}


def _with(doc: dict[str, Any], path: tuple[str | int, ...], token: str) -> bytes:
    """``doc`` as JSON text with the value at ``path`` replaced by the raw ``token``."""
    doc = json.loads(json.dumps(doc))
    target: Any = doc
    for key in path[:-1]:
        target = target[key]
    target[path[-1]] = "__here__"
    return json.dumps(doc).replace('"__here__"', token).encode()


@pytest.fixture(scope="module")
def setup_doc() -> dict[str, Any]:
    return dump_setup_dict(load_setup(EXAMPLE))


@pytest.mark.parametrize("token", ["NaN", "Infinity", "-Infinity", "1e999"])
@pytest.mark.parametrize(
    "path",
    [("responses", 0, "position_m", 1), ("reference_point_m", 2), ("inputs", 3, "position_m", 0)],
    ids=["response-position", "reference-point", "input-position"],
)
def test_setup_positions_must_be_finite(
    api: Api, setup_doc: dict[str, Any], path: tuple[str | int, ...], token: str
) -> None:
    """Were stored (201) with the number turned into null."""
    r = api.client.post("/api/setups", content=_with(setup_doc, path, token), headers=JSON)
    assert r.status_code == 422, r.text[:300]
    field = "body." + "".join(f"[{p}]" if isinstance(p, int) else f".{p}" for p in path)[1:]
    assert r.json()["field"] == field.replace(".[", "["), r.json()["field"]
    assert "finite number" in r.json()["detail"]


@pytest.mark.parametrize("fmt", ["json", "toml"])
def test_imported_setups_must_be_finite(api: Api, setup_doc: dict[str, Any], fmt: str) -> None:
    if fmt == "json":
        raw = _with(setup_doc, ("responses", 0, "position_m", 1), "NaN")
    else:
        text = EXAMPLE.read_text()
        at = text.index("position_m = [") + len("position_m = [")
        raw = (text[:at] + "nan, " + text[at:].split(",", 1)[1]).encode()
    r = api.client.post(f"/api/setups/import?format={fmt}", content=raw)
    assert r.status_code == 422, r.text[:300]
    assert "responses[0].position_m" in r.json()["detail"], r.text[:300]
    assert "finite number" in r.json()["detail"]


def test_from_geometry_reference_point_must_be_finite(api: Api) -> None:
    r = api.client.post(
        "/api/setups/from-geometry", content=b'{"reference_point_m": [0, NaN, 0]}', headers=JSON
    )
    assert r.status_code == 422 and r.json()["field"] == "body.reference_point_m[1]", r.text


@pytest.mark.parametrize("value", ["nan", "inf", "-inf", "infinity"])
def test_events_poll_must_be_finite_before_the_stream_starts(api: Api, value: str) -> None:
    """``poll_s=nan`` passed min/max clamping (NaN compares false) into asyncio.sleep; the 422
    comes before the job is looked up and before any 200."""
    r = api.client.get(f"/api/jobs/no-such-job/events?poll_s={value}")
    assert r.status_code == 422 and r.json()["field"] == "query.poll_s", r.text


def test_calibration_numbers_must_be_finite(api: Api) -> None:
    doc = json.loads((CALIBRATIONS / "lc-3001.json").read_text())
    r = api.client.post("/api/calibrations", content=_with(doc, ("matrix", 2, 5), "NaN"))
    assert r.status_code == 422 and "matrix[2][5] is nan" in r.json()["detail"], r.text


# -- 4. text: no unpaired surrogates, names of one line and bounded length ----------------------


def test_unpaired_surrogates_are_422(api: Api) -> None:
    """A lone \\ud800 in a serial number was a UnicodeEncodeError (500) at the database."""
    doc = json.loads((CALIBRATIONS / "lc-3001.json").read_text())
    r = api.client.post("/api/calibrations", content=_with(doc, ("serial_number",), '"LC\\ud800"'))
    assert r.status_code == 422, r.text
    assert "serial_number holds an unpaired surrogate" in r.json()["detail"]
    r = api.client.post(
        "/api/setups/import?format=json", content=b'{"name": "\\udfff", "responses": []}'
    )
    assert r.status_code == 422 and "name holds an unpaired surrogate" in r.json()["detail"]


@pytest.mark.parametrize(
    "serial", ["LC\n501", "LC\x00501", "L" * 101, "L" * 2_000_000], ids=["lf", "nul", "101", "2M"]
)
def test_calibration_serial_numbers_are_one_short_line(api: Api, serial: str) -> None:
    doc = json.loads((CALIBRATIONS / "lc-3001.json").read_text())
    doc["serial_number"] = serial
    r = api.client.post("/api/calibrations", content=json.dumps(doc).encode())
    assert r.status_code == 422, r.text[:300]
    detail = r.json()["detail"]
    assert "serial_number" in detail and ("MAX_ITEM_CHARS" in detail or "one line" in detail)


@pytest.mark.parametrize(
    ("where", "value", "says"),
    [
        (("name",), "box\n-1 2420 injected", "one line"),
        (("name",), "x" * 201, "at most 200 characters"),
        (("name",), "x" * 1_000_000, "at most 200 characters"),
        (("responses", 0, "label"), "1+X\r\n    -1", "one line"),
        (("inputs", 0, "label"), "a\tb", "one line"),
        (("load_cells", 0, "label"), "y" * 500, "at most 200 characters"),
    ],
    ids=["name-lf", "name-201", "name-1M", "response-label-crlf", "input-label-tab", "lc-500"],
)
def test_setup_names_and_labels_are_one_bounded_line(
    api: Api, setup_doc: dict[str, Any], where: tuple[str | int, ...], value: str, says: str
) -> None:
    """They are written verbatim into the exported UFF (2420 part name, labels): a line break
    ended the record there and the export could not be read back."""
    r = api.client.post("/api/setups", content=_with(setup_doc, where, json.dumps(value)))
    assert r.status_code == 422, r.text[:300]
    assert says in r.json()["detail"], r.text[:300]
    assert r.json()["field"].startswith("body." + str(where[0])), r.json()["field"]


def test_other_names_are_one_bounded_line(api: Api) -> None:
    for method, path, body, field in (
        ("POST", "/api/tests", {"article": "a\nb"}, "body.article"),
        ("POST", "/api/tests", {"article": "a", "operator": "o" * 201}, "body.operator"),
        ("POST", "/api/setups/from-geometry", {"name": "a\nb"}, "body.name"),
        ("POST", "/api/digitizer/tests", {"name": "x\x1b[2J"}, "body.name"),
    ):
        r = api.client.request(method, path, json=body)
        assert r.status_code == 422 and r.json()["field"] == field, (path, r.text[:300])
    r = api.client.post("/api/setups/import?format=toml&name=a%0Ab", content=EXAMPLE.read_bytes())
    assert r.status_code == 422 and r.json()["field"] == "query.name", r.text[:300]
    r = api.client.post(f"/api/frfs/import?setup_id=1&name={'n' * 201}", content=b"x")
    assert r.status_code == 422 and r.json()["field"] == "query.name", r.text[:300]


# -- 5. the envelope's cost ---------------------------------------------------------------------


def _frf_set(api: Api, tmp: Path, lines: int = 56) -> int:
    """A stored FRF set of the calibration mass (model FRFs): its id."""
    model = calibration_mass(0, support="bungee")
    frf = model.frf(np.linspace(10.0, 120.0, lines))
    sid = api.client.post("/api/setups", json=dump_setup_dict(model.setup)).json()["id"]
    write_frf_uff(tmp / "cal.uff", frf)
    r = api.client.post(
        "/api/frfs/import", params={"setup_id": sid}, content=(tmp / "cal.uff").read_bytes()
    )
    assert r.status_code == 201, r.text
    return int(r.json()["id"])


@pytest.fixture(scope="module")
def frf_id(api: Api, tmp_path_factory: pytest.TempPathFactory) -> int:
    return _frf_set(api, tmp_path_factory.mktemp("frf"))


def test_envelope_inputs_repeated_are_422(api: Api, frf_id: int) -> None:
    """``input=0`` 50 times with 100,000 points answered 126 MB (every input once per key)."""
    query = "&".join(["input=0"] * 50) + "&input=1&input=1&points=100000"
    r = api.client.get(f"/api/frfs/{frf_id}/envelope?{query}")
    assert r.status_code == 422 and r.json()["field"] == "query.input", r.text[:300]
    assert "input 0, 1 given more than once" in r.json()["detail"]
    assert len(r.content) < 1000


def test_envelope_size_is_limited(api: Api, frf_id: int, monkeypatch: pytest.MonkeyPatch) -> None:
    whole = api.client.get(f"/api/frfs/{frf_id}/envelope?points=100000").json()
    n = len(whole["frequencies_hz"]) * len(whole["responses"]) * len(whole["inputs"])
    assert n > 1000
    monkeypatch.setattr(store, "MAX_ENVELOPE_VALUES", n - 1)  # the server runs in this process
    r = api.client.get(f"/api/frfs/{frf_id}/envelope?points=100000")
    assert r.status_code == 422, r.text[:300]
    assert f"= {n} values" in r.json()["detail"] and "MAX_ENVELOPE_VALUES" in r.json()["detail"]
    r = api.client.get(f"/api/frfs/{frf_id}/envelope?points=100000&input=0")
    assert r.status_code == 200, r.text[:300]


# -- 7. races -----------------------------------------------------------------------------------


def test_a_solve_racing_the_delete_of_its_set_is_409(
    api: Api, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The set is deleted while it is solved (after it was read, before the solution is
    stored): the solution's foreign key refused the row, an IntegrityError answered 500."""
    fid = _frf_set(api, tmp_path)
    analysis = api.lab.analysis
    analyse = analysis._analyse

    def deleted_meanwhile(*args: Any, **kw: Any) -> Any:
        assert api.lab.store.delete_frf(fid) is True
        return analyse(*args, **kw)

    monkeypatch.setattr(analysis, "_analyse", deleted_meanwhile)
    r = api.client.post("/api/solutions", json={"frf_id": fid})
    assert r.status_code == 409, r.text[:300]
    assert f"FRF set {fid} was deleted while it was being solved" in r.json()["detail"]
    assert api.client.get(f"/api/frfs/{fid}").status_code == 404


def test_the_set_a_running_acquisition_merges_into_cannot_be_deleted(
    api: Api, tmp_path: Path
) -> None:
    fid = _frf_set(api, tmp_path)
    sid = api.client.get(f"/api/frfs/{fid}").json()["setup_id"]
    with api.lab.store.db.session() as s:  # a running acquisition that redoes inputs into it
        row = m.Acquisition(setup_id=sid, config={"merge_frf_id": fid}, state="running")
        s.add(row)
        s.flush()
        acq_id = int(row.id)
    try:
        r = api.client.delete(f"/api/frfs/{fid}")
        assert r.status_code == 409, r.text[:300]
        assert f"running acquisition {acq_id}" in r.json()["detail"]
        assert api.client.get(f"/api/frfs/{fid}").status_code == 200
    finally:
        with api.lab.store.db.session() as s:
            got = s.get(m.Acquisition, acq_id)
            assert got is not None
            got.state = "failed"
    assert api.client.delete(f"/api/frfs/{fid}").status_code == 204


# -- 6. ids never reused ------------------------------------------------------------------------


def test_ids_of_deleted_frf_sets_are_not_given_again(api: Api, tmp_path: Path) -> None:
    """SQLite gave the largest deleted id again: "FRF set 3" could name another set later."""
    ids = [_frf_set(api, tmp_path) for _ in range(3)]
    for fid in reversed(ids):
        assert api.client.delete(f"/api/frfs/{fid}").status_code == 204
    assert _frf_set(api, tmp_path) > max(ids)


# -- 9. the page, /docs, the token and the data files -------------------------------------------


def test_docs_are_served_from_local_assets(api: Api) -> None:
    """FastAPI's /docs fetched Swagger UI from cdn.jsdelivr.net (the lab PC may be offline, and
    a CDN's script runs with the page's access)."""
    r = api.anon.get("/docs")
    assert r.status_code == 200 and r.headers["x-frame-options"] == "DENY"
    urls = re.findall(r"""(?:src|href|url)\s*[=:]\s*['"]([^'"]+)['"]""", r.text)
    assert urls and all(u.startswith("/") for u in urls), urls
    assert "cdn" not in r.text and "https://" not in r.text
    for asset in ("swagger-ui-bundle.js", "swagger-ui.css"):
        got = api.anon.get(f"/docs-assets/{asset}")
        assert got.status_code == 200 and len(got.content) > 10_000, asset
    assert api.anon.get("/redoc").status_code == 404  # ReDoc only came from a CDN
    # the bundled Swagger UI (4.15) reads OpenAPI 3.0 only: the page gets the spec so labelled
    assert "/docs/openapi.json" in r.text
    spec, served = api.anon.get("/docs/openapi.json").json(), api.anon.get("/openapi.json").json()
    assert spec["openapi"] == "3.0.3" and served["openapi"].startswith("3.1")
    assert spec["paths"] == served["paths"]


@pytest.mark.parametrize("path", ["/", "/report"])
def test_the_lab_page_and_the_report_forbid_framing_and_foreign_scripts(
    api: Api, path: str
) -> None:
    r = api.anon.get(path)
    assert r.status_code == 200
    assert r.headers["x-frame-options"] == "DENY"
    csp = dict(
        d.strip().split(" ", 1) for d in r.headers["content-security-policy"].split(";") if d
    )
    assert csp["script-src"] == "'self'" and csp["frame-ancestors"] == "'none'"
    assert csp["default-src"] == "'self'" and csp["connect-src"] == "'self'"
    # what the page loads is allowed by it: its own scripts and styles, no inline script
    assert not re.search(r"<script(?![^>]*\bsrc=)[^>]*>", r.text), "inline script"
    assert not re.search(r"""(?:src|href)=["']https?://""", r.text)


def test_data_files_are_private(tmp_path: Path) -> None:
    """The token and the SQLite database (every measurement) were 0644 under the usual umask."""
    old = os.umask(0o022)
    try:
        settings = make_settings(tmp_path / "data")
        (tmp_path / "data").mkdir()
        (tmp_path / "data" / "token").write_text("an-old-token\n")  # as an older dimacq left it
        os.chmod(tmp_path / "data" / "token", 0o644)
        settings = settings.model_copy(update={"token": ""})
        assert settings.resolved_token() == "an-old-token"
        db = open_database(f"sqlite:///{tmp_path / 'data' / 'dimacq.sqlite'}")
        db.engine.dispose()
        fresh = load_settings(data_dir=tmp_path / "fresh", token="")
        fresh.resolved_token()
    finally:
        os.umask(old)
    for path in (
        tmp_path / "data" / "token",
        tmp_path / "data" / "dimacq.sqlite",
        tmp_path / "fresh" / "token",
    ):
        assert stat.S_IMODE(path.stat().st_mode) == 0o600, (path, oct(path.stat().st_mode))
    wal = tmp_path / "data" / "dimacq.sqlite-wal"
    if wal.exists():
        assert stat.S_IMODE(wal.stat().st_mode) == 0o600


def test_setups_stored_before_the_name_rule_stay_usable(
    api: Api, setup_doc: dict[str, Any]
) -> None:
    """A name with a line break or a 300-character label was accepted before; such a row is read
    with its names made one line (line breaks become spaces, cut at 200), never refused."""
    body = json.loads(json.dumps(setup_doc))
    body["name"] = "old\nbox"
    body["responses"][0]["label"] = "L" * 300
    with api.lab.store.db.session() as s:
        row = m.SetupRow(name=body["name"], body=body, stand="")
        s.add(row)
        s.flush()
        sid = int(row.id)
    setup = api.lab.store.setup(sid)
    assert setup is not None and setup.name == "old box"
    assert setup.responses[0].label == "L" * 200
    r = api.client.get(f"/api/setups/{sid}/export", params={"format": "toml"})
    assert r.status_code == 200 and 'name = "old box"' in r.text, r.text[:300]
