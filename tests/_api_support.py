"""Support for the API tests: settings on a fresh data directory and a unique simulated digitizer."""

from __future__ import annotations

import uuid
from dataclasses import dataclass
from pathlib import Path

import httpx

from dimacq.config import Settings, load_settings

TOKEN = "test-token-123"


@dataclass
class Api:
    url: str
    token: str
    client: httpx.Client  # authorised
    anon: httpx.Client
    app: object
    settings: Settings

    @property
    def lab(self):  # the in-process Lab behind the server
        return self.app.state.lab  # type: ignore[attr-defined]


def make_settings(data_dir: Path, **kw: object) -> Settings:
    name = f"t{uuid.uuid4().hex[:8]}"
    return load_settings(
        data_dir=data_dir, token=TOKEN, digitizer_url=f"simdigitizer://{name}?seed=3", **kw
    )
