"""Dependency aliases used by the routers (``Annotated`` types, one place)."""

from __future__ import annotations

from typing import Annotated

from fastapi import Depends, Request

from dimacq.config import Settings
from dimacq.services.lab import Lab

__all__ = ["LabDep", "SettingsDep", "get_lab", "get_settings"]


def get_lab(request: Request) -> Lab:
    lab: Lab = request.app.state.lab
    return lab


def get_settings(request: Request) -> Settings:
    settings: Settings = request.app.state.settings
    return settings


LabDep = Annotated[Lab, Depends(get_lab)]
SettingsDep = Annotated[Settings, Depends(get_settings)]
