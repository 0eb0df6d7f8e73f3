"""FRF sets: list, read, import (UFF), export (UFF)."""

from __future__ import annotations

from dataclasses import asdict
from typing import Annotated, Any

from fastapi import APIRouter, Query, Request, Response, status
from starlette.concurrency import run_in_threadpool

from dimacq.api.deps import IdPath, LabDep
from dimacq.api.routers._common import RAW_BODY, found, read_upload
from dimacq.api.schemas import MAX_ID, FrfOut
from dimacq.services.lab.store import FrfSummary

router = APIRouter(prefix="/api/frfs", tags=["frfs"])


@router.get("", response_model=list[FrfOut])
def list_frfs(lab: LabDep) -> list[FrfSummary]:
    return lab.store.frfs()


@router.get("/{frf_id:int}", response_model=FrfOut)
def get_frf(frf_id: IdPath, lab: LabDep) -> FrfSummary:
    return found(lab.store.frf_summary(frf_id), f"FRF set {frf_id}")


@router.get("/{frf_id:int}/data", response_model=dict[str, Any])
def frf_data(
    frf_id: IdPath,
    lab: LabDep,
    output: int | None = Query(default=None, ge=0),
    input: int | None = Query(default=None, ge=0),
) -> dict[str, Any]:
    """FRF values (real, imag, coherence) of one output/input pair, or all."""
    return asdict(found(lab.store.frf_values(frf_id, output, input), f"FRF set {frf_id}"))


@router.get(
    "/{frf_id:int}/uff",
    response_class=Response,
    responses={200: {"content": {"application/octet-stream": {}}}},
)
def export_uff(frf_id: IdPath, lab: LabDep, whole_test: bool = True) -> Response:
    """The FRFs as UFF 58 (with geometry 164/2420/2411 when ``whole_test``)."""
    data = found(lab.store.export_frf_uff(frf_id, whole_test), f"FRF set {frf_id}")
    return Response(content=data, media_type="application/octet-stream")


@router.post(
    "/import", response_model=FrfOut, status_code=status.HTTP_201_CREATED, openapi_extra=RAW_BODY
)
async def import_uff(
    request: Request, lab: LabDep, setup_id: Annotated[int, Query(ge=1, le=MAX_ID)], name: str = ""
) -> FrfSummary:
    """Send a UFF file (58 records) whose channels match the setup."""
    data = await read_upload(request)
    fid = await run_in_threadpool(lab.store.import_frf, data, setup_id, name)
    return found(lab.store.frf_summary(fid), f"FRF set {fid}")
