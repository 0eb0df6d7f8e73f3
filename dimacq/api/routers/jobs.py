"""Jobs: list, status, cancel, and live status as server-sent events."""

from __future__ import annotations

import asyncio
import json
from collections.abc import AsyncIterator
from typing import Annotated, Any

from fastapi import APIRouter, Query, Response
from fastapi.responses import StreamingResponse

from dimacq.api.deps import JobIdPath, LabDep
from dimacq.api.public import public_value
from dimacq.api.routers._common import LIST_RESPONSES, PageDep, found, paged
from dimacq.api.schemas import JobInfo
from dimacq.services.lab.jobs import FINAL_STATES

router = APIRouter(prefix="/api/jobs", tags=["jobs"])


@router.get("", response_model=list[JobInfo], responses=LIST_RESPONSES)
async def list_jobs(lab: LabDep, page: PageDep, response: Response) -> list[dict[str, Any]]:
    return paged(response, [_public_job(j) for j in lab.jobs.list_jobs()], page)


def _public_job(snap: dict[str, Any]) -> dict[str, Any]:
    """The job without server paths in its message, error or result."""
    return {**snap, **{k: public_value(snap.get(k)) for k in ("message", "error", "result")}}


@router.get("/{job_id}", response_model=JobInfo)
async def get_job(job_id: JobIdPath, lab: LabDep) -> dict[str, Any]:
    return _public_job(found(lab.jobs.snapshot(job_id), f"job {job_id!r}"))


@router.post("/{job_id}/cancel", response_model=JobInfo)
async def cancel_job(job_id: JobIdPath, lab: LabDep) -> dict[str, Any]:
    found(lab.jobs.snapshot(job_id), f"job {job_id!r}")
    return _public_job(lab.jobs.cancel(job_id))


@router.get(
    "/{job_id}/events",
    response_class=StreamingResponse,
    responses={
        200: {
            "content": {"text/event-stream": {}},
            "description": "one 'status' event per change, then 'end'",
        }
    },
)
async def job_events(
    job_id: JobIdPath,
    lab: LabDep,
    poll_s: Annotated[
        float,
        Query(
            ge=0,
            le=3600,
            allow_inf_nan=False,
            description="how often the job is looked at, s (used within 0.02..2)",
        ),
    ] = 0.1,
) -> StreamingResponse:
    """Server-sent events: ``event: status`` with the job's JSON on every change; ``event: end``
    when it reaches a final state."""
    found(lab.jobs.snapshot(job_id), f"job {job_id!r}")
    poll = min(max(poll_s, 0.02), 2.0)

    async def stream() -> AsyncIterator[str]:
        seen = -1
        idle = 0.0
        while True:
            snap = lab.jobs.snapshot(job_id)
            if snap is None:
                return
            if snap["version"] != seen:
                seen = snap["version"]
                idle = 0.0
                yield f"event: status\ndata: {json.dumps(_public_job(snap))}\n\n"
            if snap["state"] in FINAL_STATES:
                yield f"event: end\ndata: {json.dumps(_public_job(snap))}\n\n"
                return
            await asyncio.sleep(poll)
            idle += poll
            if idle >= 15.0:
                idle = 0.0
                yield ": keep-alive\n\n"

    return StreamingResponse(
        stream(), media_type="text/event-stream", headers={"Cache-Control": "no-cache"}
    )
