"""Kill ``dimacq serve`` with SIGKILL mid-acquisition (the simulated lab's impact test of the
calibration mass), restart it: no completed average and no digitized point is lost; the
interrupted acquisition and job say so. On SQLite and on PostgreSQL."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import httpx

from dimacq.api.server import free_port
from dimacq.io.setup_file import dump_setup_dict
from dimacq.persistence import ArrayStore
from dimacq.simulators.lab.scenarios import build_scenario

TOKEN = "crash-token"


def _start(data_dir: Path, port: int, database_url: str) -> subprocess.Popen[bytes]:
    env = {
        **os.environ,
        "DIMACQ_DATABASE_URL": database_url,
        "DIMACQ_TOKEN": TOKEN,
        "DIMACQ_DIGITIZER_URL": f"simdigitizer://crash{port}?seed=5",
        "DIMACQ_SCENARIO": "calibration-mass-bungee",
    }
    proc = subprocess.Popen(
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
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
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
            raise AssertionError(
                f"server died: {proc.stderr.read().decode() if proc.stderr else ''}"
            )
        time.sleep(0.1)
    proc.kill()
    raise AssertionError("server did not start")


def test_sigkill_mid_acquisition_loses_nothing_completed(tmp_path: Path, database_url: str) -> None:
    port = free_port()
    proc = _start(tmp_path, port, database_url)
    try:
        with httpx.Client(
            base_url=f"http://127.0.0.1:{port}",
            headers={"Authorization": f"Bearer {TOKEN}"},
            timeout=30,
        ) as c:
            for i in range(6):
                r = c.post(
                    "/api/digitizer/points",
                    json={"label": f"P{i}", "sim_probe": {"tip_m": [0.1 * i - 0.3, 0.05, 1.0]}},
                )
                assert r.status_code == 201, r.text
            setup = build_scenario("calibration-mass-bungee").model.setup
            sid = c.post("/api/setups", json=dump_setup_dict(setup)).json()["id"]
            acq = c.post("/api/acquisitions", json={"setup_id": sid}).json()
            deadline = time.monotonic() + 30
            while True:
                a = c.get(f"/api/acquisitions/{acq['id']}").json()
                if a["averages_accepted"] >= 4 or time.monotonic() > deadline:
                    break
                time.sleep(0.05)
            assert a["state"] == "running" and a["averages_accepted"] >= 4
            seen = {av["path"] for av in a["averages"]}
        os.kill(proc.pid, signal.SIGKILL)  # mid-acquisition, no shutdown of any kind
        proc.wait(10)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(10)
        if proc.stderr:
            proc.stderr.close()

    proc = _start(tmp_path, port, database_url)
    try:
        with httpx.Client(base_url=f"http://127.0.0.1:{port}", timeout=30) as c:
            points = c.get("/api/digitizer/points").json()
            assert [p["label"] for p in points] == [f"P{i}" for i in range(6)]
            a = c.get(f"/api/acquisitions/{acq['id']}").json()
            assert a["state"] == "interrupted"
            after = {av["path"] for av in a["averages"]}
            assert seen <= after  # every average completed before the kill is still there
            store = ArrayStore(tmp_path / "arrays")
            for rel in after:
                arrays, attrs = store.read(rel)
                assert arrays["outputs"].shape[0] == 24 + 6 and attrs["acquisition_id"] == acq["id"]
            assert c.get(f"/api/jobs/{acq['job_id']}").json()["state"] == "interrupted"
            # the service still refuses anonymous state changes after the restart
            assert c.post(f"/api/acquisitions/{acq['id']}/stop").status_code == 401
    finally:
        proc.send_signal(signal.SIGTERM)
        proc.wait(20)
        if proc.stderr:
            proc.stderr.close()
