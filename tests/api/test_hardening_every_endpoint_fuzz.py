"""Property: every operation of the OpenAPI spec, sent a request the spec allows with one value
replaced by a hostile one, answers below 500, on SQLite and PostgreSQL; the service still serves.

For each operation, schemathesis draws a schema-valid request (path, query, body); hypothesis then
picks one place in it (a leaf of the JSON body, a query or path parameter, or the whole file of an
upload) and puts there one hostile value: NaN and infinities as JSON numbers (``NaN``,
``-Infinity``, ``1e999``) and as strings, huge and tiny magnitudes (1e308, 5e-324, 2**63), NUL,
U+2028, U+2029 and U+0085 in strings, numbers as strings or booleans, integers in other spellings
(``01``, ``+1``, `` 1``).

Bounded: ``DIMACQ_FUZZ_EXAMPLES`` examples per operation and database (4 by default: 83
operations, about 660 requests); ``tests/scripts/fuzz_every_endpoint.py`` runs it longer and
writes the counts (``DIMACQ_FUZZ_COUNTS``: a file the test appends one line per request to)."""

from __future__ import annotations

import json
import math
import os
import tempfile
import urllib.parse
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest
import schemathesis
from _api_support import Api, make_settings
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

EXAMPLES = int(os.environ.get("DIMACQ_FUZZ_EXAMPLES", "4"))
COUNTS = os.environ.get("DIMACQ_FUZZ_COUNTS", "")

#: a JSON number token no float holds (written into the body as is)
OVERFLOW = "\u0000OVERFLOW\u0000"

JSON_HOSTILE: list[Any] = [
    math.nan,
    math.inf,
    -math.inf,
    OVERFLOW,
    1e308,
    -1e308,
    1e-300,
    5e-324,
    -5e-324,
    2**63,
    -(2**63) - 1,
    0,
    -1,
    "nan",
    "-Infinity",
    "1e999",
    "1",
    True,
    None,
    "\x00",
    "a\x00b",
    "\u2028",
    "x\u2029y",
    "\x85",
    "line\nbreak",
    "",
    "x" * 5000,
    [],
    {},
]

TEXT_HOSTILE = [
    "nan",
    "NaN",
    "-inf",
    "Infinity",
    "1e999",
    "1e308",
    "-1e308",
    "1e-300",
    "5e-324",
    "9223372036854775808",
    "\x00",
    "a\x00b",
    "\u2028",
    "x\u2029y",
    "\x85",
    "01",
    "+1",
    " 1",
    "-1",
    "true",
    "",
    "9" * 5000,
]

FILE_HOSTILE = [
    b"\x00" * 64,
    b"label,x_mm,y_mm,z_mm\nP\x00,nan,1e999,5e-324\n",
    "label,x_mm,y_mm,z_mm\nP\u2028,1e308,-1e308,inf\n".encode(),
    b'{"points": [{"label": "P", "x_mm": NaN, "y_mm": 1e999, "z_mm": -Infinity}]}',
    b'{"inputs": [], "responses": [], "name": "a\\u0000b"}',
    'name = "x\u2029y"\n[[inputs]]\nnode = 1e999\n'.encode(),
    b"    -1\n    58\n" + b"1e308 " * 40 + b"\n    -1\n",
    "\u2028\u2029\x85".encode(),
]


def _spec() -> dict[str, Any]:
    """The service's OpenAPI spec (the app built without starting it)."""
    from dimacq.api import create_app

    with tempfile.TemporaryDirectory() as tmp:
        return create_app(make_settings(Path(tmp) / "data")).openapi()


SPEC = _spec()
SCHEMA = schemathesis.openapi.from_dict(SPEC)
OPERATIONS = sorted((path, method.upper()) for path, ops in SPEC["paths"].items() for method in ops)


def _leaves(doc: Any, path: tuple[Any, ...] = ()) -> list[tuple[Any, ...]]:
    if isinstance(doc, dict):
        return [p for k, v in doc.items() for p in _leaves(v, (*path, k))] or [path]
    if isinstance(doc, list):
        return [p for i, v in enumerate(doc) for p in _leaves(v, (*path, i))] or [path]
    return [path]


def _replaced(doc: Any, path: tuple[Any, ...], value: Any) -> Any:
    if not path:
        return value
    doc = json.loads(json.dumps(doc))
    target = doc
    for k in path[:-1]:
        target = target[k]
    target[path[-1]] = value
    return doc


