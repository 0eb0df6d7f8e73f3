"""Background jobs: long operations run on worker threads with progress, cancel and a final state.

A job function receives a :class:`JobContext` and returns a JSON-able result::

    def work(ctx: JobContext) -> dict:
        for i in range(n):
            ctx.check_cancelled()           # raises JobCancelled when cancel() was called
            ...
            ctx.progress((i + 1) / n, f"average {i + 1} of {n}")
        return {"frf_id": 3}

    job = manager.submit("acquisition", work)

States: ``pending → running → succeeded | failed | cancelled``; a job that was running when the
service stopped is ``interrupted`` after a restart (its completed work, e.g. averages, is in the
database). Every change bumps :attr:`Job.version`, so watchers (the API's server-sent events) can
wait for the next change cheaply. The store (:class:`JobStore`, the database) keeps each state
change (progress changes at most every ``persist_interval_s``) and answers for jobs this process
does not hold: jobs other services run on the shared database, or final jobs of earlier runs.

Queued jobs: ``handlers`` maps a job kind to a function of the job's JSON parameters that returns
the job function; :meth:`JobManager.claim_queued` takes one pending job from the store (claimed
by exactly one service, see :mod:`dimacq.persistence.queue`) and runs it here. :class:`Ticker`
is the service's one background thread for periodic work (claiming queued jobs, the stand's
heartbeat, writes waiting for the database). No HTTP here.
"""

from __future__ import annotations

import builtins
import logging
import threading
import time
import uuid
from collections.abc import Callable
from dataclasses import dataclass, field
from datetime import UTC, datetime
from typing import Any, Literal, Protocol

from dimacq.errors import DatabaseUnavailableError, DimacqError, SetupError

__all__ = [
    "FINAL_STATES",
    "Job",
    "JobCancelled",
    "JobContext",
    "JobManager",
    "JobState",
    "JobStore",
    "Ticker",
]

log = logging.getLogger(__name__)

JobState = Literal["pending", "running", "succeeded", "failed", "cancelled", "interrupted"]
FINAL_STATES: frozenset[str] = frozenset({"succeeded", "failed", "cancelled", "interrupted"})


#: Job kinds that use the stand's devices while the operator waits (acquisitions, calibration
#: runs): they have their own limit, never taken by background work (studies, plans).
FOREGROUND_KINDS = frozenset({"acquisition", "loadcell-calibration"})


class JobCancelled(DimacqError):
    """Raised inside a job function by :meth:`JobContext.check_cancelled` after a cancel."""


@dataclass
class Job:
    """One background job (mutable; read a consistent copy with :meth:`snapshot`)."""

    id: str
    kind: str
    state: JobState = "pending"
    progress: float = 0.0
    message: str = ""
    result: dict[str, Any] | None = None
    error: str | None = None
    created_at: datetime = field(default_factory=lambda: datetime.now(UTC))
    finished_at: datetime | None = None
    updated_at: datetime | None = None  # the last change (state, progress, message)
    version: int = 0
    cancel_event: threading.Event = field(default_factory=threading.Event, repr=False)
    thread: threading.Thread | None = field(default=None, repr=False)

    @property
    def done(self) -> bool:
        return self.state in FINAL_STATES

    def snapshot(self) -> dict[str, Any]:
        return {
            "id": self.id,
            "kind": self.kind,
            "state": self.state,
            "progress": self.progress,
            "message": self.message,
            "result": self.result,
            "error": self.error,
            "created_at": self.created_at.isoformat(),
            "finished_at": self.finished_at.isoformat() if self.finished_at else None,
            "updated_at": (self.updated_at or self.created_at).isoformat(),
            "version": self.version,
        }


class JobContext:
    """What a job function sees: progress reporting and the cancel flag."""

    def __init__(self, manager: JobManager, job: Job) -> None:
        self._manager = manager
        self._job = job

    @property
    def job_id(self) -> str:
        return self._job.id

    @property
    def cancelled(self) -> bool:
        return self._job.cancel_event.is_set()

    def check_cancelled(self) -> None:
        """Raise :class:`JobCancelled` if a cancel was requested."""
        if self._job.cancel_event.is_set():
            raise JobCancelled(f"job {self._job.id} ({self._job.kind}) cancelled")

    def progress(self, fraction: float, message: str = "") -> None:
        """Report progress in 0..1 with a human message."""
        self._manager._update(
            self._job, progress=min(max(float(fraction), 0.0), 1.0), message=message
        )


