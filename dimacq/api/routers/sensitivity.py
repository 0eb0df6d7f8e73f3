"""Sensitivity studies (the thesis's cube model, Monte Carlo), run as jobs."""

from __future__ import annotations

from dataclasses import asdict
from typing import Annotated, Any

from fastapi import APIRouter, status

from dimacq.api.deps import IdPath, LabDep
from dimacq.api.routers._common import body_openapi, found, strict_body
from dimacq.api.schemas import SensitivityRequest

router = APIRouter(prefix="/api/sensitivity", tags=["sensitivity"])


@router.post(
    "",
    response_model=dict[str, Any],
    status_code=status.HTTP_202_ACCEPTED,
    openapi_extra=body_openapi(SensitivityRequest),
)
def start(
    lab: LabDep, body: Annotated[SensitivityRequest, strict_body(SensitivityRequest)]
) -> dict[str, Any]:
    return asdict(lab.studies.start_sensitivity(body))


@router.get("/{study_id:int}", response_model=dict[str, Any])
def get(study_id: IdPath, lab: LabDep) -> dict[str, Any]:
    return asdict(found(lab.studies.sensitivity(study_id), f"sensitivity study {study_id}"))