def _json_bytes(doc: Any) -> bytes:
    """JSON with NaN and infinities as the tokens ``NaN``/``Infinity`` and :data:`OVERFLOW`
    as ``1e999`` (what a careless client's serialiser writes)."""
    text = json.dumps(doc, allow_nan=True)
    return text.replace(json.dumps(OVERFLOW), "1e999").encode()


def _target(draw: st.DrawFn, case: Any, body: Any, binary: bool) -> tuple[str, Any]:
    places: list[tuple[str, Any]] = []
    places += [("path", k) for k in case.path_parameters or {}]
    op = SPEC["paths"][case.operation.path][case.method.lower()]
    places += [("query", p["name"]) for p in op.get("parameters", []) if p["in"] == "query"]
    if binary:
        places.append(("file", None))
    elif body is not None:
        places += [("body", leaf) for leaf in _leaves(body)]
    return draw(st.sampled_from(places)) if places else ("none", None)


@st.composite
def hostile_requests(draw: st.DrawFn, path: str, method: str) -> dict[str, Any]:
    """One request of the operation with one hostile value: method, url, params, content,
    headers, and where the value went."""
    case = draw(
        SCHEMA[path][method].as_strategy(generation_mode=schemathesis.GenerationMode.POSITIVE)
    )
    binary = case.media_type == "application/octet-stream"
    json_types = (dict, list, str, int, float, bool)
    # an optional body left out is schemathesis's NotSet: sent as no body
    body = case.body if not binary and isinstance(case.body, json_types) else None
    if binary:
        raw = getattr(case.body, "data", case.body)
        content = raw if isinstance(raw, bytes) else b""
    else:
        content = _json_bytes(body) if body is not None else b""
    params = {k: v for k, v in (case.query or {}).items()}
    path_params = {k: str(v) for k, v in (case.path_parameters or {}).items()}
    where, key = _target(draw, case, body, binary)
    if where == "path":
        path_params[key] = draw(st.sampled_from(TEXT_HOSTILE))
    elif where == "query":
        params[key] = draw(st.sampled_from(TEXT_HOSTILE))
    elif where == "file":
        content = draw(st.sampled_from(FILE_HOSTILE))
    elif where == "body":
        content = _json_bytes(_replaced(body, key, draw(st.sampled_from(JSON_HOSTILE))))
    url = path
    for k, v in path_params.items():
        url = url.replace("{" + k + "}", urllib.parse.quote(v, safe="") or "%20")
    headers = {"content-type": case.media_type} if case.media_type and content else {}
    return {
        "method": method,
        "url": url,
        "params": params,
        "content": content,
        "headers": headers,
        "where": f"{where}:{key}",
    }


@pytest.fixture
def jobs_end(api: Api) -> Iterator[None]:
    """Jobs the requests started are cancelled and ended before the next operation."""
    yield
    jobs = api.lab.jobs
    for _ in range(100):
        for snap in jobs.list_jobs():
            if snap["state"] in ("pending", "running"):
                jobs.cancel(snap["id"])
        running = jobs.running()
        if not running and all(s["state"] != "pending" for s in jobs.list_jobs()):
            return
        for job in running:
            jobs.wait(job.id, 60)


def _send(c: httpx.Client, req: dict[str, Any]) -> tuple[int, str]:
    """The status (and the start of the body of a 5xx); streamed, so an event stream's answer
    is judged by its status line."""
    with c.stream(
        req["method"],
        req["url"],
        params=req["params"],
        content=req["content"],
        headers=req["headers"],
        timeout=60,
    ) as r:
        text = r.read().decode("utf-8", "replace")[:400] if r.status_code >= 500 else ""
        return r.status_code, text


@pytest.mark.slow
@pytest.mark.parametrize(("path", "method"), OPERATIONS, ids=[f"{m} {p}" for p, m in OPERATIONS])
def test_every_operation_refuses_hostile_values_below_500(
    api: Api, api_database_url: str, jobs_end: None, path: str, method: str
) -> None:
    backend = "postgresql" if api_database_url.startswith("postgresql") else "sqlite"

    @settings(
        max_examples=EXAMPLES,
        deadline=None,
        derandomize=not COUNTS,  # the default run: the same examples every time
        suppress_health_check=list(HealthCheck),
    )
    @given(req=hostile_requests(path, method))
    def check(req: dict[str, Any]) -> None:
        status, text = _send(api.client, req)
        if COUNTS:
            with open(COUNTS, "a", encoding="utf-8") as fh:
                fh.write(f"{backend}\t{method} {path}\t{req['where']}\t{status}\n")
        assert status < 500, (method, path, req["where"], req["params"], status, text)

    check()
    assert api.client.get("/api/status").status_code == 200
