"""Versioned schema migrations: a ``schema_migrations`` table records each applied version.

Each migration is a function of a SQLAlchemy connection, applied in order inside one
transaction per version, using only portable DDL (``MetaData.create_all`` / ``Table.create`` and
``ALTER TABLE ... ADD COLUMN``), so SQLite and PostgreSQL take the same path; except version 5,
which rebuilds SQLite's id tables with AUTOINCREMENT (SQLite cannot add it in place; SQLite
migrations run with foreign keys off, checked before each commit). Every step checks
what exists before creating it, so a migration is idempotent. To change the schema, append
``(version, description, function)`` to :data:`MIGRATIONS`; never edit an applied one.

Several processes may start at once on one database (the services of several test stands): the
whole check-and-apply runs under a lock, a PostgreSQL advisory lock (``pg_advisory_lock``, held
by the migrating connection, released when it ends even if the process dies) or, for SQLite, an
exclusive ``flock`` on ``<database file>.migrate.lock``. The second process waits, then finds
the schema current and applies nothing.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Callable, Iterator
from contextlib import contextmanager

from sqlalchemy import Column, Connection, Engine, MetaData, inspect, select, text

from dimacq.errors import SetupError
from dimacq.persistence import models as m

__all__ = ["MIGRATIONS", "SCHEMA_VERSION", "current_version", "migrate", "migration_lock"]

#: Key of the PostgreSQL advisory lock held while migrating (any fixed 64-bit number).
ADVISORY_LOCK_KEY = 0x64_69_6D_61_63_71  # "dimacq"

log = logging.getLogger(__name__)


def _v1_initial(conn: Connection) -> None:
    tables = [t for name, t in m.Base.metadata.tables.items() if name != "schema_migrations"]
    m.Base.metadata.create_all(conn, tables=tables)


def _add_column(conn: Connection, table: str, column: Column[object]) -> None:
    """``ALTER TABLE table ADD COLUMN`` unless the column is there (a database created by a
    later schema's ``create_all`` already has it)."""
    if column.name in {c["name"] for c in inspect(conn).get_columns(table)}:
        return
    ddl = f"ALTER TABLE {table} ADD COLUMN {column.name} {column.type.compile(conn.dialect)}"
    if column.server_default is not None:
        ddl += f" DEFAULT '{column.server_default.arg}'"  # type: ignore[attr-defined]
        ddl += " NOT NULL"
    conn.execute(text(ddl))


def _v2_stands(conn: Connection) -> None:
    m.StandRow.__table__.create(conn, checkfirst=True)  # type: ignore[attr-defined]
    for table in ("setups", "acquisitions", "averages", "frf_sets", "solutions", "calibrations"):
        _add_column(conn, table, Column("stand", m.String(100), server_default=""))
    _add_column(conn, "frf_sets", Column("data", m.LargeBinary(), nullable=True))
    _add_column(conn, "jobs", Column("stand", m.String(100), server_default=""))
    _add_column(conn, "jobs", Column("created_by", m.String(100), server_default=""))
    _add_column(conn, "jobs", Column("runs_on", m.String(100), nullable=True))
    _add_column(conn, "jobs", Column("owner", m.String(100), nullable=True))
    _add_column(conn, "jobs", Column("params", m.JSON(), nullable=True))
    _add_column(conn, "jobs", Column("attempts", m.Integer(), server_default="0"))


def _v3_patch_test(conn: Connection) -> None:
    # the digitizing test a patch belongs to (a database created by a later create_all has it)
    _add_column(conn, "patches", Column("test", m.Integer(), server_default="0"))


def _v4_tests_and_times(conn: Connection) -> None:
    m.TestRow.__table__.create(conn, checkfirst=True)  # type: ignore[attr-defined]
    _add_column(conn, "setups", Column("test_id", m.Integer(), nullable=True))
    _add_column(
        conn, "acquisitions", Column("updated_at", m.DateTime(timezone=True), nullable=True)
    )


def _sqlite_tables_reusing_ids(conn: Connection) -> list[str]:
    """The tables of :data:`~dimacq.persistence.models.NEVER_REUSE_IDS` whose SQLite DDL lacks
    AUTOINCREMENT (created before schema 5)."""
    out = []
    for name, table in m.Base.metadata.tables.items():
        if not table.dialect_options["sqlite"].get("autoincrement"):
            continue
        ddl = conn.execute(
            text("SELECT sql FROM sqlite_master WHERE type = 'table' AND name = :n"), {"n": name}
        ).scalar()
        if ddl is not None and "AUTOINCREMENT" not in ddl.upper():
            out.append(name)
    return out


def _v5_ids_never_reused(conn: Connection) -> None:
    """SQLite: rebuild each id table with AUTOINCREMENT, rows and ids kept (SQLite cannot add
    it in place): create the new table from the model, copy the rows, drop the old one, rename,
    recreate its indexes. Foreign keys are off meanwhile (:func:`migrate`) and checked before
    the commit. PostgreSQL: nothing to do (SERIAL sequences never reuse an id)."""
    if conn.dialect.name != "sqlite":
        return
    for name in _sqlite_tables_reusing_ids(conn):
        table = m.Base.metadata.tables[name]
        have = {c["name"] for c in inspect(conn).get_columns(name)}
        cols = ", ".join(f'"{c.name}"' for c in table.columns if c.name in have)
        tmp = MetaData()  # the model's tables, for the foreign keys to resolve
        for t in m.Base.metadata.sorted_tables:
            t.to_metadata(tmp)
        # the model's table (columns, foreign keys, AUTOINCREMENT) under a new name, without
        # its indexes: their names are the old table's until it is dropped
        new = table.to_metadata(tmp, name=f"_new_{name}")
        new.indexes.clear()
        new.create(conn)
        conn.execute(text(f'INSERT INTO "_new_{name}" ({cols}) SELECT {cols} FROM "{name}"'))
        conn.execute(text(f'DROP TABLE "{name}"'))
        conn.execute(text(f'ALTER TABLE "_new_{name}" RENAME TO "{name}"'))
        for index in table.indexes:
            index.create(conn, checkfirst=True)
        log.info("table %s rebuilt with AUTOINCREMENT (ids are never reused)", name)


MIGRATIONS: list[tuple[int, str, Callable[[Connection], None]]] = [
    (
        1,
        "initial schema: geometry, setups, acquisitions, averages, FRFs, solutions, jobs",
        _v1_initial,
    ),
    (
        2,
        "several stands on one database: stands, stand of each row, FRF data in the database, "
        "queued jobs",
        _v2_stands,
    ),
    (3, "patches.test: the digitizing test a patch belongs to", _v3_patch_test),
    (
        4,
        "tests (article, operator, date, notes, archived), setups.test_id, acquisitions.updated_at",
        _v4_tests_and_times,
    ),
    (5, "ids never reused: SQLite id tables rebuilt with AUTOINCREMENT", _v5_ids_never_reused),
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
    with migration_lock(engine):
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
            with _migrating(engine) as conn:
                fn(conn)
                conn.execute(
                    m.SchemaMigration.__table__.insert().values(  # type: ignore[attr-defined]
                        version=version, description=description, applied_at=m.utcnow()
                    )
                )
            log.info("database migrated to schema version %d (%s)", version, description)
        return max(have, SCHEMA_VERSION)


@contextmanager
def _migrating(engine: Engine) -> Iterator[Connection]:
    """A connection in a transaction for one migration, committed at the end. SQLite: with
    foreign keys off (a table rebuild drops a table others refer to; the pragma only takes
    effect outside a transaction), checked with ``PRAGMA foreign_key_check`` before the commit
    and on again afterwards."""
    if engine.dialect.name != "sqlite":
        with engine.begin() as conn:
            yield conn
        return
    with engine.connect() as conn:
        conn.exec_driver_sql("PRAGMA foreign_keys=OFF")
        conn.commit()
        try:
            with conn.begin():
                # the DDL inside the transaction too (Python's sqlite3 begins one only before
                # INSERT/UPDATE/DELETE): a failed rebuild leaves the database as it was
                conn.exec_driver_sql("BEGIN")
                yield conn
                bad = conn.exec_driver_sql("PRAGMA foreign_key_check").fetchall()
                if bad:
                    raise SetupError(
                        f"database migration left rows whose foreign key names nothing: {bad[:5]};"
                        " the migration is rolled back (restore the database from its backup)"
                    )
        finally:
            conn.exec_driver_sql("PRAGMA foreign_keys=ON")
            conn.commit()


@contextmanager
def migration_lock(engine: Engine) -> Iterator[None]:
    """Hold the database's migration lock (see the module docstring) for the block."""
    if engine.dialect.name == "postgresql":
        with engine.connect() as conn:
            conn.execute(text("SELECT pg_advisory_lock(:k)"), {"k": ADVISORY_LOCK_KEY})
            conn.commit()
            try:
                yield
            finally:
                conn.execute(text("SELECT pg_advisory_unlock(:k)"), {"k": ADVISORY_LOCK_KEY})
                conn.commit()
        return
    path = engine.url.database if engine.dialect.name == "sqlite" else None
    if not path or path == ":memory:":
        yield
        return
    try:
        import fcntl
    except ImportError:  # Windows: one process per SQLite file is the rule there anyway
        yield
        return
    fd = os.open(f"{path}.migrate.lock", os.O_RDWR | os.O_CREAT, 0o600)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
        yield
    finally:
        fcntl.flock(fd, fcntl.LOCK_UN)
        os.close(fd)
