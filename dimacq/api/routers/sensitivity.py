"""Sensitivity studies (the thesis's cube model, Monte Carlo), run as jobs."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, status

from dimacq.api.deps import IdPath, LabDep
from dimacq.api.routers._common import body_openapi, found, strict_body
from dimacq.api.schemas import SensitivityRequest, StudyOut
from dimacq.services.lab.studies import StoredStudy

router = APIRouter(prefix="/api/sensitivity", tags=["sensitivity"])


@router.post(
    "",
    response_model=StudyOut,
    status_code=status.HTTP_202_ACCEPTED,
    openapi_extra=body_openapi(SensitivityRequest),
)
def start(
    lab: LabDep, body: Annotated[SensitivityRequest, strict_body(SensitivityRequest)]
) -> StoredStudy:
    """Start a study: returns it with its ``id`` and the ``job_id`` that runs it."""
    return lab.studies.start_sensitivity(body)


@router.get("/{study_id:id}", response_model=StudyOut)
def get(study_id: IdPath, lab: LabDep) -> StoredStudy:
    return found(lab.studies.sensitivity(study_id), f"sensitivity study {study_id}")
