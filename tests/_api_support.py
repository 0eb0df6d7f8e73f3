"""Support for the API tests: settings on a fresh data directory and a unique simulated digitizer."""

from __future__ import annotations

import uuid
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

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


@contextmanager
def served_lab(
    data_dir: Path, database_url: str, rig_factory: object
) -> Iterator[tuple[httpx.Client, Any]]:
    """A Lab on ``rig_factory`` (no devices opened) behind a loopback server: ``(authorised
    client, lab)``; the Lab is closed afterwards."""
    from dimacq.api import create_app
    from dimacq.api.server import BackgroundServer
    from dimacq.services.lab import Lab

    settings = make_settings(data_dir, database_url=database_url)
    lab = Lab(settings, open_devices=False, rig_factory=rig_factory)  # type: ignore[arg-type]
    try:
        with (
            BackgroundServer(create_app(settings, lab=lab)) as srv,
            httpx.Client(
                base_url=srv.url, headers={"Authorization": f"Bearer {TOKEN}"}, timeout=30
            ) as c,
        ):
            yield c, lab
    finally:
        lab.close()
