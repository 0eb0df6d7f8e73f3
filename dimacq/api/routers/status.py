"""Service status (cheap, in memory: the call clients poll)."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter

from dimacq.api.deps import LabDep
from dimacq.api.schemas import StatusOut

router = APIRouter(prefix="/api", tags=["status"])


@router.get("/status", response_model=StatusOut)
async def get_status(lab: LabDep) -> dict[str, Any]:
    return lab.status()
