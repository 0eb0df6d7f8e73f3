"""Devices: list, status, connect, identify."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter
from starlette.concurrency import run_in_threadpool

from dimacq.api.deps import LabDep
from dimacq.api.routers._common import found
from dimacq.api.schemas import DeviceOut

router = APIRouter(prefix="/api/devices", tags=["devices"])


@router.get("", response_model=list[DeviceOut])
async def list_devices(lab: LabDep) -> list[dict[str, Any]]:
    return [d.as_dict() for d in lab.devices.values()]


@router.get("/{name}", response_model=DeviceOut)
async def device_status(name: str, lab: LabDep) -> dict[str, Any]:
    return found(lab.device(name), f"device {name!r}").as_dict()


@router.post("/{name}/connect", response_model=DeviceOut)
async def connect(name: str, lab: LabDep) -> dict[str, Any]:
    found(lab.device(name), f"device {name!r}")
    info = await run_in_threadpool(lab.connect, name)
    return info.as_dict()


@router.post("/{name}/identify", response_model=dict[str, Any])
async def identify(name: str, lab: LabDep) -> dict[str, Any]:
    found(lab.device(name), f"device {name!r}")
    return await run_in_threadpool(lab.identify, name)
