"""Service status (cheap, in memory: the call clients poll)."""

from __future__ import annotations

import json
from typing import Any

from fastapi import APIRouter, Response

from dimacq.api.deps import LabDep
from dimacq.api.routers._common import LIST_RESPONSES, PageDep, paged
from dimacq.api.schemas import StandOut, StatusOut

router = APIRouter(prefix="/api", tags=["status"])


@router.get("/status", response_model=StatusOut)
async def get_status(lab: LabDep) -> Response:
    """Service status from memory only (no database, no device I/O): the call to poll."""
    # serialised directly: this is the hot path clients poll during acquisitions
    return Response(json.dumps(lab.status().to_json()).encode(), media_type="application/json")


@router.get("/stands", response_model=list[StandOut], responses=LIST_RESPONSES)
def get_stands(lab: LabDep, page: PageDep, response: Response) -> list[dict[str, Any]]:
    """The test stands sharing this database: name, host, API address, last heartbeat."""
    return paged(response, lab.stands(), page)