JobFunction = Callable[[JobContext], dict[str, Any] | None]
PersistFunction = Callable[[dict[str, Any]], None]
JobHandler = Callable[[dict[str, Any]], JobFunction]


class JobStore(Protocol):
    """Where job states are kept beyond this process (the database)."""

    def save(self, snapshot: dict[str, Any]) -> None: ...

    def load(self, job_id: str) -> dict[str, Any] | None: ...

    def load_all(self) -> list[dict[str, Any]]: ...

    def cancel(self, job_id: str) -> dict[str, Any]: ...

    def claim(self, kinds: list[str]) -> tuple[str, str, dict[str, Any]] | None: ...

    def release(self, job_id: str, reason: str) -> None: ...


class JobManager:
    """Runs jobs on their own threads and keeps their state.

    Parameters
    ----------
    persist : callable, optional
        Called with :meth:`Job.snapshot` on every state change (and on progress, throttled).
    persist_interval_s : float
        Minimum time between two progress-only persist calls of one job.
    max_running : int
        Background jobs (studies, plans: every kind not in ``foreground``) allowed to run at
        once; :meth:`submit` beyond that raises SetupError.
    max_foreground : int
        Foreground jobs (:data:`FOREGROUND_KINDS`: acquisitions, calibration runs, the lab's
        tests on its devices) allowed at once, counted apart: background work never blocks
        them.
    """

    def __init__(
        self,
        persist: PersistFunction | None = None,
        *,
        store: JobStore | None = None,
        persist_interval_s: float = 1.0,
        max_running: int = 4,
        max_foreground: int = 4,
    ) -> None:
        self.store = store
        if persist is None and store is not None:
            persist = store.save
        self.handlers: dict[str, JobHandler] = {}
        self._claim_lock = threading.Lock()
        self._jobs: dict[str, Job] = {}
        self._lock = threading.Lock()
        self._changed = threading.Condition(self._lock)
        self._persist = persist
        self._persist_interval_s = persist_interval_s
        self._last_persist: dict[str, float] = {}
        self.max_running = max_running
        self.max_foreground = max_foreground
        self._reserved = 0  # background slots held by claims in progress

    # -- queries -------------------------------------------------------------------------------
    def get(self, job_id: str) -> Job | None:
        with self._lock:
            return self._jobs.get(job_id)

    def snapshot(self, job_id: str) -> dict[str, Any] | None:
        with self._lock:
            job = self._jobs.get(job_id)
            if job is not None:
                return job.snapshot()
        return None if self.store is None else self.store.load(job_id)

    def list_jobs(self) -> list[dict[str, Any]]:
        """Every job: those of this process (live) and, from the store, those of the others."""
        with self._lock:
            live = {j.id: j.snapshot() for j in self._jobs.values()}
        stored = [] if self.store is None else self.store.load_all()
        out = [live.pop(s["id"], s) for s in stored]
        return out + list(live.values())

    def running(self, kind: str | None = None) -> builtins.list[Job]:
        with self._lock:
            return [
                j for j in self._jobs.values() if not j.done and (kind is None or j.kind == kind)
            ]

    def wait_change(
        self, job_id: str, seen_version: int, timeout_s: float
    ) -> dict[str, Any] | None:
        """Block until the job's version exceeds ``seen_version`` or it is final, or the timeout."""
        deadline = time.monotonic() + timeout_s
        with self._changed:
            while True:
                job = self._jobs.get(job_id)
                if job is None:
                    return None
                if job.version > seen_version or job.done:
                    return job.snapshot()
                left = deadline - time.monotonic()
                if left <= 0:
                    return job.snapshot()
                self._changed.wait(left)

    def wait(self, job_id: str, timeout_s: float | None = None) -> dict[str, Any]:
        """Block until the job is final (here or, for a job another service runs, in the store);
        return its snapshot."""
        deadline = None if timeout_s is None else time.monotonic() + timeout_s
        while True:
            job = self.get(job_id)
            if job is not None and job.thread is not None:
                job.thread.join(None if deadline is None else max(0.0, deadline - time.monotonic()))
            snap = self.snapshot(job_id)
            if snap is None:
                raise SetupError(f"job {job_id!r} does not exist; list jobs to find its id")
            if snap["state"] in FINAL_STATES or (
                deadline is not None and time.monotonic() >= deadline
            ):
                return snap
            time.sleep(0.05)

    # -- control -------------------------------------------------------------------------------
    def submit(
        self, kind: str, fn: JobFunction, *, job_id: str | None = None, claimed: bool = False
    ) -> Job:
        """Start ``fn`` on a new thread; return the job at once (``claimed``: a queued job this
        service has claimed, already ``running`` in the store)."""
        foreground = kind in FOREGROUND_KINDS
        with self._lock:
            if claimed:
                self._reserved = max(0, self._reserved - 1)  # the slot claim_queued held
            else:
                active, limit = self._active(foreground)
                if active >= limit:
                    what = "acquisitions and calibration runs" if foreground else "background jobs"
                    raise SetupError(
                        f"{active} {what} are running (limit {limit}); wait for one to finish "
                        "or cancel one"
                    )
            job = Job(
                id=job_id or uuid.uuid4().hex[:12],
                kind=kind,
                state="running" if claimed else "pending",
            )
            self._jobs[job.id] = job
        self._store(job, force=True)
        thread = threading.Thread(
            target=self._run, args=(job, fn), name=f"dimacq-job-{kind}-{job.id}", daemon=True
        )
        job.thread = thread
        thread.start()
        return job

    def _active(self, foreground: bool) -> tuple[int, int]:
        """Jobs of the class running here (background: with the slots reserved by claims in
        progress) and the class's limit; call with the lock held."""
        n = sum(
            1
            for j in self._jobs.values()
            if not j.done and (j.kind in FOREGROUND_KINDS) == foreground
        )
        if foreground:
            return n, self.max_foreground
        return n + self._reserved, self.max_running

    def claim_queued(self) -> bool:
        """Claim one queued (background) job this service has a handler for and start it; False
        if none (or no capacity). Its slot is reserved before the claim, so the claimed job
        always starts; a job claimed but not started is failed in the store, never left
        running with nobody to run it."""
        if self.store is None or not self.handlers:
            return False
        with self._claim_lock:
            with self._lock:
                active, limit = self._active(foreground=False)
                if active >= limit:
                    return False
                self._reserved += 1
            started = False
            got = None
            try:
                got = self.store.claim(sorted(self.handlers))
                if got is None:
                    return False
                job_id, kind, params = got
                log.info("claimed queued job %s (%s)", job_id, kind)
                try:
                    fn = self.handlers[kind](params)
                except DimacqError as err:
                    fn = _failing(err)
                self.submit(kind, fn, job_id=job_id, claimed=True)
                started = True
                return True
            finally:
                if not started:
                    with self._lock:
                        self._reserved = max(0, self._reserved - 1)
                    if got is not None:
                        self.store.release(got[0], "claimed but could not be started")

    def cancel(self, job_id: str) -> dict[str, Any]:
        """Ask a job to stop (it stops at its next check); final jobs are left as they are. A
        queued job nobody claimed yet is cancelled in the store."""
        job = self.get(job_id)
        if job is None and self.store is not None:
            # a claim of this process in progress (claimed in the store, not yet submitted
            # here) ends first: the job is then this process's to cancel, not "another stand's"
            with self._claim_lock:
                job = self.get(job_id)
                if job is None and self.store.load(job_id) is not None:
                    return self.store.cancel(job_id)
        if job is None:
            raise SetupError(f"job {job_id!r} does not exist; list jobs to find its id")
        if not job.done:
            job.cancel_event.set()
            self._update(job, message="cancel requested")
        snap = self.snapshot(job_id)
        assert snap is not None
        return snap

    def shutdown(self, timeout_s: float = 10.0) -> None:
        """Cancel every running job and join the threads."""
        jobs = self.running()
        for j in jobs:
            j.cancel_event.set()
        deadline = time.monotonic() + timeout_s
        for j in jobs:
            if j.thread is not None:
                j.thread.join(max(0.0, deadline - time.monotonic()))
            if j.thread is not None and j.thread.is_alive():
                log.warning("job %s (%s) did not stop within %.1f s", j.id, j.kind, timeout_s)

    # -- internals -----------------------------------------------------------------------------
    def _update(self, job: Job, **changes: Any) -> None:
        with self._changed:
            for k, v in changes.items():
                setattr(job, k, v)
            job.updated_at = datetime.now(UTC)
            job.version += 1
            self._changed.notify_all()
        self._store(job, force="state" in changes)

    def _store(self, job: Job, force: bool) -> None:
        if self._persist is None:
            return
        now = time.monotonic()
        if not force and now - self._last_persist.get(job.id, 0.0) < self._persist_interval_s:
            return
        self._last_persist[job.id] = now
        try:
            self._persist(job.snapshot())
        except DatabaseUnavailableError as err:  # the job goes on; the next change retries
            self._last_persist.pop(job.id, None)
            log.warning("state of job %s not stored: %s", job.id, err)
        except Exception:  # persisting status must never kill the job
            log.exception("could not persist the state of job %s", job.id)

    def _run(self, job: Job, fn: JobFunction) -> None:
        ctx = JobContext(self, job)
        self._update(job, state="running", message="started")
        try:
            result = fn(ctx)
        except JobCancelled as err:
            self._finish(job, "cancelled", message=str(err))
        except DimacqError as err:
            log.warning("job %s (%s) failed: %s", job.id, job.kind, err)
            self._finish(job, "failed", error=str(err), message=str(err))
        except Exception as err:
            log.exception("job %s (%s) failed with an internal error", job.id, job.kind)
            self._finish(job, "failed", error=f"internal error: {type(err).__name__}: {err}")
        else:
            if job.cancel_event.is_set():
                self._finish(job, "cancelled", result=result, message="cancelled")
            else:
                self._finish(job, "succeeded", result=result, progress=1.0, message="done")

    def _finish(self, job: Job, state: JobState, **changes: Any) -> None:
        self._update(job, state=state, finished_at=datetime.now(UTC), **changes)

    def adopt(self, snapshot: dict[str, Any]) -> None:
        """Register a job known from storage (final; e.g. interrupted by a restart)."""
        created = snapshot.get("created_at")
        finished = snapshot.get("finished_at")
        job = Job(
            id=snapshot["id"],
            kind=snapshot["kind"],
            state=snapshot["state"],
            progress=float(snapshot.get("progress") or 0.0),
            message=snapshot.get("message") or "",
            result=snapshot.get("result"),
            error=snapshot.get("error"),
            created_at=created if isinstance(created, datetime) else datetime.now(UTC),
            finished_at=finished if isinstance(finished, datetime) else None,
        )
        with self._lock:
            self._jobs.setdefault(job.id, job)


