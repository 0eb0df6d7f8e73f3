"""Test stands on a shared database: one service per stand name, proven by a heartbeat lease.

A service claims its stand at start-up (:func:`claim_stand`): it takes the ``stands`` row under
a row lock (``SELECT ... FOR UPDATE``; SQLite serialises writers anyway) and writes its instance
id, host, pid and API address. If another instance holds the row and its heartbeat is younger
than ``stale_s`` (and it is not a process of this host that has died), the claim is refused with a :class:`~dimacq.errors.SetupError` naming that
instance: two PCs configured with the same stand name would otherwise drive one stand's devices
and interrupt each other's acquisitions. The holder renews the heartbeat (:func:`heartbeat`)
every few seconds; a service that died stops renewing and its stand can be taken over.
"""

from __future__ import annotations

import logging
import os
import socket
import uuid
from dataclasses import dataclass, field
from datetime import UTC, datetime, timedelta
from typing import Any

from sqlalchemy import select

from dimacq.errors import SetupError
from dimacq.persistence import models as m
from dimacq.persistence.db import Database

__all__ = ["StandIdentity", "claim_stand", "heartbeat", "release_stand", "stands"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class StandIdentity:
    """This service: its stand's name, a unique instance id, host, pid and API address."""

    name: str
    api_url: str = ""
    host: str = field(default_factory=socket.gethostname)
    pid: int = field(default_factory=os.getpid)
    instance: str = field(default_factory=lambda: uuid.uuid4().hex[:16])


def _utc(t: datetime) -> datetime:
    return t if t.tzinfo is not None else t.replace(tzinfo=UTC)  # SQLite drops the zone


def _pid_alive(pid: int) -> bool:
    """A process with this id runs on this host (a killed service's stand can be taken over at
    once by its restart)."""
    if pid <= 0:
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # exists, another user's
        return True
    return True


def claim_stand(db: Database, me: StandIdentity, *, stale_s: float = 30.0) -> None:
    """Take the stand's row for this instance.

    Raises
    ------
    SetupError
        Another live service (heartbeat younger than ``stale_s``) holds the stand.
    """
    now = m.utcnow()
    with db.session() as s:
        row = s.scalars(
            select(m.StandRow).where(m.StandRow.name == me.name).with_for_update()
        ).first()
        if row is None:
            s.add(
                m.StandRow(
                    name=me.name,
                    instance=me.instance,
                    host=me.host,
                    pid=me.pid,
                    api_url=me.api_url,
                    started_at=now,
                    heartbeat_at=now,
                )
            )
            return
        age = now - _utc(row.heartbeat_at)
        died_here = row.host == me.host and row.pid != me.pid and not _pid_alive(row.pid)
        if row.instance != me.instance and age < timedelta(seconds=stale_s) and not died_here:
            raise SetupError(
                f"stand {me.name!r} is already served by pid {row.pid} on {row.host} "
                f"({row.api_url or 'no API address'}, alive {age.total_seconds():.0f} s ago); "
                "give each PC its own stand name (setting stand, DIMACQ_STAND) or stop that service"
            )
        if row.instance != me.instance:
            log.info("stand %s taken over from %s (silent for %s)", me.name, row.host, age)
        row.instance, row.host, row.pid, row.api_url = me.instance, me.host, me.pid, me.api_url
        row.started_at = row.heartbeat_at = now


def heartbeat(db: Database, me: StandIdentity) -> bool:
    """Renew this instance's lease; False if another instance has taken the stand over."""
    with db.session() as s:
        row = s.get(m.StandRow, me.name)
        if row is None or row.instance != me.instance:
            return False
        row.heartbeat_at = m.utcnow()
        return True


def release_stand(db: Database, me: StandIdentity) -> None:
    """Give the stand up at shutdown (the next service may claim it at once)."""
    with db.session() as s:
        row = s.get(m.StandRow, me.name)
        if row is not None and row.instance == me.instance:
            row.heartbeat_at = datetime(1970, 1, 1, tzinfo=UTC)


def stands(db: Database) -> list[dict[str, Any]]:
    """Every stand known to the database, with its API address and last heartbeat."""
    with db.session() as s:
        return [
            {
                "name": r.name,
                "host": r.host,
                "pid": r.pid,
                "api_url": r.api_url,
                "started_at": _utc(r.started_at).isoformat(),
                "heartbeat_at": _utc(r.heartbeat_at).isoformat(),
            }
            for r in s.scalars(select(m.StandRow).order_by(m.StandRow.name))
        ]
