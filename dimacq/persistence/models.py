"""Database tables (SQLAlchemy 2 declarative, portable types only: SQLite and PostgreSQL).

Several test stands may share one database: every row a stand produces carries the stand's name
(``stand``). FRF sets live in the database (``FrfSet.data``, the HDF5 bytes), so every stand and
the office read them; raw time data (each average of an acquisition) stays on the acquiring
stand's disk as an HDF5 file, registered here by its path relative to that stand's data folder
and the stand's name (:class:`dimacq.persistence.arrays.ArrayStore`). Columns added after schema
version 1 are listed in :data:`dimacq.persistence.migrations.MIGRATIONS`.
"""

from __future__ import annotations

from datetime import UTC, datetime
from typing import Any, ClassVar

from sqlalchemy import (
    JSON,
    Boolean,
    DateTime,
    Float,
    ForeignKey,
    Integer,
    LargeBinary,
    String,
    Text,
)
from sqlalchemy.orm import DeclarativeBase, Mapped, mapped_column

__all__ = [
    "NEVER_REUSE_IDS",
    "Acquisition",
    "Average",
    "Base",
    "Calibration",
    "DigitizedPointRow",
    "FrfSet",
    "JobRow",
    "LineOfActionRow",
    "OrientationRow",
    "PatchRow",
    "ReferenceNode",
    "SchemaMigration",
    "SensitivityStudy",
    "SetupRow",
    "Solution",
    "StandRow",
    "TestRow",
    "utcnow",
]


def utcnow() -> datetime:
    return datetime.now(UTC)


#: Table options of every table whose integer id the API shows: SQLite's AUTOINCREMENT, so an
#: id is never given again after its row was deleted (without it SQLite reuses the largest
#: deleted id: a client holding "FRF set 3" would read another set). PostgreSQL's SERIAL
#: sequences never go back anyway. Existing SQLite tables are rebuilt by migration 5.
NEVER_REUSE_IDS: dict[str, Any] = {"sqlite_autoincrement": True}


class Base(DeclarativeBase):
    type_annotation_map: ClassVar[dict[Any, Any]] = {dict[str, Any]: JSON, list[Any]: JSON}


class SchemaMigration(Base):
    __tablename__ = "schema_migrations"
    version: Mapped[int] = mapped_column(Integer, primary_key=True)
    description: Mapped[str] = mapped_column(String(200))
    applied_at: Mapped[datetime] = mapped_column(DateTime(timezone=True), default=utcnow)


class PatchRow(Base):
    """An array position of the digitizer; ``registration`` maps its DACS to the GCS."""

    __tablename__ = "patches"
    index: Mapped[int] = mapped_column(Integer, primary_key=True, autoincrement=False)
    name: Mapped[str] = mapped_column(String(200))
    registration: Mapped[dict[str, Any] | None] = mapped_column(JSON, nullable=True)
    # which test (reference nodes, orientations, lines of action) the patch belongs to; a new
    # test starts a fresh patch with the next number and leaves the older patches' points aside
    test: Mapped[int] = mapped_column(Integer, default=0, server_default="0")


class DigitizedPointRow(Base):
    """One accepted digitized point (committed as soon as it is accepted)."""

    __tablename__ = "digitized_points"
    __table_args__ = NEVER_REUSE_IDS
    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    label: Mapped[str] = mapped_column(String(200), index=True)
    patch: Mapped[int] = mapped_column(Integer)
    position_array_m: Mapped[list[Any]] = mapped_column(JSON)
    spread_m: Mapped[list[Any]] = mapped_column(JSON)
    n_shots: Mapped[int] = mapped_column(Integer)
    n_used: Mapped[int] = mapped_column(Integer)
    seqs: Mapped[list[Any]] = mapped_column(JSON)
    created_at: Mapped[datetime] = mapped_column(DateTime(timezone=True), default=utcnow)


class ReferenceNode(Base):
    """A reference node with known GCS coordinates (registration targets)."""

    __tablename__ = "reference_nodes"
    label: Mapped[str] = mapped_column(String(200), primary_key=True)
    position_m: Mapped[list[Any]] = mapped_column(JSON)


class OrientationRow(Base):
    """A triaxial sensor's orientation from the jig (rotation: columns = local axes in the GCS)."""

    __tablename__ = "orientations"
    node: Mapped[int] = mapped_column(Integer, primary_key=True, autoincrement=False)
    body: Mapped[dict[str, Any]] = mapped_column(JSON)


