"""Devices: list, status, connect, identify."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter, Response
from starlette.concurrency import run_in_threadpool

from dimacq.api.deps import LabDep
from dimacq.api.routers._common import LIST_RESPONSES, PageDep, found, paged
from dimacq.api.schemas import DeviceOut
from dimacq.services.lab import DeviceInfo

router = APIRouter(prefix="/api/devices", tags=["devices"])


@router.get("", response_model=list[DeviceOut], responses=LIST_RESPONSES)
async def list_devices(lab: LabDep, page: PageDep, response: Response) -> list[DeviceInfo]:
    return paged(response, lab.devices.all(), page)


@router.get("/{name}", response_model=DeviceOut)
async def device_status(name: str, lab: LabDep) -> DeviceInfo:
    return found(lab.devices.get(name), f"device {name!r}")


@router.post("/{name}/connect", response_model=DeviceOut)
async def connect(name: str, lab: LabDep) -> DeviceInfo:
    found(lab.devices.get(name), f"device {name!r}")
    return await run_in_threadpool(lab.devices.connect, name)


@router.post("/{name}/identify", response_model=dict[str, Any])
async def identify(name: str, lab: LabDep) -> dict[str, Any]:
    found(lab.devices.get(name), f"device {name!r}")
    return await run_in_threadpool(lab.devices.identify, name)
