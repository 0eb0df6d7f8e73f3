"""Acquisitions: configure, start, stop, progress, averages accepted and rejected."""

from __future__ import annotations

from dataclasses import asdict
from typing import Annotated, Any

from fastapi import APIRouter, status

from dimacq.api.deps import IdPath, LabDep
from dimacq.api.routers._common import body_openapi, found, strict_body
from dimacq.api.schemas import AcquisitionRequest, HitDecision

router = APIRouter(prefix="/api/acquisitions", tags=["acquisitions"])


@router.post(
    "",
    response_model=dict[str, Any],
    status_code=status.HTTP_202_ACCEPTED,
    openapi_extra=body_openapi(AcquisitionRequest),
)
def start_acquisition(
    lab: LabDep, body: Annotated[AcquisitionRequest, strict_body(AcquisitionRequest)]
) -> dict[str, Any]:
    """Configure and start an impact acquisition (a job); FRFs are stored when it finishes."""
    return asdict(lab.acquisitions.start(body.model_dump()))


@router.get("", response_model=list[dict[str, Any]])
def list_acquisitions(lab: LabDep) -> list[dict[str, Any]]:
    return [asdict(a) for a in lab.acquisitions.all()]


@router.get("/{acq_id:int}", response_model=dict[str, Any])
def get_acquisition(acq_id: IdPath, lab: LabDep) -> dict[str, Any]:
    """State, progress and the averages accepted and rejected so far."""
    return asdict(found(lab.acquisitions.get(acq_id), f"acquisition {acq_id}"))


@router.post("/{acq_id:int}/stop", response_model=dict[str, Any])
def stop_acquisition(acq_id: IdPath, lab: LabDep) -> dict[str, Any]:
    return asdict(found(lab.acquisitions.stop(acq_id), f"acquisition {acq_id}"))


@router.post(
    "/{acq_id:int}/review", response_model=dict[str, Any], openapi_extra=body_openapi(HitDecision)
)
def review_hit(
    acq_id: IdPath, lab: LabDep, body: Annotated[HitDecision, strict_body(HitDecision)]
) -> dict[str, Any]:
    """The operator's accept / reject / redo of the hit waiting for review (``pending_review``
    of an acquisition started with ``review: true``); 409 when that hit is not the one waiting."""
    return asdict(
        found(lab.acquisitions.decide(acq_id, body.number, body.decision), f"acquisition {acq_id}")
    )


@router.post("/{acq_id:int}/finish", response_model=dict[str, Any])
def finish_acquisition(acq_id: IdPath, lab: LabDep) -> dict[str, Any]:
    """Stop striking and keep the accepted averages: the FRFs of the inputs that reached
    ``min_averages`` are stored (``stop`` cancels instead: no FRF set)."""
    return asdict(found(lab.acquisitions.finish(acq_id), f"acquisition {acq_id}"))


@router.get("/{acq_id:int}/hit", response_model=dict[str, Any])
def get_hit(acq_id: IdPath, lab: LabDep) -> dict[str, Any]:
    """The hit waiting for review (``pending: true``), else the last decided one (this service's
    run only): force (N) and strongest response (m/s²) over time, their spectra in dB, the
    checks' reasons."""
    return found(lab.acquisitions.hit(acq_id), f"hit of acquisition {acq_id}")


@router.get("/{acq_id:int}/averages/{number:int}", response_model=dict[str, Any])
def get_average(acq_id: int, number: int, lab: LabDep) -> dict[str, Any]:
    """Raw time data of one average, served by the stand that acquired it (it stays on that
    stand's disk); another stand answers 409 with that stand's address."""
    return found(
        lab.acquisitions.average_data(acq_id, number), f"average {number} of acquisition {acq_id}"
    )