class LineOfActionRow(Base):
    """An input's line of action."""

    __tablename__ = "lines_of_action"
    node: Mapped[int] = mapped_column(Integer, primary_key=True, autoincrement=False)
    body: Mapped[dict[str, Any]] = mapped_column(JSON)


class TestRow(Base):
    """A test of one article (schema 4): who, when, notes; its setups name it (``test_id``), and
    through them its acquisitions, FRF sets and solutions. Archived tests are kept, listed apart."""

    __test__ = False  # not a pytest class
    __tablename__ = "tests"
    __table_args__ = NEVER_REUSE_IDS
    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    article: Mapped[str] = mapped_column(String(200))
    operator: Mapped[str] = mapped_column(String(200), default="")
    date: Mapped[str] = mapped_column(String(10))  # ISO date of the test, YYYY-MM-DD
    notes: Mapped[str] = mapped_column(Text, default="")
    archived: Mapped[bool] = mapped_column(Boolean, default=False)
    stand: Mapped[str] = mapped_column(String(100), default="", server_default="")
    created_at: Mapped[datetime] = mapped_column(DateTime(timezone=True), default=utcnow)
    updated_at: Mapped[datetime | None] = mapped_column(
        DateTime(timezone=True), nullable=True, default=utcnow, onupdate=utcnow
    )


class SetupRow(Base):
    __tablename__ = "setups"
    __table_args__ = NEVER_REUSE_IDS
    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    name: Mapped[str] = mapped_column(String(200), default="")
    stand: Mapped[str] = mapped_column(String(100), default="", server_default="")
    body: Mapped[dict[str, Any]] = mapped_column(JSON)
    created_at: Mapped[datetime] = mapped_column(DateTime(timezone=True), default=utcnow)
    # the test it belongs to (schema 4; NULL: none, and every setup stored before)
    test_id: Mapped[int | None] = mapped_column(ForeignKey("tests.id"), nullable=True, index=True)


class Acquisition(Base):
    __tablename__ = "acquisitions"
    __table_args__ = NEVER_REUSE_IDS
    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    setup_id: Mapped[int | None] = mapped_column(ForeignKey("setups.id"), nullable=True)
    config: Mapped[dict[str, Any]] = mapped_column(JSON)
    state: Mapped[str] = mapped_column(String(20), default="configured")
    message: Mapped[str] = mapped_column(Text, default="")
    job_id: Mapped[str | None] = mapped_column(String(40), nullable=True)
    frf_id: Mapped[int | None] = mapped_column(Integer, nullable=True)
    stand: Mapped[str] = mapped_column(String(100), default="", server_default="")
    created_at: Mapped[datetime] = mapped_column(DateTime(timezone=True), default=utcnow)
    # every change of state, message, job or FRF set (schema 4; NULL in older rows)
    updated_at: Mapped[datetime | None] = mapped_column(
        DateTime(timezone=True), nullable=True, default=utcnow, onupdate=utcnow
    )


class Average(Base):
    """One completed average (accepted or rejected) of an acquisition; data in an HDF5 file."""

    __tablename__ = "averages"
    __table_args__ = NEVER_REUSE_IDS
    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    acquisition_id: Mapped[int] = mapped_column(ForeignKey("acquisitions.id"), index=True)
    input_index: Mapped[int] = mapped_column(Integer)
    number: Mapped[int] = mapped_column(Integer)
    accepted: Mapped[bool] = mapped_column(Boolean)
    reason: Mapped[str] = mapped_column(Text, default="")
    path: Mapped[str] = mapped_column(String(500))
    stand: Mapped[str] = mapped_column(String(100), default="", server_default="")
    created_at: Mapped[datetime] = mapped_column(DateTime(timezone=True), default=utcnow)


class FrfSet(Base):
    __tablename__ = "frf_sets"
    __table_args__ = NEVER_REUSE_IDS
    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    setup_id: Mapped[int] = mapped_column(ForeignKey("setups.id"))
    acquisition_id: Mapped[int | None] = mapped_column(Integer, nullable=True)
    name: Mapped[str] = mapped_column(String(200), default="")
    path: Mapped[str] = mapped_column(String(500))
    n_lines: Mapped[int] = mapped_column(Integer)
    n_outputs: Mapped[int] = mapped_column(Integer)
    n_inputs: Mapped[int] = mapped_column(Integer)
    f_min_hz: Mapped[float] = mapped_column(Float)
    f_max_hz: Mapped[float] = mapped_column(Float)
    stand: Mapped[str] = mapped_column(String(100), default="", server_default="")
    data: Mapped[bytes | None] = mapped_column(LargeBinary, nullable=True)
    created_at: Mapped[datetime] = mapped_column(DateTime(timezone=True), default=utcnow)


