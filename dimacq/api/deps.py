"""Dependency aliases used by the routers (``Annotated`` types, one place).

:data:`IdPath` is the one type of every stored item's id in a path (``/api/setups/{setup_id}``,
acquisitions, FRF sets, calibrations, studies, solutions): 1..:data:`~dimacq.api.schemas.MAX_ID`,
documented in the spec; a value out of that range is answered 404 like any id that names nothing
(the app's validation handler maps errors located in the path to 404), before any database call.
"""

from __future__ import annotations

from typing import Annotated

from fastapi import Depends, Path, Request

from dimacq.api.schemas import MAX_ID
from dimacq.config import Settings
from dimacq.services.lab import Lab

__all__ = ["IdPath", "LabDep", "SettingsDep", "get_lab", "get_settings"]


def get_lab(request: Request) -> Lab:
    lab: Lab = request.app.state.lab
    return lab


def get_settings(request: Request) -> Settings:
    settings: Settings = request.app.state.settings
    return settings


LabDep = Annotated[Lab, Depends(get_lab)]
SettingsDep = Annotated[Settings, Depends(get_settings)]
IdPath = Annotated[int, Path(ge=1, le=MAX_ID, description=f"the item's id, 1..{MAX_ID}")]
