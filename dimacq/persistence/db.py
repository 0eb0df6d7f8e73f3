"""Database engine, sessions, and the database's health.

SQLite (the embedded default for one PC) is opened in WAL mode with ``synchronous=FULL``: a
committed transaction survives the process being killed, readers never block the writer.
PostgreSQL (``postgresql+psycopg://user@host/db``, the database several test stands share) is
opened with ``pool_pre_ping`` so connections broken by a server restart are replaced on their
next use. The code issues no backend-specific SQL outside the SQLite pragmas below, the
PostgreSQL advisory lock of :mod:`dimacq.persistence.migrations` and the ``SKIP LOCKED`` job claim
of :mod:`dimacq.persistence.queue`.

Connection loss: a session whose connection fails raises
:class:`~dimacq.errors.DatabaseUnavailableError` (the API's 503, naming the cause) and marks
:attr:`Database.health` down; :meth:`Database.retry` retries an operation with exponential
backoff until a deadline. The health is in memory, for the status call.
"""

from __future__ import annotations

import logging
import os
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from datetime import UTC, datetime
from pathlib import Path
from typing import Any, TypeVar

from sqlalchemy import Engine, create_engine, event, make_url
from sqlalchemy.exc import ArgumentError, DBAPIError, OperationalError, SQLAlchemyError
from sqlalchemy.orm import Session, sessionmaker

from dimacq.errors import DatabaseUnavailableError, SetupError
from dimacq.persistence.migrations import migrate

__all__ = ["INT32_MAX", "Database", "DbHealth", "masked_url", "open_database"]

log = logging.getLogger(__name__)

T = TypeVar("T")

#: Largest integer primary key on both backends (PostgreSQL ``integer``).
INT32_MAX = 2**31 - 1


def private_file(path: Path) -> None:
    """Create ``path`` (empty) readable and writable by its owner only (0600), or take group's
    and others' access away from an existing one: the database holds every measurement, and
    SQLite gives its ``-wal`` and ``-shm`` files the database file's mode."""
    try:
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o600)
    except OSError:
        return  # not ours to create (read-only folder): SQLite says why when it opens it
    try:
        if os.fstat(fd).st_mode & 0o077:
            os.fchmod(fd, 0o600)
    except OSError as err:  # another owner's file: keep going, say so
        log.warning("cannot make %s private (%s)", path, err)
    finally:
        os.close(fd)


def _sqlite_pragmas(dbapi_conn: Any, _record: Any) -> None:
    cur = dbapi_conn.cursor()
    cur.execute("PRAGMA journal_mode=WAL")
    cur.execute("PRAGMA synchronous=FULL")
    cur.execute("PRAGMA foreign_keys=ON")
    cur.execute("PRAGMA busy_timeout=10000")
    cur.close()


class _Session(Session):
    """A session whose ``get`` answers None for an integer key no row can have (beyond the
    32-bit ``integer`` of PostgreSQL, which would otherwise refuse the query)."""

    def get(self, entity: Any, ident: Any, **kw: Any) -> Any:
        if isinstance(ident, int) and not -INT32_MAX - 1 <= ident <= INT32_MAX:
            return None
        return super().get(entity, ident, **kw)


def is_connection_error(err: BaseException) -> bool:
    """The error means the database server is unreachable (not that the query is wrong)."""
    if isinstance(err, DBAPIError) and err.connection_invalidated:
        return True
    if not isinstance(err, OperationalError):
        return False
    if type(err.orig).__module__.startswith("sqlite3"):  # a file, not a server
        return "unable to open database" in str(err)
    return True


