"""Work classes: background studies never block an acquisition; a claim that cannot start leaves
no orphan; a job of this stand can always be cancelled."""

from __future__ import annotations

import threading
import time
from pathlib import Path
from typing import Any

import pytest
from _api_support import served_lab
from _lab_rig_support import IMPULSE_SETUP, impulse_rig_factory

from dimacq.io.setup_file import dump_setup_dict
from dimacq.persistence import models as m
from dimacq.persistence.queue import DbJobStore, enqueue_job
from dimacq.services.lab.jobs import FOREGROUND_KINDS, JobContext, JobManager

STUDY = {"half_size_m": 0.5, "max_angle_deg": 2.0, "trials": 5}


def _until(cond: Any, timeout_s: float = 30.0) -> Any:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        got = cond()
        if got:
            return got
        time.sleep(0.02)
    raise AssertionError("condition not reached within the bound")


@pytest.mark.slow
def test_queued_studies_do_not_block_an_acquisition(tmp_path: Path, database_url: str) -> None:
    release = threading.Event()
    with served_lab(tmp_path, database_url, impulse_rig_factory(pace_s=0.05)) as (c, lab):
        real = lab.jobs.handlers["sensitivity"]

        def held(doc: dict[str, Any]) -> Any:
            fn = real(doc)

            def work(ctx: JobContext) -> Any:
                while not release.is_set() and not ctx.cancelled:
                    time.sleep(0.01)  # a long study: holds its background slot
                return fn(ctx)

            return work

        lab.jobs.handlers["sensitivity"] = held
        studies = [c.post("/api/sensitivity", json=STUDY) for _ in range(6)]
        assert all(r.status_code in (200, 201, 202) for r in studies), studies[0].text
        _until(lambda: len(lab.jobs.running("sensitivity")) == lab.jobs.max_running)
        sid = c.post("/api/setups", json=dump_setup_dict(IMPULSE_SETUP)).json()["id"]
        body = {"setup_id": sid, "averages_per_input": 50, "record_samples": 512}
        t0 = time.monotonic()
        r = c.post("/api/acquisitions", json=body)
        assert r.status_code in (200, 201, 202), r.text[:300]
        acq = r.json()
        job = _until(lambda: c.get(f"/api/jobs/{acq['job_id']}").json())
        assert job["state"] in ("pending", "running"), job
        _until(lambda: c.get(f"/api/jobs/{acq['job_id']}").json()["state"] == "running")
        print(f"acquisition running {time.monotonic() - t0:.3f} s after its request")
        assert c.post(f"/api/acquisitions/{acq['id']}/stop").status_code == 200
        for s in studies:
            jid = s.json()["job_id"]
            assert c.post(f"/api/jobs/{jid}/cancel").status_code == 200
        release.set()
        _until(lambda: not lab.jobs.running())


def test_a_claim_that_cannot_start_leaves_no_orphan(tmp_path: Path) -> None:
    from dimacq.persistence import open_database

    db = open_database(f"sqlite:///{tmp_path / 'q.sqlite'}")
    try:
        store = DbJobStore(db, "vm", "inst-1")
        jobs = JobManager(store=store)

        def broken(_doc: dict[str, Any]) -> Any:
            raise RuntimeError("handler bug")

        jobs.handlers["sensitivity"] = broken
        enqueue_job(db, "j1", "sensitivity", {}, created_by="vm")
        with pytest.raises(RuntimeError):
            jobs.claim_queued()
        snap = store.load("j1")
        assert snap is not None and snap["state"] == "failed", snap
        assert "could not be started" in snap["message"]
        assert jobs._reserved == 0
    finally:
        db.engine.dispose()


def test_a_job_of_this_stand_left_running_can_be_cancelled(tmp_path: Path) -> None:
    """A row 'running' on this stand with no thread here (a claim cut short): cancel was a 409
    "runs on stand 'vm'" for the stand itself."""
    from dimacq.persistence import open_database

    db = open_database(f"sqlite:///{tmp_path / 'q.sqlite'}")
    try:
        with db.session() as s:
            s.add(m.JobRow(id="j2", kind="sensitivity", state="running", stand="vm", owner="old"))
        jobs = JobManager(store=DbJobStore(db, "vm", "inst-2"))
        snap = jobs.cancel("j2")
        assert snap["state"] == "cancelled", snap
    finally:
        db.engine.dispose()


def test_foreground_kinds_have_their_own_limit() -> None:
    jobs = JobManager(max_running=1, max_foreground=1)
    gate = threading.Event()

    def wait(_ctx: JobContext) -> None:
        gate.wait(10)

    jobs.submit("plan", wait)
    with pytest.raises(Exception, match="background jobs are running"):
        jobs.submit("plan", wait)
    assert "acquisition" in FOREGROUND_KINDS
    jobs.submit("acquisition", wait)  # not blocked by the plan
    gate.set()
    jobs.shutdown()
