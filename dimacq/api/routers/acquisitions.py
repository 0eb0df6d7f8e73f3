"""Acquisitions: configure, start, stop, progress, averages accepted and rejected, delete."""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, Response, status

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
from dimacq.api.schemas import AcquisitionOut, AcquisitionRequest, AverageDataOut
from dimacq.services.lab.acquisitions import AcquisitionInfo

router = APIRouter(prefix="/api/acquisitions", tags=["acquisitions"])


@router.post(
    "",
    response_model=AcquisitionOut,
    status_code=status.HTTP_202_ACCEPTED,
    openapi_extra=body_openapi(AcquisitionRequest),
)
def start_acquisition(
    lab: LabDep, body: Annotated[AcquisitionRequest, strict_body(AcquisitionRequest)]
) -> AcquisitionInfo:
    """Configure and start an impact acquisition (a job, ``job_id``); FRFs are stored when it
    succeeds (``frf_id``). The settings are checked here (422 naming the field), before
    anything starts."""
    return lab.acquisitions.start(body.model_dump())


@router.get("", response_model=list[AcquisitionOut], responses=LIST_RESPONSES)
def list_acquisitions(lab: LabDep, page: PageDep, response: Response) -> list[AcquisitionInfo]:
    return paged(response, lab.acquisitions.all(page.limit, page.offset), page)


@router.get("/{acq_id:int}", response_model=AcquisitionOut)
def get_acquisition(acq_id: IdPath, lab: LabDep) -> AcquisitionInfo:
    """State, progress and the averages accepted and rejected so far."""
    return found(lab.acquisitions.get(acq_id), f"acquisition {acq_id}")


@router.delete("/{acq_id:int}", status_code=status.HTTP_204_NO_CONTENT)
def delete_acquisition(acq_id: IdPath, lab: LabDep) -> Response:
    """Delete an acquisition that is not running and its raw averages (its FRF set stays);
    409 while it runs."""
    return deleted(lab.acquisitions.delete(acq_id), f"acquisition {acq_id}")


@router.post("/{acq_id:int}/stop", response_model=AcquisitionOut)
def stop_acquisition(acq_id: IdPath, lab: LabDep) -> AcquisitionInfo:
    """Stop: the accepted averages are kept."""
    return found(lab.acquisitions.stop(acq_id), f"acquisition {acq_id}")


@router.get("/{acq_id:int}/averages/{number:int}", response_model=AverageDataOut)
def get_average(acq_id: IdPath, number: int, lab: LabDep) -> dict[str, Any]:
    """Raw time data of one average, served by the stand that acquired it (it stays on that
    stand's disk); another stand answers 409 with that stand's address."""
    return found(
        lab.acquisitions.average_data(acq_id, number), f"average {number} of acquisition {acq_id}"
    )
