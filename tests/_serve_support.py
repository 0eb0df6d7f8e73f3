"""``dimacq serve`` as its own process for the on-demand scripts (loopback, token, stand)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import httpx

__all__ = ["Service"]


class Service:
    """A ``dimacq serve`` process on ``port`` with its own data folder; ``client`` is an
    authorised httpx client to it. Stop with :meth:`stop` (SIGTERM, then SIGKILL)."""

    def __init__(
        self, data_dir: Path, port: int, token: str, env: dict[str, str] | None = None
    ) -> None:
        self.url = f"http://127.0.0.1:{port}"
        self.log = open(data_dir.parent / f"serve-{port}.log", "wb")
        self.proc = subprocess.Popen(
            [
                sys.executable,
                "-m",
                "dimacq.cli.main",
                "serve",
                "--port",
                str(port),
                "--data-dir",
                str(data_dir),
                "--log-level",
                "warning",
            ],
            stdout=self.log,
            stderr=subprocess.STDOUT,
            env={**os.environ, "DIMACQ_TOKEN": token, "DIMACQ_PORT": str(port), **(env or {})},
        )
        self.client = httpx.Client(
            base_url=self.url, headers={"Authorization": f"Bearer {token}"}, timeout=60
        )
        deadline = time.monotonic() + 60
        while True:
            try:
                if self.client.get("/api/status").status_code == 200:
                    break
            except httpx.TransportError:
                pass
            if self.proc.poll() is not None or time.monotonic() > deadline:
                self.stop()
                log = Path(self.log.name).read_text(errors="replace")
                raise RuntimeError(f"dimacq serve on port {port} did not start:\n{log}")
            time.sleep(0.1)

    def stop(self) -> None:
        self.client.close()
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(30)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(10)
        self.log.close()
