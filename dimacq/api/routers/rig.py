"""The rig's channel map (``rig.toml``): read, check, replace (token)."""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter

from dimacq.api.deps import LabDep
from dimacq.api.public import public
from dimacq.api.routers._common import body_openapi, strict_body
from dimacq.api.schemas import RigOut, RigText

router = APIRouter(prefix="/api/rig", tags=["rig"])


@router.get("", response_model=RigOut)
def read_rig(lab: LabDep) -> dict[str, Any]:
    """The configured rig file: ``path``, ``text``, ``rig`` (parsed: ``daq``, ``hammers``,
    ``responses`` with ``sensitivity_mv_per_g``, ``load_cells``; None when invalid) and
    ``error`` (why it is invalid, "" when valid)."""
    out = lab.rig_map.read()
    return {**out, "error": public(out["error"])}


@router.post("/check", response_model=RigOut, openapi_extra=body_openapi(RigText))
def check_rig(lab: LabDep, body: Annotated[RigText, strict_body(RigText)]) -> dict[str, Any]:
    """Check a rig file's text as an acquisition would read it (422 naming the item); nothing
    is written."""
    from dimacq.services.lab.rig_map import dump_rig

    return {"rig": dump_rig(lab.rig_map.check(body.text)), "error": ""}


@router.put("", response_model=RigOut, openapi_extra=body_openapi(RigText))
def write_rig(lab: LabDep, body: Annotated[RigText, strict_body(RigText)]) -> dict[str, Any]:
    """Replace the rig file with ``text`` once it is checked (422 naming the item otherwise);
    the previous file is kept as ``<name>.previous``. The next acquisition uses it."""
    out = lab.rig_map.write(body.text)
    return {**out, "error": public(out["error"])}
