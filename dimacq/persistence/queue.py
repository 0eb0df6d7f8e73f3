"""Jobs queued in the database and claimed by exactly one service.

A queued job is a ``jobs`` row with ``state = "pending"``, a ``kind`` and JSON ``params``; it
may name the stand that must run it (``runs_on``) or leave it NULL (any service). A service
claims the oldest job it can run in one transaction::

    SELECT ... FROM jobs WHERE state = 'pending' AND kind IN (...)
        AND (runs_on IS NULL OR runs_on = :stand)
        ORDER BY created_at LIMIT 1 FOR UPDATE SKIP LOCKED
    UPDATE jobs SET state = 'running', stand = :stand, owner = :instance,
        attempts = attempts + 1 WHERE id = :id AND state = 'pending'

On PostgreSQL the row lock with ``SKIP LOCKED`` makes concurrent claimers take different rows
without waiting for each other; the guarded ``UPDATE`` (``state = 'pending'``, its row count
checked) is the compare-and-set that makes the claim exclusive on SQLite too, where
SQLAlchemy leaves ``FOR UPDATE`` out and writers are serialised by the database lock.
"""

from __future__ import annotations

import logging
import threading
import zlib
from collections.abc import Callable, Iterable, Mapping
from datetime import UTC, datetime
from typing import Any

from sqlalchemy import or_, select, update
from sqlalchemy.orm import Session

from dimacq.errors import DatabaseUnavailableError, DeviceStateError
from dimacq.persistence import models as m
from dimacq.persistence.db import Database

__all__ = ["DbJobStore", "Outbox", "cancel_pending", "claim_job", "enqueue_job"]

log = logging.getLogger(__name__)

_RUNNING = ("pending", "running")


def enqueue_job(
    db: Database,
    job_id: str,
    kind: str,
    params: Mapping[str, Any],
    *,
    created_by: str,
    runs_on: str | None = None,
) -> None:
    """Queue a job; a service that can run ``kind`` (on stand ``runs_on``, or any) claims it."""
    with db.session() as s:
        s.add(
            m.JobRow(
                id=job_id,
                kind=kind,
                state="pending",
                message="queued",
                params=dict(params),
                created_by=created_by,
                runs_on=runs_on,
                stand="",
            )
        )


def claim_job(
    db: Database, kinds: Iterable[str], *, stand: str, instance: str
) -> tuple[str, str, dict[str, Any]] | None:
    """Claim the oldest pending job of ``kinds`` this stand may run: ``(id, kind, params)``,
    or None when there is none (or another service took it first)."""
    kinds = list(kinds)
    if not kinds:
        return None
    with db.session() as s:
        row = s.execute(
            select(m.JobRow.id, m.JobRow.kind, m.JobRow.params)
            .where(
                m.JobRow.state == "pending",
                m.JobRow.kind.in_(kinds),
                or_(m.JobRow.runs_on.is_(None), m.JobRow.runs_on == stand),
            )
            .order_by(m.JobRow.created_at, m.JobRow.id)
            .limit(1)
            .with_for_update(skip_locked=True)
        ).first()
        if row is None:
            return None
        done = s.execute(
            update(m.JobRow)
            .where(m.JobRow.id == row.id, m.JobRow.state == "pending")
            .values(
                state="running",
                stand=stand,
                owner=instance,
                attempts=m.JobRow.attempts + 1,
                message="claimed",
            )
            .execution_options(synchronize_session=False)
        )
        if done.rowcount != 1:  # type: ignore[attr-defined]
            return None
        return str(row.id), str(row.kind), dict(row.params or {})


def cancel_pending(db: Database, job_id: str) -> bool:
    """Cancel a job nobody has claimed yet; False if it was claimed (or is final) already."""
    with db.session() as s:
        done = s.execute(
            update(m.JobRow)
            .where(m.JobRow.id == job_id, m.JobRow.state == "pending")
            .values(
                state="cancelled",
                message="cancelled before any service claimed it",
                finished_at=m.utcnow(),
            )
            .execution_options(synchronize_session=False)
        )
        return bool(done.rowcount)  # type: ignore[attr-defined]


def _iso(t: datetime | None) -> str | None:
    if t is None:
        return None
    return (t if t.tzinfo is not None else t.replace(tzinfo=UTC)).isoformat()


def _snapshot(r: m.JobRow) -> dict[str, Any]:
    key = f"{r.state}|{r.progress:.4f}|{r.message}|{r.stand}".encode()
    return {
        "id": r.id,
        "kind": r.kind,
        "state": r.state,
        "progress": float(r.progress or 0.0),
        "message": r.message or "",
        "result": r.result,
        "error": r.error,
        "created_at": _iso(r.created_at),
        "finished_at": _iso(r.finished_at),
        # the row keeps no time of its last progress: known only once the job has ended
        "updated_at": _iso(r.finished_at),
        "version": zlib.crc32(key) & 0x7FFFFFFF,  # changes whenever what a watcher sees does
        "stand": r.stand,
    }


