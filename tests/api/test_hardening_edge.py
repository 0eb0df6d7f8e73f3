"""API hardening, second pass (issue 24, "no 500"): every probe below answered 500 (or reset the
connection) before its fix; each now gets a 4xx whose message names the field or the limit."""

from __future__ import annotations

from pathlib import Path

import pytest
from _api_support import Api

from dimacq.io.documents import MAX_DEPTH, MAX_DOCUMENT_BYTES, MAX_VALUES

ROOT = Path(__file__).resolve().parents[2]
CALIBRATIONS = ROOT / "config" / "calibrations"
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


TOML_BOMBS = {
    "deep arrays": "a = " + "[" * 50_000 + "]" * 50_000,
    "deep inline tables": "a = " + "{b=" * 5000 + "1" + "}" * 5000,
    "deep dotted keys": "a" + ".a" * 5000 + " = 1",
    "deep table header": "[" + ".".join(["t"] * 5000) + "]\nx = 1",
    "huge number": "a = " + "9" * 5000,
    "many values": "a = [" + "1," * (MAX_VALUES + 10) + "]",
    "huge string": 'a = "' + "x" * (MAX_DOCUMENT_BYTES + 10) + '"',
}


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
