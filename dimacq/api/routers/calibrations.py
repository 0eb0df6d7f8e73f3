"""Load cell calibrations (JSON documents of :mod:`dimacq.io.loadcell_calibration`)."""

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


@router.get("", response_model=list[dict[str, Any]])
def list_calibrations(lab: LabDep) -> list[dict[str, Any]]:
    return [asdict(c) for c in lab.calibrations.all()]


@router.get("/{cal_id:int}", response_model=dict[str, Any])
def get_calibration(cal_id: IdPath, lab: LabDep) -> dict[str, Any]:
    return asdict(found(lab.calibrations.get(cal_id), f"calibration {cal_id}"))
