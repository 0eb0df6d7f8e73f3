"""A live API server (uvicorn on a loopback port, in-process) per test module."""

from __future__ import annotations

import shutil
from collections.abc import Iterator

import httpx
import pytest
from _api_support import TOKEN, Api, make_settings
from _pg_support import BACKENDS, database_url_for

from dimacq.api import create_app
from dimacq.api.server import BackgroundServer
from dimacq.config import default_config_file


@pytest.fixture(scope="module", params=BACKENDS)
def api_database_url(request: pytest.FixtureRequest) -> Iterator[str]:
    """The module's database: SQLite, then a fresh PostgreSQL database."""
    yield from database_url_for(request, request.param)


@pytest.fixture(scope="module")
def api(tmp_path_factory: pytest.TempPathFactory, api_database_url: str) -> Iterator[Api]:
    # the rig file is a copy: PUT /api/rig (schemathesis sends it too) never touches config/
    rig_dir = tmp_path_factory.mktemp("rig")
    shutil.copy(default_config_file().parent / "rig.toml", rig_dir / "rig.toml")
    shutil.copytree(default_config_file().parent / "calibrations", rig_dir / "calibrations")
    settings = make_settings(
        tmp_path_factory.mktemp("api"),
        database_url=api_database_url,
        rig_file=str(rig_dir / "rig.toml"),
    )
    app = create_app(settings)
    with BackgroundServer(app) as srv:
        auth = {"Authorization": f"Bearer {TOKEN}"}
        with (
            httpx.Client(base_url=srv.url, headers=auth, timeout=30) as c,
            httpx.Client(base_url=srv.url, timeout=30) as anon,
        ):
            # spawn the server's worker threads before any per-test thread accounting
            for _ in range(8):
                c.get("/api/setups")
            yield Api(srv.url, TOKEN, c, anon, app, settings)


@pytest.fixture
def thread_leak_allowed() -> tuple[str, ...]:
    """The suite-wide leak check (``tests/conftest.py``) in this folder: the module's server keeps
    AnyIO worker threads alive between requests (they end with the server)."""
    return ("AnyIO worker thread",)
