"""Tests: one test of one article (article name, operator, date, notes), listed, opened, edited,
archived and deleted. A setup names its test (``test_id``); the test's acquisitions, FRF sets
and solutions are those of its setups. Deleting a test that has setups is refused (archive it,
or delete its setups first): nothing measured is lost by a click.
"""

from __future__ import annotations

import datetime as dt
from dataclasses import dataclass
from typing import Any

from sqlalchemy import func, select

from dimacq.errors import DeviceStateError, SetupError
from dimacq.persistence import Database
from dimacq.persistence import models as m
from dimacq.services.lab.common import iso
from dimacq.services.lab.store import Page

__all__ = ["LabTest", "LabTestService"]


@dataclass(frozen=True)
class LabTest:
    """A stored test and the ids of its setups."""

    __test__ = False  # not a pytest class

    id: int
    article: str
    operator: str
    date: str
    notes: str
    archived: bool
    setup_ids: list[int]
    stand: str = ""
    created_at: str | None = None
    updated_at: str | None = None


class LabTestService:
    """Create, list, read, change and delete tests."""

    __test__ = False

    def __init__(self, db: Database, stand: str = "") -> None:
        self.db = db
        self.stand = stand

    def _of(self, s: Any, r: m.TestRow) -> LabTest:
        setups = list(
            s.scalars(
                select(m.SetupRow.id).where(m.SetupRow.test_id == r.id).order_by(m.SetupRow.id)
            )
        )
        return LabTest(
            id=r.id,
            article=r.article,
            operator=r.operator,
            date=r.date,
            notes=r.notes,
            archived=bool(r.archived),
            setup_ids=[int(i) for i in setups],
            stand=r.stand,
            created_at=iso(r.created_at),
            updated_at=iso(r.updated_at or r.created_at),
        )

    def create(
        self, article: str, operator: str = "", date: dt.date | None = None, notes: str = ""
    ) -> LabTest:
        """A new test (``date`` default: today, UTC)."""
        day = (date or dt.datetime.now(dt.UTC).date()).isoformat()
        with self.db.session() as s:
            row = m.TestRow(
                article=article, operator=operator, date=day, notes=notes, stand=self.stand
            )
            s.add(row)
            s.flush()
            return self._of(s, row)

    def get(self, test_id: int) -> LabTest | None:
        with self.db.session() as s:
            row = s.get(m.TestRow, test_id)
            return None if row is None else self._of(s, row)

    def all(
        self, limit: int | None = None, offset: int = 0, archived: bool | None = None
    ) -> Page[LabTest]:
        """Tests in id order (only archived or only open ones when ``archived`` is given)."""
        where = [] if archived is None else [m.TestRow.archived == archived]
        with self.db.session() as s:
            total = int(s.scalar(select(func.count()).select_from(m.TestRow).where(*where)) or 0)
            q = select(m.TestRow).where(*where).order_by(m.TestRow.id).offset(offset).limit(limit)
            return Page([self._of(s, r) for r in s.scalars(q)], total)

    def update(self, test_id: int, changes: dict[str, Any]) -> LabTest | None:
        """Change the given fields (``article``, ``operator``, ``date``, ``notes``,
        ``archived``)."""
        with self.db.session() as s:
            row = s.get(m.TestRow, test_id)
            if row is None:
                return None
            for k, v in changes.items():
                setattr(row, k, v.isoformat() if isinstance(v, dt.date) else v)
            s.flush()
            return self._of(s, row)

    def delete(self, test_id: int) -> bool | None:
        """Delete a test without setups; 409 (naming them) while it has some."""
        with self.db.session() as s:
            row = s.get(m.TestRow, test_id)
            if row is None:
                return None
            setups = list(s.scalars(select(m.SetupRow.id).where(m.SetupRow.test_id == test_id)))
            if setups:
                raise DeviceStateError(
                    f"test {test_id} has setups {setups}: archive it (PATCH archived = true) or "
                    "delete its setups first"
                )
            s.delete(row)
            return True

    def require(self, test_id: int) -> None:
        """SetupError naming ``test_id`` unless the test exists."""
        if self.get(test_id) is None:
            raise SetupError(
                f"test_id {test_id} does not exist; create the test first (POST /api/tests)"
            )
