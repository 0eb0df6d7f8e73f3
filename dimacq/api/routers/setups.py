"""Test setups: create, list, read, delete, import (JSON/TOML/whole-test UFF), export, build from
geometry."""

from __future__ import annotations

from dataclasses import asdict
from typing import Annotated, Any, Literal

from fastapi import APIRouter, Query, Request, Response, status
from starlette.concurrency import run_in_threadpool

from dimacq.api.deps import CANONICAL_INT, IdPath, LabDep, NameQuery
from dimacq.api.routers._common import (
    LIST_RESPONSES,
    RAW_BODY,
    PageDep,
    body_openapi,
    deleted,
    found,
    paged,
    read_upload,
    strict_body,
)
from dimacq.api.schemas import MAX_ID, FromGeometryRequest, ImportOut, SetupOut
from dimacq.model.setup import TestSetup
from dimacq.services.lab.store import SetupSummary

router = APIRouter(prefix="/api/setups", tags=["setups"])

TestIdQuery = Annotated[
    int | None, CANONICAL_INT, Query(ge=1, le=MAX_ID, description="the test the setup belongs to")
]


@router.post(
    "",
    response_model=SetupOut,
    status_code=status.HTTP_201_CREATED,
    openapi_extra=body_openapi(TestSetup),
)
def create_setup(
    lab: LabDep, body: Annotated[TestSetup, strict_body(TestSetup)], test_id: TestIdQuery = None
) -> SetupSummary:
    """Store a setup (the setup-file keys as JSON), in test ``test_id`` when given; returns it
    with its ``id``."""
    sid = lab.store.save_setup(body, test_id)
    return found(lab.store.setup_summary(sid), f"setup {sid}")


@router.get("", response_model=list[SetupOut], responses=LIST_RESPONSES)
def list_setups(
    lab: LabDep, page: PageDep, response: Response, test_id: TestIdQuery = None
) -> list[SetupSummary]:
    return paged(response, lab.store.setups(page.limit, page.offset, test_id), page)


@router.get("/{setup_id:id}", response_model=SetupOut)
def get_setup(setup_id: IdPath, lab: LabDep) -> SetupSummary:
    return found(lab.store.setup_summary(setup_id), f"setup {setup_id}")


@router.delete("/{setup_id:id}", status_code=status.HTTP_204_NO_CONTENT)
def delete_setup(setup_id: IdPath, lab: LabDep) -> Response:
    """Delete a setup; 409 while FRF sets or acquisitions use it (delete those first)."""
    return deleted(lab.store.delete_setup(setup_id), f"setup {setup_id}")


@router.get(
    "/{setup_id:id}/export",
    response_class=Response,
    responses={200: {"content": {"application/json": {}, "application/toml": {}}}},
)
def export_setup(
    setup_id: IdPath, lab: LabDep, format: Literal["json", "toml"] = "json"
) -> Response:
    """The setup file (the keys of ``dimacq/io/setup_file.py``)."""
    out = found(lab.store.export_setup(setup_id, format), f"setup {setup_id}")
    return Response(content=out.content, media_type=out.media_type)


@router.post(
    "/import", response_model=ImportOut, status_code=status.HTTP_201_CREATED, openapi_extra=RAW_BODY
)
async def import_setup(
    request: Request,
    lab: LabDep,
    format: Literal["json", "toml", "uff"] = "json",
    name: NameQuery | None = None,
    test_id: TestIdQuery = None,
) -> dict[str, Any]:
    """Send the file as the body; returns the stored setup with its ``id``. ``uff`` (a whole
    test) also stores its FRFs (``frf_id``)."""
    data = await read_upload(request)
    got = await run_in_threadpool(lab.store.import_setup, data, format, name, test_id)
    summary = found(lab.store.setup_summary(got.setup_id), f"setup {got.setup_id}")
    return {**asdict(summary), "frf_id": got.frf_id}


@router.post(
    "/from-geometry",
    response_model=SetupOut,
    status_code=status.HTTP_201_CREATED,
    openapi_extra=body_openapi(FromGeometryRequest),
)
def setup_from_geometry(
    lab: LabDep, body: Annotated[FromGeometryRequest, strict_body(FromGeometryRequest)]
) -> SetupSummary:
    """Responses from the oriented triaxes, inputs from the lines of action."""
    setup = lab.geometry.setup_from_geometry(
        name=body.name,
        reference_point_m=body.reference_point_m,
        length_unit=body.length_unit,
        triaxes=body.triaxes,
        inputs=body.inputs,
        load_cells=body.load_cells,
        known=body.known,
    )
    sid = lab.store.save_setup(setup, body.test_id)
    return found(lab.store.setup_summary(sid), f"setup {sid}")
