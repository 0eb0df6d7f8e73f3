"""Background jobs: progress, cancel, final states, persistence callback, watchers."""

from __future__ import annotations

import threading

import pytest

from dimacq.errors import DataError, SetupError
from dimacq.services.lab.jobs import JobManager


def test_progress_and_success_are_persisted() -> None:
    stored: list[dict] = []
    mgr = JobManager(persist=stored.append, persist_interval_s=0.0)

    def work(ctx):
        for i in range(5):
            ctx.progress((i + 1) / 5, f"step {i + 1}")
        return {"answer": 42}

    job = mgr.submit("t", work)
    snap = mgr.wait(job.id, 5)
    assert snap["state"] == "succeeded" and snap["progress"] == 1.0
    assert snap["result"] == {"answer": 42}
    states = [s["state"] for s in stored]
    assert states[0] == "pending" and states[-1] == "succeeded" and "running" in states
    assert any(s["message"] == "step 3" for s in stored)


def test_cancel_stops_the_job() -> None:
    mgr = JobManager()
    started = threading.Event()

    def work(ctx):
        started.set()
        while True:
            ctx.check_cancelled()
            threading.Event().wait(0.005)

    job = mgr.submit("t", work)
    assert started.wait(5)
    mgr.cancel(job.id)
    assert mgr.wait(job.id, 5)["state"] == "cancelled"
    # cancelling a final job changes nothing
    assert mgr.cancel(job.id)["state"] == "cancelled"


def test_failures_are_final_states_with_the_message() -> None:
    mgr = JobManager()

    def bad(ctx):
        raise DataError("channel 3: NaN; re-measure")

    def bug(ctx):
        raise ZeroDivisionError("oops")

    a = mgr.submit("t", bad)
    b = mgr.submit("t", bug)
    sa, sb = mgr.wait(a.id, 5), mgr.wait(b.id, 5)
    assert sa["state"] == "failed" and "channel 3" in sa["error"]
    assert sb["state"] == "failed" and "internal error: ZeroDivisionError" in sb["error"]


def test_wait_change_and_limits() -> None:
    mgr = JobManager(max_running=1)
    go = threading.Event()

    def work(ctx):
        go.wait(5)
        ctx.progress(0.5, "half")
        go.clear()
        return None

    job = mgr.submit("t", work)
    v0 = mgr.snapshot(job.id)["version"]
    with pytest.raises(SetupError, match="limit 1"):
        mgr.submit("t", work)
    go.set()
    snap = mgr.wait_change(job.id, v0, 5)
    assert snap is not None and snap["version"] > v0
    assert mgr.wait(job.id, 5)["state"] == "succeeded"
    assert mgr.wait_change("missing", 0, 0.01) is None
    with pytest.raises(SetupError, match="does not exist"):
        mgr.cancel("missing")


def test_shutdown_cancels_running_jobs() -> None:
    mgr = JobManager()

    def work(ctx):
        while True:
            ctx.check_cancelled()
            threading.Event().wait(0.005)

    job = mgr.submit("t", work)
    mgr.shutdown(5)
    assert mgr.snapshot(job.id)["state"] == "cancelled"


def test_cancel_during_a_claim_of_this_process_cancels_the_job_here() -> None:
    """The lab's ticker claims a queued job (running in the store, not yet submitted here) while
    a client cancels it: the cancel waits for the claim and stops the job here, where it used to
    answer "job ... runs on stand <this stand>; cancel it through that stand's API" (the
    schemathesis fixture's flake on PostgreSQL)."""
    from dimacq.errors import DeviceStateError

    claimed, go = threading.Event(), threading.Event()
    rows: dict[str, dict] = {"j1": {"id": "j1", "state": "pending", "stand": "here"}}

    class Store:
        def save(self, snap: dict) -> None:
            rows[snap["id"]] = {**rows.get(snap["id"], {}), **snap}

        def load(self, job_id: str) -> dict | None:
            return rows.get(job_id)

        def load_all(self) -> list[dict]:
            return list(rows.values())

        def cancel(self, job_id: str) -> dict:
            if rows[job_id]["state"] == "pending":
                rows[job_id]["state"] = "cancelled"
                return rows[job_id]
            raise DeviceStateError(f"job {job_id} runs on stand 'here'")

        def claim(self, kinds: list[str]) -> tuple[str, str, dict] | None:
            rows["j1"]["state"] = "running"
            claimed.set()
            assert go.wait(5)
            return "j1", "slow", {}

    mgr = JobManager(store=Store(), persist_interval_s=0.0)  # type: ignore[arg-type]

    def slow(params: dict):
        def work(ctx):
            while True:
                ctx.check_cancelled()
                threading.Event().wait(0.005)

        return work

    mgr.handlers["slow"] = slow
    ticker = threading.Thread(target=mgr.claim_queued)
    ticker.start()
    assert claimed.wait(5)
    got: list[object] = []
    client = threading.Thread(target=lambda: got.append(mgr.cancel("j1")))
    client.start()
    go.set()
    client.join(5)
    ticker.join(5)
    assert got and isinstance(got[0], dict), got
    assert mgr.wait("j1", 5)["state"] == "cancelled"