class DbJobStore:
    """:class:`dimacq.services.lab.jobs.JobStore` on the database, for the service of one stand."""

    def __init__(self, db: Database, stand: str, instance: str) -> None:
        self.db = db
        self.stand = stand
        self.instance = instance

    def save(self, snap: Mapping[str, Any]) -> None:
        with self.db.session() as s:
            row = s.get(m.JobRow, snap["id"])
            if row is None:
                row = m.JobRow(
                    id=snap["id"],
                    kind=snap["kind"],
                    state=snap["state"],
                    stand=self.stand,
                    created_by=self.stand,
                    owner=self.instance,
                    attempts=1,
                )
                s.add(row)
            elif row.owner not in (None, self.instance):
                return  # another service claimed it (never overwrite its state)
            row.state = snap["state"]
            row.progress = float(snap["progress"])
            row.message = snap["message"]
            row.result = snap["result"]
            row.error = snap["error"]
            if snap["finished_at"]:
                row.finished_at = m.utcnow()

    def load(self, job_id: str) -> dict[str, Any] | None:
        if len(job_id) > 40:
            return None
        with self.db.session() as s:
            row = s.get(m.JobRow, job_id)
            return None if row is None else _snapshot(row)

    def load_all(self) -> list[dict[str, Any]]:
        with self.db.session() as s:
            rows = s.scalars(select(m.JobRow).order_by(m.JobRow.created_at, m.JobRow.id))
            return [_snapshot(r) for r in rows]

    def cancel(self, job_id: str) -> dict[str, Any]:
        """Cancel a queued job, or a job of this stand that no thread of this service runs (the
        caller knows its own): one service per stand, so nothing else will ever finish it."""
        if not cancel_pending(self.db, job_id):
            snap = self.load(job_id)
            assert snap is not None
            if snap["state"] in _RUNNING and snap["stand"] == self.stand:
                self._end_orphan(job_id, "cancelled", "cancelled: no thread of this stand ran it")
            elif snap["state"] in _RUNNING:
                raise DeviceStateError(
                    f"job {job_id} runs on stand {snap['stand']!r}; cancel it through that "
                    "stand's API (GET /api/stands lists their addresses)"
                )
        out = self.load(job_id)
        assert out is not None
        return out

    def _end_orphan(self, job_id: str, state: str, message: str) -> None:
        with self.db.session() as s:
            s.execute(
                update(m.JobRow)
                .where(m.JobRow.id == job_id, m.JobRow.state.in_(list(_RUNNING)))
                .where(m.JobRow.stand == self.stand)
                .values(state=state, message=message, error=message, finished_at=m.utcnow())
                .execution_options(synchronize_session=False)
            )

    def release(self, job_id: str, reason: str) -> None:
        """A job this service claimed but could not start: failed with ``reason`` (never left
        running with nobody to run it)."""
        self._end_orphan(job_id, "failed", reason)

    def claim(self, kinds: list[str]) -> tuple[str, str, dict[str, Any]] | None:
        return claim_job(self.db, kinds, stand=self.stand, instance=self.instance)

    def interrupt_stale(self) -> int:
        """Jobs this stand was running when its service stopped become ``interrupted``."""
        with self.db.session() as s:
            done = s.execute(
                update(m.JobRow)
                .where(m.JobRow.state == "running", m.JobRow.stand.in_([self.stand, ""]))
                .values(
                    state="interrupted",
                    message="the service stopped while this job ran; completed work is kept",
                    finished_at=m.utcnow(),
                )
                .execution_options(synchronize_session=False)
            )
            return int(done.rowcount)  # type: ignore[attr-defined]


class Outbox:
    """Database writes waiting for the database: each is a function of a session, applied in
    order by :meth:`flush` once the database is reachable again. The data they register (e.g.
    an average's HDF5 file) is already on the local disk; a service that dies before the flush
    re-registers those files at its next start (orphan recovery)."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._items: list[tuple[str, Callable[[Session], None]]] = []

    def __len__(self) -> int:
        with self._lock:
            return len(self._items)

    def write(self, db: Database, what: str, fn: Callable[[Session], None]) -> bool:
        """Apply ``fn`` now if nothing waits before it and the database answers; otherwise
        queue it. True if it was written now."""
        with self._lock:
            if not self._items:
                try:
                    with db.session() as s:
                        fn(s)
                    return True
                except DatabaseUnavailableError:
                    pass
            self._items.append((what, fn))
            return False

    def flush(self, db: Database) -> int:
        """Apply the waiting writes in order; stops at the first that cannot reach the database
        (raising DatabaseUnavailableError). Returns how many were written."""
        n = 0
        with self._lock:
            while self._items:
                what, fn = self._items[0]
                with db.session() as s:
                    fn(s)
                self._items.pop(0)
                log.info("stored %s (it waited for the database)", what)
                n += 1
        return n
