"""Tests: one test of one article (article name, operator, date, notes); list, open, change,
archive, delete. A setup joins a test with ``test_id`` (``POST /api/setups?test_id=N``, the
import's and ``from-geometry``'s ``test_id``); ``GET /api/setups?test_id=N`` lists them."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Query, Response, status

from dimacq.api.deps import IdPath, LabDep
from dimacq.api.routers._common import (
    LIST_RESPONSES,
    PageDep,
    body_openapi,
    deleted,
    found,
    paged,
    strict_body,
)
from dimacq.api.schemas import TestCreate, TestOut, TestUpdate
from dimacq.services.lab.lab_tests import LabTest

router = APIRouter(prefix="/api/tests", tags=["tests"])


@router.post(
    "",
    response_model=TestOut,
    status_code=status.HTTP_201_CREATED,
    openapi_extra=body_openapi(TestCreate),
)
def create_test(lab: LabDep, body: Annotated[TestCreate, strict_body(TestCreate)]) -> LabTest:
    """A new test; returns it with its ``id``."""
    return lab.tests.create(body.article, body.operator, body.date, body.notes)


@router.get("", response_model=list[TestOut], responses=LIST_RESPONSES)
def list_tests(
    lab: LabDep,
    page: PageDep,
    response: Response,
    archived: Annotated[
        bool | None, Query(description="only archived (true) or only open (false) tests")
    ] = None,
) -> list[LabTest]:
    return paged(response, lab.tests.all(page.limit, page.offset, archived), page)


@router.get("/{test_id:id}", response_model=TestOut)
def get_test(test_id: IdPath, lab: LabDep) -> LabTest:
    return found(lab.tests.get(test_id), f"test {test_id}")


@router.patch("/{test_id:id}", response_model=TestOut, openapi_extra=body_openapi(TestUpdate))
def update_test(
    test_id: IdPath, lab: LabDep, body: Annotated[TestUpdate, strict_body(TestUpdate)]
) -> LabTest:
    """Change the fields given; ``{"archived": true}`` archives the test (kept, listed apart)."""
    changes = body.model_dump(exclude_none=True)  # left out or null: unchanged
    return found(lab.tests.update(test_id, changes), f"test {test_id}")


@router.delete("/{test_id:id}", status_code=status.HTTP_204_NO_CONTENT)
def delete_test(test_id: IdPath, lab: LabDep) -> Response:
    """Delete a test without setups; 409 while it has some (archive it instead)."""
    return deleted(lab.tests.delete(test_id), f"test {test_id}")
