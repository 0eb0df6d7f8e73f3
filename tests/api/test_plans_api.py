"""``POST /api/plans``: a plan as a job of the lab service, its result the JSON of
``dimacq plan``; bad requests refused with 422 before any job starts; cancel between solves."""

from __future__ import annotations

import json
import tomllib
from pathlib import Path

import pytest
from _api_support import Api
from _pg_support import SQLITE_ONLY

from dimacq.io.setup_file import load_setup
from dimacq.model.properties import RigidBodyProperties
from dimacq.services.solve.planning import make_plan

pytestmark = SQLITE_ONLY  # computation-bound: see _pg_support.SQLITE_ONLY

ROOT = Path(__file__).resolve().parents[2]
SETUP = ROOT / "config" / "plans" / "calibration-mass-candidates.toml"
PROPS = ROOT / "config" / "plans" / "calibration-mass-properties.json"


def _body(**kw: object) -> dict:
    props = json.loads(PROPS.read_text())
    return {
        "setup": tomllib.loads(SETUP.read_text()),
        "properties": {k: props[k] for k in ("mass_kg", "cg_m", "inertia_cg_kgm2")},
        "triaxes": 4,
        "inputs": 8,
        **kw,
    }


@pytest.mark.slow
def test_plan_job_gives_the_command_line_plan(api: Api) -> None:
    r = api.client.post("/api/plans", json=_body(seed=2))
    assert r.status_code == 202, r.text
    assert r.json()["kind"] == "plan"
    snap = api.lab.jobs.wait(r.json()["id"], 60)
    assert snap["state"] == "succeeded", snap
    props = RigidBodyProperties.from_json(json.loads(PROPS.read_text()))
    direct = make_plan(load_setup(SETUP), props, 4, 8, seed=2)
    assert api.client.get(f"/api/jobs/{r.json()['id']}").json()["result"] == direct


def test_bad_plans_are_refused_before_a_job_starts(api: Api) -> None:
    before = len(api.lab.jobs.list_jobs())
    for body, word in (
        (_body(triaxes=40), "triaxes 40"),
        (_body(inputs=0), "inputs"),
        (_body(setup={"responses": []}), "setup"),
        (
            _body(properties={"mass_kg": 1.0, "cg_m": [0, 0, 0], "inertia_cg_kgm2": [[1, 0, 0], [0, -1, 0], [0, 0, 1]]}),
            "positive definite",
        ),
    ):  # fmt: skip
        r = api.client.post("/api/plans", json=body)
        assert r.status_code == 422, r.text
        assert word in r.json()["detail"], r.json()
    assert len(api.lab.jobs.list_jobs()) == before


@pytest.mark.slow
def test_a_plan_with_trials_can_be_cancelled(api: Api) -> None:
    r = api.client.post("/api/plans", json=_body(trials=50))
    assert r.status_code == 202, r.text
    job_id = r.json()["id"]
    api.client.post(f"/api/jobs/{job_id}/cancel")
    snap = api.lab.jobs.wait(job_id, 120)
    assert snap["state"] == "cancelled", snap
