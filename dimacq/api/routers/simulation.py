"""Simulation only: where the virtual lab's sensors and impact points are."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter, HTTPException
from starlette.concurrency import run_in_threadpool

from dimacq.api.deps import SettingsDep

router = APIRouter(prefix="/api/simulation", tags=["simulation"])


@router.get("/article", response_model=dict[str, Any])
async def article(settings: SettingsDep) -> dict[str, Any]:
    """The simulated article's geometry (``setup`` in the setup-file format, GCS metres: response
    channels, inputs with their lines of action, load cells), the scenario's recommended band and
    the orientation jig (``jig``: indentation labels and positions in the sensor's axes, m);
    404 when no device is simulated. A client points the simulated digitizer's probe
    (``sim_probe``) at these positions; the true inertia properties are not given."""
    kinds = (settings.daq, settings.loadcell, settings.digitizer)
    if "simulated" not in kinds:
        raise HTTPException(404, "no simulated device: the article's geometry is not known")
    from dimacq.backends.simulated import article_geometry
    from dimacq.services.digitizing import load_jig

    out: dict[str, Any] = await run_in_threadpool(article_geometry, settings.scenario)
    jig = load_jig()
    out["jig"] = {
        "labels": list(jig.labels),
        "points_local_m": [[float(v) for v in p] for p in jig.points_local_m],
    }
    return out
