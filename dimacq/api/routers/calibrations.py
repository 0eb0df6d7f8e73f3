"""Load cell calibrations (JSON documents of :mod:`dimacq.io.loadcell_calibration`) and
calibration runs: ``POST /api/calibrations/runs`` starts a job, static or inertial, with the
circular check on request (follow it at ``/api/jobs/{job_id}``); on the real rig a static run
waits at every load case:
``GET /api/calibrations/runs/{job_id}/prompt`` tells which, ``POST .../confirm`` with
``{"case": N}`` says it is in place."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter, HTTPException, Request, Response, status
from starlette.concurrency import run_in_threadpool

from dimacq.api.deps import IdPath, JobIdPath, LabDep
from dimacq.api.routers._common import LIST_RESPONSES, PageDep, found, json_object, paged
from dimacq.api.schemas import CalibrationOut
from dimacq.services.lab.calibrations import StoredCalibration

router = APIRouter(prefix="/api/calibrations", tags=["calibrations"])


@router.post(
    "",
    response_model=CalibrationOut,
    status_code=status.HTTP_201_CREATED,
    openapi_extra={
        "requestBody": {
            "required": True,
            "content": {"application/json": {"schema": {"type": "object"}}},
        }
    },
)
async def add_calibration(request: Request, lab: LabDep) -> StoredCalibration:
    """A calibration JSON document (schema_version 1: serial_number, date, 6×12 matrix, ...);
    returns it stored, with its ``id``."""
    raw = await request.body()
    body = json_object(raw or b"null", "the calibration JSON document")
    return await run_in_threadpool(lab.calibrations.save, body)


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
                                    {"type": "integer", "minimum": 1, "maximum": 100},
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
    body = json_object(await request.body(), '{"method": "static"}')
    return await run_in_threadpool(lab.calibrations.runs.start, body)


@router.get("/runs/{job_id}/prompt", response_model=dict[str, Any])
def calibration_prompt(job_id: JobIdPath, lab: LabDep) -> dict[str, Any]:
    """What the run waits for from the operator: a load case to put in place (``kind``
    ``load_case``: ``case``, ``of``, ``message``; confirm it) or a strike (``kind`` ``strike``:
    ``stage``, ``input_index`` of ``n_inputs``, ``node``, ``direction`` (``+X``),
    ``direction_gcs``, ``average`` of ``averages``, ``message``: "strike point 101 along +X",
    as an acquisition asks); ``{"waiting": false}`` when none."""
    found(lab.jobs.snapshot(job_id), f"job {job_id}")
    return lab.calibrations.runs.prompt(job_id)


@router.post("/runs/{job_id}/confirm", response_model=dict[str, Any])
async def confirm_load_case(job_id: JobIdPath, request: Request, lab: LabDep) -> dict[str, Any]:
    """The operator has put load case ``{"case": N}`` in place."""
    found(lab.jobs.snapshot(job_id), f"job {job_id}")
    body = json_object(await request.body() or b"null", '{"case": N}')
    case = body.get("case")
    if not isinstance(case, int) or isinstance(case, bool):
        raise HTTPException(422, 'body.case: give the load case number, {"case": N}')
    return lab.calibrations.runs.confirm(job_id, case)


@router.get("", response_model=list[CalibrationOut], responses=LIST_RESPONSES)
def list_calibrations(lab: LabDep, page: PageDep, response: Response) -> list[StoredCalibration]:
    return paged(response, lab.calibrations.all(), page)


@router.get("/{cal_id:id}", response_model=CalibrationOut)
def get_calibration(cal_id: IdPath, lab: LabDep) -> StoredCalibration:
    return found(lab.calibrations.get(cal_id), f"calibration {cal_id}")
