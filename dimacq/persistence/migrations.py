"""Versioned schema migrations: a ``schema_migrations`` table records each applied version.

Each migration is a function of a SQLAlchemy connection, applied in order inside one
transaction per version, using only portable DDL (``MetaData.create_all`` / ``Table.create`` and
``ALTER TABLE ... ADD COLUMN``), so SQLite and PostgreSQL take the same path. To change the
schema, append ``(version, description, function)`` to :data:`MIGRATIONS`; never edit an applied one.
"""

from __future__ import annotations

import logging
from collections.abc import Callable

from sqlalchemy import Connection, Engine, inspect, select

from dimacq.errors import SetupError
from dimacq.persistence import models as m

__all__ = ["MIGRATIONS", "SCHEMA_VERSION", "current_version", "migrate"]

log = logging.getLogger(__name__)


def _v1_initial(conn: Connection) -> None:
    tables = [t for name, t in m.Base.metadata.tables.items() if name != "schema_migrations"]
    m.Base.metadata.create_all(conn, tables=tables)


MIGRATIONS: list[tuple[int, str, Callable[[Connection], None]]] = [
    (
        1,
        "initial schema: geometry, setups, acquisitions, averages, FRFs, solutions, jobs",
        _v1_initial,
    ),
]

#: The schema version this code expects.
SCHEMA_VERSION = MIGRATIONS[-1][0]


def current_version(engine: Engine) -> int:
    """Highest applied migration (0 for an empty database)."""
    if not inspect(engine).has_table("schema_migrations"):
        return 0
    with engine.connect() as conn:
        rows = conn.execute(select(m.SchemaMigration.version)).scalars().all()
    return max(rows, default=0)


def migrate(engine: Engine) -> int:
    """Apply the missing migrations; return the resulting version.

    Raises
    ------
    SetupError
        The database is newer than this code (downgrade refused).
    """
    m.SchemaMigration.__table__.create(engine, checkfirst=True)  # type: ignore[attr-defined]
    have = current_version(engine)
    if have > SCHEMA_VERSION:
        raise SetupError(
            f"database schema version {have} is newer than this dimacq ({SCHEMA_VERSION}); "
            "upgrade dimacq or point database_url at another database"
        )
    for version, description, fn in MIGRATIONS:
        if version <= have:
            continue
        with engine.begin() as conn:
            fn(conn)
            conn.execute(
                m.SchemaMigration.__table__.insert().values(  # type: ignore[attr-defined]
                    version=version, description=description, applied_at=m.utcnow()
                )
            )
        log.info("database migrated to schema version %d (%s)", version, description)
    return max(have, SCHEMA_VERSION)
