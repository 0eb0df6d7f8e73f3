"""Plans (``dimacq plan`` as a job): the layout of triaxes and inputs, its predicted 95 % bounds
and the Monte Carlo check; progress and the result through ``/api/jobs/{job_id}``."""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, status

from dimacq.api.deps import LabDep
from dimacq.api.routers._common import body_openapi, strict_body
from dimacq.api.schemas import JobInfo, PlanRequest

router = APIRouter(prefix="/api/plans", tags=["plans"])


@router.post(
    "",
    response_model=JobInfo,
    status_code=status.HTTP_202_ACCEPTED,
    openapi_extra=body_openapi(PlanRequest),
)
def start(lab: LabDep, body: Annotated[PlanRequest, strict_body(PlanRequest)]) -> dict[str, Any]:
    """Start a plan: returns its job (``id``; ``GET /api/jobs/{id}`` gives its progress, solves
    done of all, and once ``succeeded`` the plan in ``result``, the JSON of ``dimacq plan``)."""
    job = lab.plans.start(body)
    snap = lab.jobs.snapshot(job.id)
    assert snap is not None
    return snap