def _failing(err: DimacqError) -> JobFunction:
    def fn(_ctx: JobContext) -> dict[str, Any] | None:
        raise err

    return fn


class Ticker:
    """One background thread running periodic tasks: ``add(name, period_s, fn)``; ``poke()``
    runs the due ones at once. A task's exception is logged and the task runs again at its next
    period (a database that is down is retried this way)."""

    def __init__(self, name: str = "dimacq-ticker") -> None:
        self._tasks: list[tuple[str, float, Callable[[], Any]]] = []
        self._next: dict[str, float] = {}
        self._wake = threading.Event()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, name=name, daemon=True)

    def add(self, name: str, period_s: float, fn: Callable[[], Any]) -> None:
        self._tasks.append((name, period_s, fn))

    def start(self) -> None:
        self._thread.start()

    def poke(self) -> None:
        self._next.clear()
        self._wake.set()

    def stop(self, timeout_s: float = 10.0) -> None:
        self._stop.set()
        self._wake.set()
        if self._thread.is_alive():
            self._thread.join(timeout_s)

    def _loop(self) -> None:
        while not self._stop.is_set():
            now = time.monotonic()
            for name, period, fn in self._tasks:
                if self._stop.is_set():
                    return
                if now < self._next.get(name, 0.0):
                    continue
                self._next[name] = now + period
                try:
                    fn()
                except DatabaseUnavailableError as err:
                    log.debug("task %s waits for the database: %s", name, err)
                except Exception:
                    log.exception("periodic task %s failed", name)
            due = min((self._next.get(n, 0.0) for n, _, _ in self._tasks), default=now + 1.0)
            self._wake.wait(max(0.01, due - time.monotonic()))
            self._wake.clear()
