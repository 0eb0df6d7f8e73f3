"""Simulation only: where the virtual lab's sensors and impact points are, and (for showing
beside an answer) the simulated article's true properties."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter, HTTPException
from starlette.concurrency import run_in_threadpool

from dimacq.api.deps import LabDep
from dimacq.api.schemas import ArticleOut

router = APIRouter(prefix="/api/simulation", tags=["simulation"])


@router.get("/article", response_model=ArticleOut)
async def article(lab: LabDep) -> dict[str, Any]:
    """The simulated article's geometry (``setup`` in the setup-file format, GCS metres: response
    channels, inputs with their lines of action, load cells), the scenario's recommended band and
    the orientation jig (``jig``: indentation labels and positions in the sensor's axes, m);
    404 when no device is simulated. A client points the simulated digitizer's probe
    (``sim_probe``) at these positions; the true inertia properties are not given."""
    out = await run_in_threadpool(lab.devices.simulated_article)
    if out is None:
        raise HTTPException(404, "no simulated device: the article's geometry is not known")
    return out


@router.get("/truth", response_model=dict[str, Any])
async def truth(lab: LabDep) -> dict[str, Any]:
    """The simulated article's true properties (mass, CG, inertia about the scenario's reference
    point, its modes and suspension frequencies): the simulator's, for a demonstration to show
    beside a solution; the solve never reads them. 404 when no device is simulated."""
    out = await run_in_threadpool(lab.devices.simulated_truth)
    if out is None:
        raise HTTPException(404, "no simulated device: there is no simulator's truth")
    return out
