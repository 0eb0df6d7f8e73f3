"""Load cell calibrations (JSON documents of :mod:`dimacq.io.loadcell_calibration`)."""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, Body, status

from dimacq.api.deps import LabDep
from dimacq.api.routers._common import found

router = APIRouter(prefix="/api/calibrations", tags=["calibrations"])


@router.post("", response_model=dict[str, Any], status_code=status.HTTP_201_CREATED)
def add_calibration(lab: LabDep, body: Annotated[dict[str, Any], Body()]) -> dict[str, Any]:
    """A calibration JSON document (schema_version 1: serial_number, date, 6×12 matrix, ...)."""
    return lab.save_calibration(body)


@router.get("", response_model=list[dict[str, Any]])
def list_calibrations(lab: LabDep) -> list[dict[str, Any]]:
    return lab.calibrations()


@router.get("/{cal_id}", response_model=dict[str, Any])
def get_calibration(cal_id: int, lab: LabDep) -> dict[str, Any]:
    return found(lab.calibration(cal_id), f"calibration {cal_id}")