class Solution(Base):
    __tablename__ = "solutions"
    __table_args__ = NEVER_REUSE_IDS
    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    frf_id: Mapped[int] = mapped_column(ForeignKey("frf_sets.id"))
    options: Mapped[dict[str, Any]] = mapped_column(JSON)
    result: Mapped[dict[str, Any]] = mapped_column(JSON)
    stand: Mapped[str] = mapped_column(String(100), default="", server_default="")
    created_at: Mapped[datetime] = mapped_column(DateTime(timezone=True), default=utcnow)


class Calibration(Base):
    __tablename__ = "calibrations"
    __table_args__ = NEVER_REUSE_IDS
    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    serial: Mapped[str] = mapped_column(String(100))
    body: Mapped[dict[str, Any]] = mapped_column(JSON)
    stand: Mapped[str] = mapped_column(String(100), default="", server_default="")
    created_at: Mapped[datetime] = mapped_column(DateTime(timezone=True), default=utcnow)


class SensitivityStudy(Base):
    __tablename__ = "sensitivity_studies"
    __table_args__ = NEVER_REUSE_IDS
    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    params: Mapped[dict[str, Any]] = mapped_column(JSON)
    result: Mapped[dict[str, Any] | None] = mapped_column(JSON, nullable=True)
    created_at: Mapped[datetime] = mapped_column(DateTime(timezone=True), default=utcnow)


class JobRow(Base):
    """A background job's last known state (running jobs found at start-up were interrupted).

    ``stand`` runs (or ran) the job, ``owner`` is the service process that claimed it,
    ``created_by`` the stand that created it. A queued job (``state = "pending"``, ``params``
    given) runs on stand ``runs_on`` or, if that is NULL, on whichever service claims it first
    (:mod:`dimacq.persistence.queue`); ``attempts`` counts its claims.
    """

    __tablename__ = "jobs"
    id: Mapped[str] = mapped_column(String(40), primary_key=True)
    kind: Mapped[str] = mapped_column(String(50))
    state: Mapped[str] = mapped_column(String(20))
    progress: Mapped[float] = mapped_column(Float, default=0.0)
    message: Mapped[str] = mapped_column(Text, default="")
    result: Mapped[dict[str, Any] | None] = mapped_column(JSON, nullable=True)
    error: Mapped[str | None] = mapped_column(Text, nullable=True)
    created_at: Mapped[datetime] = mapped_column(DateTime(timezone=True), default=utcnow)
    finished_at: Mapped[datetime | None] = mapped_column(DateTime(timezone=True), nullable=True)
    stand: Mapped[str] = mapped_column(String(100), default="", server_default="")
    created_by: Mapped[str] = mapped_column(String(100), default="", server_default="")
    runs_on: Mapped[str | None] = mapped_column(String(100), nullable=True)
    owner: Mapped[str | None] = mapped_column(String(100), nullable=True)
    params: Mapped[dict[str, Any] | None] = mapped_column(JSON, nullable=True)
    attempts: Mapped[int] = mapped_column(Integer, default=0, server_default="0")


class StandRow(Base):
    """A test stand (one dimacq service on its PC): who holds the name, alive until when.

    A service claims its stand's row at start-up and renews ``heartbeat_at``; a second service
    under the same name is refused while the heartbeat is fresh, so one stand's devices are only
    ever driven by that stand's service (:mod:`dimacq.persistence.stands`).
    """

    __tablename__ = "stands"
    name: Mapped[str] = mapped_column(String(100), primary_key=True)
    instance: Mapped[str] = mapped_column(String(100))
    host: Mapped[str] = mapped_column(String(200), default="")
    pid: Mapped[int] = mapped_column(Integer, default=0)
    api_url: Mapped[str] = mapped_column(String(300), default="")
    started_at: Mapped[datetime] = mapped_column(DateTime(timezone=True), default=utcnow)
    heartbeat_at: Mapped[datetime] = mapped_column(DateTime(timezone=True), default=utcnow)
