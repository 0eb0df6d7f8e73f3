"""The lab page's browser tests: ``dimacq serve`` of the simulated lab as its own process, and a
short setup to acquire on."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import httpx

from dimacq.io.setup_file import dump_setup_dict

__all__ = ["serve", "two_input_setup"]


def serve(data_dir: Path, port: int, token: str) -> subprocess.Popen[bytes]:
    """``dimacq serve`` of the simulated calibration mass on ``port`` (SQLite in ``data_dir``),
    returned once it answers."""
    env = {
        **os.environ,
        "DIMACQ_TOKEN": token,
        "DIMACQ_SCENARIO": "calibration-mass-bungee",
        "DIMACQ_DIGITIZER_URL": f"simdigitizer://recover{port}?seed=3",
        "DIMACQ_DATABASE_URL": "",
    }
    proc = subprocess.Popen(
        [sys.executable, "-m", "dimacq.cli.main", "serve", "--port", str(port)]
        + ["--data-dir", str(data_dir), "--log-level", "warning"],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        env=env,
    )
    deadline = time.monotonic() + 120  # a guard only: it returns as soon as the server answers
    while time.monotonic() < deadline:
        try:
            if httpx.get(f"http://127.0.0.1:{port}/api/status", timeout=1).status_code == 200:
                return proc
        except httpx.TransportError:
            pass
        if proc.poll() is not None:
            raise AssertionError(f"dimacq serve exited with {proc.returncode}")
        time.sleep(0.1)
    proc.kill()
    proc.wait()
    raise AssertionError("dimacq serve did not start")


def two_input_setup() -> dict[str, Any]:
    """The simulated calibration mass with two of its inputs (a short acquisition)."""
    from dimacq.simulators.lab.scenarios import build_scenario

    setup = dump_setup_dict(build_scenario("calibration-mass-bungee").model.setup)
    setup["inputs"] = setup["inputs"][:2]
    setup["name"] = "calibration mass, two inputs"
    return setup
