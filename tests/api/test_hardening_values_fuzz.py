"""Property: a valid request with any one value replaced by a hostile one (non-finite numbers as
numbers or strings, huge and tiny magnitudes, NUL and Unicode line separators, numbers as strings
or booleans) gets an answer below 500, on SQLite and PostgreSQL, and the service still serves.

Each example takes a known-good body of an endpoint, walks to one of its leaves and puts the
hostile value there. Bounded: 200 examples a database (under 10 s each on 2 cores, the server's
start aside); bodies that would start work (acquisitions, runs) name an item that does not
exist, so a valid one is refused after validation and nothing runs."""

from __future__ import annotations

import json
import os
import tomllib
from pathlib import Path
from typing import Any

import pytest
import tomli_w
from _api_support import Api
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from dimacq.io.setup_file import dump_setup_dict, load_setup

ROOT = Path(__file__).resolve().parents[2]
EXAMPLE = ROOT / "config" / "examples" / "six_triax_setup.toml"
CALIBRATION = ROOT / "config" / "rigs" / "calibrations" / "lc-3001.json"
NOWHERE = 2_147_483_647

HOSTILE: list[Any] = [
    "nan",
    "NaN",
    "-Infinity",
    "inf",
    "1e999",
    1e308,
    -1e308,
    1e-300,
    5e-324,
    -5e-324,
    0,
    -1,
    2**63,
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


def _bodies() -> dict[str, Any]:
    setup = dump_setup_dict(load_setup(EXAMPLE))
    return {
        "POST /api/setups": setup,
        "POST /api/setups/import?format=json": setup,
        "POST /api/tests": {"article": "box", "operator": "me", "notes": "n"},
        "POST /api/digitizer/points": {
            "label": "P1",
            "sim_probe": {"tip_m": [0.1, 0.2, 0.3], "axis": [0.0, 0.0, 1.0]},
        },
        "PUT /api/digitizer/reference-nodes": {"nodes": {"R1": [0.0, 0.0, 0.0]}},
        "POST /api/calibrations": json.loads(CALIBRATION.read_text()),
        "POST /api/acquisitions": {
            "setup_id": NOWHERE,
            "trigger_level_n": 5.0,
            "record_samples": 1024,
            "averages_per_input": 2,
            "exponential_tau_s": 0.1,
        },
        "POST /api/calibrations/runs": {
            "method": "static",
            "node": NOWHERE,
            "averages_per_input": 2,
        },
        "POST /api/solutions": {"frf_id": NOWHERE},
        "POST /api/setups/from-geometry": {"name": "g", "reference_point_m": [0.0, 0.0, 0.0]},
        "POST /api/digitizer/registrations": {"patch": NOWHERE, "limit_m": 0.01},
        "RIG /api/rig/check": tomllib.loads(
            (ROOT / "config" / "rig.toml").read_text(encoding="utf-8")
        ),
    }


BODIES = _bodies()


def _leaves(doc: Any, path: tuple[Any, ...] = ()) -> list[tuple[Any, ...]]:
    if isinstance(doc, dict):
        return [p for k, v in doc.items() for p in _leaves(v, (*path, k))] or [path]
    if isinstance(doc, list):
        return [p for i, v in enumerate(doc) for p in _leaves(v, (*path, i))] or [path]
    return [path]


def _replaced(doc: Any, path: tuple[Any, ...], value: Any) -> Any:
    doc = json.loads(json.dumps(doc))
    if not path:
        return value
    target = doc
    for k in path[:-1]:
        target = target[k]
    target[path[-1]] = value
    return doc


@st.composite
def requests(draw: st.DrawFn) -> tuple[str, Any]:
    route = draw(st.sampled_from(sorted(BODIES)))
    leaves = _leaves(BODIES[route])
    path = draw(st.sampled_from(leaves))
    value = draw(st.sampled_from(HOSTILE))
    return route, _replaced(BODIES[route], path, value)


#: the default run draws the same 200 of the ~24,000 (route, leaf, value) cases every time (a
#: suite that passes or fails by chance is a flaky one); ``DIMACQ_FUZZ_RANDOM=1`` draws anew
FUZZ = settings(
    max_examples=200,
    deadline=None,
    derandomize=not os.environ.get("DIMACQ_FUZZ_RANDOM"),
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)


@pytest.mark.slow
@FUZZ
@given(req=requests())
def test_hostile_values_anywhere_never_fail(api: Api, req: tuple[str, Any]) -> None:
    route, body = req
    method, path = route.split(" ", 1)
    if method == "RIG":
        try:
            text = tomli_w.dumps(body)
        except (TypeError, ValueError):
            return  # None or a NUL has no TOML spelling
        r = api.client.post(path, json={"text": text})
    else:
        raw = json.dumps(body).encode()
        r = api.client.request(
            method, path, content=raw, headers={"content-type": "application/json"}
        )
    assert r.status_code < 500, (route, r.status_code, r.text[:400])
    if r.status_code >= 400:
        assert isinstance(r.json().get("detail"), str)
    if r.status_code in (201, 202) and "job_id" in r.text:
        jid = r.json().get("job_id") or r.json().get("id")
        api.client.post(f"/api/jobs/{jid}/cancel")


QUERIES = [
    "/api/setups?limit={}",
    "/api/setups?offset={}",
    "/api/frfs?test_id={}",
    "/api/jobs/none/events?poll_s={}",
    "/api/digitizer/points?patch={}",
    "/api/frfs/1/envelope?points={}",
]


@pytest.mark.slow
@FUZZ
@given(
    q=st.sampled_from(QUERIES),
    v=st.sampled_from(
        [
            "nan",
            "-inf",
            "1e999",
            "1e-300",
            "5e-324",
            "%00",
            "%E2%80%A8",
            "true",
            "-1",
            "0" * 50 + "1",
        ]
    ),
)
def test_hostile_query_values_never_fail(api: Api, q: str, v: str) -> None:
    r = api.client.get(q.format(v))
    assert r.status_code < 500, (q, v, r.status_code, r.text[:300])
    assert api.client.get("/api/status").status_code == 200
