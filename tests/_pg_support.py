"""A throwaway PostgreSQL server from the installed binaries (``initdb``, ``pg_ctl``).

The server lives in a fresh folder under the system temporary directory (pytest's own temporary
folders are private to the user running pytest, and PostgreSQL refuses to run as root: as root
it runs as the ``postgres`` user, which owns the folder). It listens on a free loopback port and a
Unix socket in its folder, trusts local connections, and is stopped (and its folder removed) by
:meth:`PgServer.stop`. Each test gets its own database (:meth:`PgServer.create_database`).
"""

from __future__ import annotations

import os
import shutil
import subprocess
import tempfile
import uuid
from collections.abc import Iterator
from pathlib import Path

import pytest

from dimacq.api.server import free_port

__all__ = ["BACKENDS", "SQLITE_ONLY", "PgServer", "database_url_for", "pg_binaries_missing"]

BACKENDS = ("sqlite", "postgresql")

# For an API test module whose cost is computation, not storage (plans, solves): its tests run on
# the module's server on SQLite only (``pytestmark = SQLITE_ONLY``). What they store (jobs and
# their results, setups, FRF sets, solutions) goes through the same store that test_api.py's
# round trips check on both backends; a second server on PostgreSQL would repeat the computation.
SQLITE_ONLY = pytest.mark.parametrize("api_database_url", ["sqlite"], indirect=True)

USER = "dimacq"


def pg_binaries_missing() -> str:
    """Why no server can be started here ('' when the binaries are on PATH)."""
    missing = [b for b in ("initdb", "pg_ctl", "postgres") if shutil.which(b) is None]
    if missing:
        return f"PostgreSQL binaries not on PATH: {', '.join(missing)} (install PostgreSQL 15)"
    try:
        import psycopg  # noqa: F401
    except ImportError:
        return "the PostgreSQL driver psycopg is not installed (pip install -e .)"
    return ""


def _as_server_user(cmd: list[str]) -> list[str]:
    if os.geteuid() == 0:  # PostgreSQL refuses to run as root
        return ["runuser", "-u", "postgres", "--", *cmd]
    return cmd


class PgServer:
    """One PostgreSQL cluster on a loopback port; ``url(db)`` gives SQLAlchemy URLs."""

    def __init__(self, *, durable: bool = False) -> None:
        self.durable = durable
        self.dir = Path(tempfile.mkdtemp(prefix="dimacq-pg-"))
        self.data = self.dir / "data"
        self.port = free_port()
        self.log = self.dir / "server.log"
        if os.geteuid() == 0:
            shutil.chown(self.dir, "postgres", "postgres")
        self.dir.chmod(0o700)
        self._run(["initdb", "-D", str(self.data), "-A", "trust", "-U", USER, "-E", "UTF8"])
        self.start()

    def _run(self, cmd: list[str]) -> None:
        out = subprocess.run(_as_server_user(cmd), capture_output=True, text=True, check=False)
        if out.returncode != 0:
            raise RuntimeError(f"{' '.join(cmd)} failed: {out.stderr.strip() or out.stdout}")

    def start(self) -> None:
        opts = (
            f"-p {self.port} -k {self.dir} -c listen_addresses=127.0.0.1 -c max_connections=200"
            + ("" if self.durable else " -c fsync=off -c synchronous_commit=off")
        )
        self._run(["pg_ctl", "-D", str(self.data), "-l", str(self.log), "-o", opts, "-w", "start"])

    def stop(self, mode: str = "fast") -> None:
        self._run(["pg_ctl", "-D", str(self.data), "-m", mode, "-w", "stop"])

    def url(self, db: str = "postgres") -> str:
        return f"postgresql+psycopg://{USER}@127.0.0.1:{self.port}/{db}"

    def _admin(self, sql: str) -> None:
        import psycopg

        with psycopg.connect(
            f"host=127.0.0.1 port={self.port} user={USER} dbname=postgres", autocommit=True
        ) as conn:
            conn.execute(sql)  # type: ignore[arg-type]

    def create_database(self) -> str:
        """A new empty database; returns its SQLAlchemy URL."""
        name = f"t_{uuid.uuid4().hex[:12]}"
        self._admin(f'CREATE DATABASE "{name}"')
        return self.url(name)

    def drop_database(self, url: str) -> None:
        name = url.rsplit("/", 1)[1]
        self._admin(f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)')

    def close(self) -> None:
        try:
            self.stop("immediate")
        finally:
            shutil.rmtree(self.dir, ignore_errors=True)


def database_url_for(request: pytest.FixtureRequest, backend: str) -> Iterator[str]:
    """'' (SQLite in the data folder) or a fresh PostgreSQL database, dropped afterwards."""
    if backend == "sqlite":
        yield ""
        return
    srv = request.getfixturevalue("pg_server")
    url = srv.create_database()
    try:
        yield url
    finally:
        srv.drop_database(url)
