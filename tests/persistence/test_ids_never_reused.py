"""Ids are never given again (issue 24, item 6): SQLite reused the largest deleted id (a client
holding "FRF set 3" read another set after a delete and an import); the id tables have
AUTOINCREMENT, and migration 5 rebuilds those of an older database, rows kept."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from sqlalchemy import create_engine, text
from sqlalchemy.schema import CreateIndex, CreateTable

from dimacq.persistence import migrate, open_database
from dimacq.persistence import models as m
from dimacq.persistence.migrations import SCHEMA_VERSION

ID_TABLES = sorted(
    name
    for name, t in m.Base.metadata.tables.items()
    if t.dialect_options["sqlite"].get("autoincrement")
)


def _ddl(engine_url: str, name: str) -> str:
    engine = create_engine(engine_url)
    try:
        with engine.connect() as conn:
            return str(
                conn.execute(
                    text("SELECT sql FROM sqlite_master WHERE type = 'table' AND name = :n"),
                    {"n": name},
                ).scalar()
            )
    finally:
        engine.dispose()


def test_every_table_of_api_ids_has_autoincrement(tmp_path: Path) -> None:
    assert {"frf_sets", "setups", "solutions", "acquisitions", "tests", "calibrations"} <= set(
        ID_TABLES
    )
    db = open_database(f"sqlite:///{tmp_path / 'new.sqlite'}")
    db.engine.dispose()
    for name in ID_TABLES:
        assert "AUTOINCREMENT" in _ddl(f"sqlite:///{tmp_path / 'new.sqlite'}", name), name


def _schema_4_database(url: str) -> None:
    """A database as schema 4 made it: the same tables without AUTOINCREMENT, and rows."""
    engine = create_engine(url)
    with engine.begin() as conn:
        conn.exec_driver_sql("PRAGMA foreign_keys=ON")
        for table in m.Base.metadata.sorted_tables:
            ddl = str(CreateTable(table).compile(dialect=engine.dialect))
            conn.exec_driver_sql(re.sub(r"\s*AUTOINCREMENT", "", ddl))
            for index in table.indexes:
                conn.exec_driver_sql(str(CreateIndex(index).compile(dialect=engine.dialect)))
        for v in (1, 2, 3, 4):
            conn.execute(
                m.SchemaMigration.__table__.insert().values(  # type: ignore[attr-defined]
                    version=v, description=f"v{v}", applied_at=m.utcnow()
                )
            )
        now = m.utcnow()
        conn.execute(
            text(
                "INSERT INTO setups (id, name, body, created_at, stand) "
                "VALUES (1, 's', '{}', :t, ''), (2, 't', '{}', :t, '')"
            ),
            {"t": now},
        )
        for fid in (1, 2, 3):
            conn.execute(
                text(
                    "INSERT INTO frf_sets (id, setup_id, name, path, n_outputs, n_inputs, "
                    "n_lines, f_min_hz, f_max_hz, created_at, stand) "
                    "VALUES (:i, 2, :n, '', 1, 1, 1, 0, 1, :t, '')"
                ),
                {"i": fid, "n": f"set {fid}", "t": now},
            )
        conn.execute(
            text(
                "INSERT INTO solutions (id, frf_id, options, result, created_at, stand) "
                "VALUES (7, 3, '{}', '{}', :t, '')"
            ),
            {"t": now},
        )
    engine.dispose()


def test_migration_5_rebuilds_the_id_tables_keeping_rows_and_keys(tmp_path: Path) -> None:
    url = f"sqlite:///{tmp_path / 'old.sqlite'}"
    _schema_4_database(url)
    assert "AUTOINCREMENT" not in _ddl(url, "frf_sets")
    db = open_database(url)
    try:
        assert db.schema_version == SCHEMA_VERSION
        with db.engine.connect() as conn:
            assert conn.exec_driver_sql("PRAGMA foreign_keys").scalar() == 1  # on again
            names = conn.exec_driver_sql("SELECT id, name FROM frf_sets ORDER BY id").fetchall()
            assert [tuple(r) for r in names] == [(1, "set 1"), (2, "set 2"), (3, "set 3")]
            assert conn.exec_driver_sql("SELECT frf_id FROM solutions").scalar() == 3
            assert conn.exec_driver_sql("PRAGMA foreign_key_check").fetchall() == []
            for child, parent in (("solutions", "frf_sets"), ("frf_sets", "setups")):
                refs = {r[2] for r in conn.exec_driver_sql(f"PRAGMA foreign_key_list({child})")}
                assert refs == {parent}, (child, refs)
            indexes = {r[1] for r in conn.exec_driver_sql("PRAGMA index_list(setups)")}
            assert "ix_setups_test_id" in indexes
            # the foreign keys still hold: a solution of a set that does not exist is refused
            with pytest.raises(Exception, match="FOREIGN KEY"):
                conn.exec_driver_sql(
                    "INSERT INTO solutions (frf_id, options, result, created_at, stand) "
                    "VALUES (99, '{}', '{}', '2026-01-01', '')"
                )
            conn.rollback()
            # ids are not reused: delete the newest set, the next one gets a new id
            conn.exec_driver_sql("DELETE FROM solutions")
            conn.exec_driver_sql("DELETE FROM frf_sets WHERE id = 3")
            conn.exec_driver_sql(
                "INSERT INTO frf_sets (setup_id, name, path, n_outputs, n_inputs, n_lines, "
                "f_min_hz, f_max_hz, created_at, stand) "
                "VALUES (2, 'new', '', 1, 1, 1, 0, 1, '2026-01-01', '')"
            )
            new_id = conn.exec_driver_sql("SELECT max(id) FROM frf_sets").scalar()
            assert new_id == 4
            conn.commit()
        for name in ID_TABLES:
            assert "AUTOINCREMENT" in _ddl(url, name), name
        assert migrate(db.engine) == SCHEMA_VERSION  # again: nothing to do
    finally:
        db.engine.dispose()
