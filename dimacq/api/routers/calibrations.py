"""Load cell calibrations (JSON documents of :mod:`dimacq.io.loadcell_calibration`) and
calibration runs: ``POST /api/calibrations/runs`` starts a job, static or inertial, with the
circular check on request (follow it at ``/api/jobs/{job_id}``); on the real rig a static run
waits at every load case:
``GET /api/calibrations/runs/{job_id}/prompt`` tells which, ``POST .../confirm`` with
``{"case": N}`` says it is in place."""

from __future__ import annotations

import json
from dataclasses import asdict
from typing import Any

from fastapi import APIRouter, Request, status
from starlette.concurrency import run_in_threadpool

from dimacq.api.deps import IdPath, LabDep
from dimacq.api.routers._common import found
from dimacq.errors import DataError

router = APIRouter(prefix="/api/calibrations", tags=["calibrations"])


@router.post(
    "",
    response_model=dict[str, Any],
    status_code=status.HTTP_201_CREATED,
    openapi_extra={
        "requestBody": {
            "required": True,
            "content": {"application/json": {"schema": {"type": "object"}}},
        }
    },
)
async def add_calibration(request: Request, lab: LabDep) -> dict[str, Any]:
    """A calibration JSON document (schema_version 1: serial_number, date, 6×12 matrix, ...)."""
    try:
        body = json.loads(await request.body())
    except (json.JSONDecodeError, UnicodeDecodeError) as err:
        raise DataError(
            f"body: not valid JSON ({err}); send the calibration JSON document"
        ) from err
    if not isinstance(body, dict):
        raise DataError("body: send a JSON object (the calibration document)")
    return asdict(await run_in_threadpool(lab.calibrations.save, body))


@router.post(
    "/runs",
    response_model=dict[str, Any],
    status_code=status.HTTP_202_ACCEPTED,
    openapi_extra={
        "requestBody": {
            "required": False,
            "content": {
                "application/json": {
                    "schema": {
                        "type": "object",
                        "properties": {
                            "method": {"enum": ["static", "inertial"]},
                            "node": {"anyOf": [{"type": "integer"}, {"type": "null"}]},
                            "download": {"type": "boolean"},
                            "plan": {"enum": ["standard", "minimal"]},
                            "circular_check": {"type": "boolean"},
                            "averages_per_input": {
                                "anyOf": [
                                    {"type": "integer", "minimum": 1, "maximum": 1000},
                                    {"type": "null"},
                                ]
                            },
                        },
                        "additionalProperties": False,
                    }
                }
            },
        }
    },
)
async def start_calibration_run(request: Request, lab: LabDep) -> dict[str, Any]:
    """Start a load cell calibration job (``method`` static | inertial, ``node``,
    ``download``, ``plan``, ``circular_check``, ``averages_per_input``):
    ``{"job_id", "method", "simulated"}``. Progress at ``/api/jobs/{job_id}`` (a real inertial
    run asks there for every strike); the result has the contract keys of ``dimacq loadcell
    calibrate`` and the record id."""
    raw = await request.body()
    try:
        body = json.loads(raw) if raw.strip() else {}
    except (json.JSONDecodeError, UnicodeDecodeError) as err:
        raise DataError(f'body: not valid JSON ({err}); send {{"method": "static"}}') from err
    if not isinstance(body, dict):
        raise DataError('body: send a JSON object, e.g. {"method": "static"}')
    return await run_in_threadpool(lab.calibrations.runs.start, body)


@router.get("/runs/{job_id}/prompt", response_model=dict[str, Any])
def calibration_prompt(job_id: str, lab: LabDep) -> dict[str, Any]:
    """The load case the run waits for: ``{"waiting", "case", "of", "message"}``."""
    found(lab.jobs.snapshot(job_id), f"job {job_id}")
    return lab.calibrations.runs.prompt(job_id)


@router.post("/runs/{job_id}/confirm", response_model=dict[str, Any])
async def confirm_load_case(job_id: str, request: Request, lab: LabDep) -> dict[str, Any]:
    """The operator has put load case ``{"case": N}`` in place."""
    found(lab.jobs.snapshot(job_id), f"job {job_id}")
    try:
        body = json.loads(await request.body())
    except (json.JSONDecodeError, UnicodeDecodeError) as err:
        raise DataError(f'body: not valid JSON ({err}); send {{"case": N}}') from err
    case = body.get("case") if isinstance(body, dict) else None
    if not isinstance(case, int) or isinstance(case, bool):
        raise DataError('body: give the load case number, {"case": N}')
    return lab.calibrations.runs.confirm(job_id, case)


@router.get("", response_model=list[dict[str, Any]])
def list_calibrations(lab: LabDep) -> list[dict[str, Any]]:
    return [asdict(c) for c in lab.calibrations.all()]


@router.get("/{cal_id:int}", response_model=dict[str, Any])
def get_calibration(cal_id: IdPath, lab: LabDep) -> dict[str, Any]:
    return asdict(found(lab.calibrations.get(cal_id), f"calibration {cal_id}"))
