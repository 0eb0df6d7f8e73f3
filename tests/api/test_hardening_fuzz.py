"""Property: no request makes the service fail (issue 24, item 11). Path ids of any length and
JSON / TOML bodies of any shape (deep, wide, huge or non-finite numbers, unpaired surrogates,
control characters) get an answer below 500 with the API's error body, and the connection is
not reset. The schemathesis run (``test_schemathesis.py``) generates from the spec, within its
ranges; these generate what the spec does not describe.

Bounded: 25 examples a test against this module's server (SQLite), about 30 s in all. Bodies go
only to routes that start nothing: a generated body that happened to be valid stores a record at
most (a setup, a calibration) and never a job."""

from __future__ import annotations

import json
import math
import os
from typing import Any

import pytest
import tomli_w
from _api_support import Api
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

#: the same examples every run (a suite that passes or fails by chance is a flaky one);
#: ``DIMACQ_FUZZ_RANDOM=1`` draws anew
FUZZ = settings(
    max_examples=25,
    deadline=None,
    derandomize=not os.environ.get("DIMACQ_FUZZ_RANDOM"),
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)


@pytest.fixture(scope="module")
def api_database_url() -> str:
    return ""


def _answered(r: Any) -> None:
    assert r.status_code < 500, (r.status_code, r.text[:300])
    if r.status_code >= 400:
        body = r.json()
        assert isinstance(body.get("detail"), str) and body["detail"], body


ID_ROUTES = (
    ("GET", "/api/setups/{}"),
    ("DELETE", "/api/setups/{}"),
    ("GET", "/api/tests/{}"),
    ("GET", "/api/frfs/{}/envelope"),
    ("GET", "/api/acquisitions/1/averages/{}"),
    ("POST", "/api/acquisitions/{}/stop"),
    ("GET", "/api/solutions/{}/spectrum"),
    ("GET", "/api/calibrations/{}"),
    ("DELETE", "/api/digitizer/points/{}"),
)

digits = st.one_of(
    st.integers(min_value=0, max_value=10**40).map(str),
    st.text("0123456789", min_size=1, max_size=8000),
    st.builds(lambda z, n: "0" * z + str(n), st.integers(0, 6000), st.integers(0, 10**12)),
)


@pytest.mark.slow
@FUZZ
@given(route=st.sampled_from(ID_ROUTES), value=digits)
def test_path_ids_of_any_length_never_fail(api: Api, route: tuple[str, str], value: str) -> None:
    method, template = route
    r = api.client.request(method, template.format(value))
    _answered(r)
    significant = value.lstrip("0")
    if not significant or len(significant) > 10 or int(significant) > 2**31 - 1:
        assert r.status_code == 404, (template, len(value), r.text[:200])


# -- JSON: any value Python's json can write, and some it writes only with allow_nan ------------

scalars = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(min_value=-(10**30), max_value=10**30),
    st.floats(allow_nan=True, allow_infinity=True),
    st.text(max_size=40),  # surrogates and control characters included
    st.sampled_from(["\ud800", "a\nb", "\x00", "x" * 300]),
)
json_values = st.recursive(
    scalars,
    lambda inner: st.one_of(
        st.lists(inner, max_size=5),
        st.dictionaries(
            st.sampled_from(["name", "label", "serial_number", "matrix", "responses", "inputs"])
            | st.text(max_size=10),
            inner,
            max_size=5,
        ),
    ),
    max_leaves=30,
)


def _deep(depth: int, kind: str) -> bytes:
    return {"[": b"[" * depth + b"]" * depth, "{": b'{"a":' * depth + b"1" + b"}" * depth}[kind]


raw_json = st.one_of(
    json_values.map(lambda v: json.dumps(v).encode()),  # NaN/Infinity written as such
    json_values.map(lambda v: json.dumps(v, ensure_ascii=False).encode("utf-8", "surrogatepass")),
    st.builds(_deep, st.integers(1, 200_000), st.sampled_from(["[", "{"])),
    st.integers(1, 20_000).map(lambda n: b'{"serial_number": ' + b"9" * n + b"}"),
    st.binary(max_size=200),
)

JSON_ROUTES = (
    "/api/calibrations",
    "/api/setups",
    "/api/setups/from-geometry",
    "/api/setups/import?format=json",
    "/api/rig/check",
    "/api/solutions",
    "/api/acquisitions/2147483647/review",
    "/api/digitizer/reference-nodes",
)


@FUZZ
@given(path=st.sampled_from(JSON_ROUTES), raw=raw_json)
def test_json_bodies_of_any_shape_never_fail(api: Api, path: str, raw: bytes) -> None:
    method = "PUT" if path == "/api/digitizer/reference-nodes" else "POST"
    r = api.client.request(method, path, content=raw, headers={"content-type": "application/json"})
    _answered(r)


# -- TOML: valid documents of any shape, and broken ones ----------------------------------------

toml_scalars = st.one_of(
    st.booleans(),
    st.integers(min_value=-(2**63), max_value=2**63 - 1),
    st.floats(allow_nan=True, allow_infinity=True),
    st.text(max_size=30).filter(lambda s: not any(0xD800 <= ord(c) <= 0xDFFF for c in s)),
)
toml_tables = st.recursive(
    st.dictionaries(st.text(min_size=1, max_size=8), toml_scalars, max_size=4),
    lambda inner: st.dictionaries(
        st.sampled_from(["responses", "inputs", "known", "name", "daq"]) | st.text(max_size=6),
        st.one_of(inner, st.lists(inner, max_size=3), st.lists(toml_scalars, max_size=4)),
        max_size=4,
    ),
    max_leaves=20,
)


def _dotted(depth: int) -> str:
    return "a" + ".a" * depth + " = 1\n"


raw_toml = st.one_of(
    toml_tables.map(tomli_w.dumps),
    st.integers(1, 60_000).map(lambda n: "a = " + "[" * n + "]" * n),
    st.integers(1, 20_000).map(_dotted),
    st.integers(1, 10_000).map(lambda n: "x = " + "9" * n),
    st.text(max_size=200).filter(lambda s: not any(0xD800 <= ord(c) <= 0xDFFF for c in s)),
)


@FUZZ
@given(text=raw_toml, to_rig=st.booleans())
def test_toml_documents_of_any_shape_never_fail(api: Api, text: str, to_rig: bool) -> None:
    if to_rig:
        r = api.client.post("/api/rig/check", json={"text": text})
    else:
        r = api.client.post("/api/setups/import?format=toml", content=text.encode())
    _answered(r)
    if r.status_code == 201:  # a valid setup: every number in it is finite
        for value in json.loads(r.text, parse_constant=lambda c: math.nan).values():
            assert not (isinstance(value, float) and not math.isfinite(value))
