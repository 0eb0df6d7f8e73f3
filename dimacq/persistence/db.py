"""Database engine and sessions.

SQLite (the embedded default) is opened in WAL mode with ``synchronous=FULL``: a committed
transaction survives the process being killed, readers never block the writer. Any other
SQLAlchemy URL (e.g. ``postgresql+psycopg://...``) is used as is; the code issues no
SQLite-only SQL outside the connection pragmas below.
"""

from __future__ import annotations

import logging
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from sqlalchemy import Engine, create_engine, event
from sqlalchemy.exc import SQLAlchemyError
from sqlalchemy.orm import Session, sessionmaker

from dimacq.errors import SetupError
from dimacq.persistence.migrations import migrate

__all__ = ["Database", "open_database"]

log = logging.getLogger(__name__)


def _sqlite_pragmas(dbapi_conn: Any, _record: Any) -> None:
    cur = dbapi_conn.cursor()
    cur.execute("PRAGMA journal_mode=WAL")
    cur.execute("PRAGMA synchronous=FULL")
    cur.execute("PRAGMA foreign_keys=ON")
    cur.execute("PRAGMA busy_timeout=10000")
    cur.close()


class Database:
    """An engine, its session factory and the applied schema version."""

    def __init__(self, engine: Engine) -> None:
        self.engine = engine
        self.sessions = sessionmaker(engine, expire_on_commit=False)
        self.schema_version = migrate(engine)

    @contextmanager
    def session(self) -> Iterator[Session]:
        """A session committed on success, rolled back on error."""
        with self.sessions() as s:
            try:
                yield s
                s.commit()
            except BaseException:
                s.rollback()
                raise

    def close(self) -> None:
        self.engine.dispose()


def open_database(url: str) -> Database:
    """Open (and migrate) the database at ``url``.

    Raises
    ------
    SetupError
        The URL cannot be opened; the message names it.
    """
    kwargs: dict[str, Any] = {}
    is_sqlite = url.startswith("sqlite")
    if is_sqlite:
        kwargs["connect_args"] = {"check_same_thread": False, "timeout": 10.0}
        path = url.split("///", 1)[1] if "///" in url else ""
        if path and path != ":memory:":
            Path(path).parent.mkdir(parents=True, exist_ok=True)
    try:
        engine = create_engine(url, **kwargs)
        if is_sqlite:
            event.listen(engine, "connect", _sqlite_pragmas)
        return Database(engine)
    except SQLAlchemyError as err:
        raise SetupError(
            f"database_url {url!r} cannot be opened ({err}); fix database_url in config/dimacq.toml "
            "or DIMACQ_DATABASE_URL"
        ) from err