class DbHealth:
    """Whether the last database operation reached the server, since when, and why not."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self.ok = True
        self.error = ""
        self.since = datetime.now(UTC)
        self.outages = 0

    def up(self) -> None:
        if self.ok:
            return
        with self._lock:
            if not self.ok:
                log.warning("database reachable again after %s", datetime.now(UTC) - self.since)
                self.ok, self.error, self.since = True, "", datetime.now(UTC)

    def down(self, err: BaseException) -> None:
        msg = str(getattr(err, "orig", None) or err).strip().splitlines()[0][:300]
        with self._lock:
            if self.ok:
                log.warning("database unreachable: %s (retrying with backoff)", msg)
                self.ok, self.since = False, datetime.now(UTC)
                self.outages += 1
            self.error = msg

    def as_dict(self) -> dict[str, Any]:
        return {
            "ok": self.ok,
            "error": self.error,
            "since": self.since.isoformat(),
            "outages": self.outages,
        }


class Database:
    """An engine, its session factory, the applied schema version and the health."""

    def __init__(self, engine: Engine) -> None:
        self.engine = engine
        self.backend = engine.dialect.name
        self.sessions = sessionmaker(engine, class_=_Session, expire_on_commit=False)
        self.health = DbHealth()
        self.schema_version = migrate(engine)

    @contextmanager
    def session(self) -> Iterator[Session]:
        """A session committed on success, rolled back on error.

        Raises
        ------
        DatabaseUnavailableError
            The server could not be reached (the cause is in the message).
        """
        try:
            with self.sessions() as s:
                try:
                    yield s
                    s.commit()
                except BaseException:
                    s.rollback()
                    raise
        except SQLAlchemyError as err:
            if not is_connection_error(err):
                raise
            self.health.down(err)
            raise DatabaseUnavailableError(
                f"database unavailable ({self.health.error}); the service retries, try again "
                "shortly (GET /api/status shows the database state)"
            ) from err
        self.health.up()

    def retry(
        self,
        fn: Callable[[], T],
        *,
        what: str,
        timeout_s: float,
        on_wait: Callable[[str], None] | None = None,
        stop: Callable[[], bool] | None = None,
    ) -> T:
        """``fn()`` retried with exponential backoff (0.2 s doubling to 5 s) while the database
        is unavailable, up to ``timeout_s``; ``on_wait(message)`` is called before each wait.

        Raises
        ------
        DatabaseUnavailableError
            Still unavailable at the deadline (or ``stop()`` became true).
        """
        deadline = time.monotonic() + timeout_s
        delay = 0.2
        while True:
            try:
                return fn()
            except DatabaseUnavailableError as err:
                left = deadline - time.monotonic()
                if left <= 0 or (stop is not None and stop()):
                    raise DatabaseUnavailableError(
                        f"{what}: database still unavailable after {timeout_s:.0f} s "
                        f"({self.health.error})"
                    ) from err
                msg = f"waiting for the database to {what} (retry in {min(delay, left):.1f} s)"
                if on_wait is not None:
                    on_wait(msg)
                time.sleep(min(delay, left))
                delay = min(delay * 2, 5.0)

    def close(self) -> None:
        self.engine.dispose()


def open_database(url: str, *, timeout_s: float = 0.0) -> Database:
    """Open (and migrate) the database at ``url``, waiting up to ``timeout_s`` for a server
    that is not up yet.

    Raises
    ------
    SetupError
        The URL cannot be opened; the message names it.
    """
    shown = masked_url(url)
    kwargs: dict[str, Any] = {}
    is_sqlite = url.startswith("sqlite")
    if is_sqlite:
        kwargs["connect_args"] = {"check_same_thread": False, "timeout": 10.0}
        path = url.split("///", 1)[1] if "///" in url else ""
        if path and path != ":memory:":
            Path(path).parent.mkdir(parents=True, exist_ok=True)
            private_file(Path(path))
    else:
        kwargs["pool_pre_ping"] = True
        kwargs["pool_size"] = 10
        kwargs["max_overflow"] = 10
        if url.startswith("postgresql"):
            kwargs["connect_args"] = {"connect_timeout": 5}
    deadline = time.monotonic() + timeout_s
    delay = 0.2
    while True:
        try:
            engine = create_engine(url, **kwargs)
            if is_sqlite:
                event.listen(engine, "connect", _sqlite_pragmas)
            return Database(engine)
        except ImportError as err:
            raise SetupError(
                f"database_url {shown!r} needs a driver that is not installed ({err}); "
                "PostgreSQL: use postgresql+psycopg://... (psycopg comes with pip install -e .)"
            ) from err
        except SQLAlchemyError as err:
            if is_connection_error(err) and time.monotonic() + delay < deadline:
                log.warning("database %s not reachable yet (%s); retrying", shown, err)
                time.sleep(delay)
                delay = min(delay * 2, 5.0)
                continue
            raise SetupError(
                f"database_url {shown!r} cannot be opened ({err}); fix database_url in "
                "config/dimacq.toml or DIMACQ_DATABASE_URL"
            ) from err


def masked_url(url: str) -> str:
    """The URL with its password hidden (for messages and logs)."""
    try:
        return make_url(url).render_as_string(hide_password=True)
    except (ArgumentError, ValueError):
        return url.split("@", 1)[-1]
