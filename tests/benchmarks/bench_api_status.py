"""Status-call latency with 50 concurrent clients while an acquisition runs (loopback).

Starts ``dimacq serve`` as its own process on the simulated lab (scenario
calibration-mass-bungee: USB DAQ and CAN FD load cell simulators fed by the virtual lab), starts
the scenario's impact acquisition (24 inputs x 5 averages), then 50 concurrent clients each call
``GET /api/status`` repeatedly over keep-alive connections; prints p50/p90/p99/max latency and
checks that the acquisition was running for the whole measurement. Target: p99 < 50 ms.

    python tests/benchmarks/bench_api_status.py [--clients 50] [--calls 40]
"""

from __future__ import annotations

import argparse
import asyncio
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import httpx
import numpy as np

TESTS = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(TESTS))

from dimacq.api.server import free_port  # noqa: E402
from dimacq.io.setup_file import dump_setup_dict  # noqa: E402
from dimacq.simulators.lab.scenarios import build_scenario  # noqa: E402

TOKEN = "bench-token"


async def _client(host: str, port: int, calls: int, out: list[float]) -> None:
    """One keep-alive HTTP/1.1 connection; raw asyncio streams keep the client's own CPU cost
    (which would otherwise be measured as latency) far below the server's."""
    reader, writer = await asyncio.open_connection(host, port)
    req = f"GET /api/status HTTP/1.1\r\nHost: {host}:{port}\r\n\r\n".encode()
    try:
        for _ in range(calls):
            t = time.perf_counter()
            writer.write(req)
            head = await reader.readuntil(b"\r\n\r\n")
            length = 0
            for line in head.split(b"\r\n"):
                if line.lower().startswith(b"content-length:"):
                    length = int(line.split(b":", 1)[1])
            await reader.readexactly(length)
            out.append(time.perf_counter() - t)
            assert head.startswith(b"HTTP/1.1 200"), head[:40]
    finally:
        writer.close()
        await writer.wait_closed()


async def _load(host: str, port: int, clients: int, calls: int) -> list[float]:
    lat: list[float] = []
    await asyncio.gather(*(_client(host, port, calls, lat) for _ in range(clients)))
    return lat


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--clients", type=int, default=50)
    ap.add_argument("--calls", type=int, default=200, help="status calls per client")
    args = ap.parse_args()
    port = free_port()
    url = f"http://127.0.0.1:{port}"
    with tempfile.TemporaryDirectory() as tmp:
        env = {
            **os.environ,
            "DIMACQ_TOKEN": TOKEN,
            "DIMACQ_DIGITIZER_URL": f"simdigitizer://bench{os.getpid()}",
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
                tmp,
                "--log-level",
                "warning",
            ],
            stdout=subprocess.DEVNULL,
            env=env,
        )
        try:
            deadline = time.monotonic() + 30
            while True:
                try:
                    httpx.get(url + "/api/status", timeout=1)
                    break
                except httpx.TransportError:
                    if time.monotonic() > deadline:
                        raise SystemExit("server did not start") from None
                    time.sleep(0.1)
            with httpx.Client(
                base_url=url, headers={"Authorization": f"Bearer {TOKEN}"}, timeout=30
            ) as c:
                setup = build_scenario("calibration-mass-bungee").model.setup
                sid = c.post("/api/setups", json=dump_setup_dict(setup)).json()["id"]
                acq = c.post("/api/acquisitions", json={"setup_id": sid}).json()
                time.sleep(1.0)
                before = c.get(f"/api/acquisitions/{acq['id']}").json()
                # warm-up
                asyncio.run(_load("127.0.0.1", port, args.clients, 2))
                t0 = time.perf_counter()
                lat = np.array(asyncio.run(_load("127.0.0.1", port, args.clients, args.calls)))
                wall = time.perf_counter() - t0
                after = c.get(f"/api/acquisitions/{acq['id']}").json()
                c.post(f"/api/acquisitions/{acq['id']}/stop")
        finally:
            proc.send_signal(signal.SIGTERM)
            proc.wait(30)
    running = before["state"] == "running" and after["state"] == "running"
    n_avg = (
        after["averages_accepted"]
        + after["averages_rejected"]
        - (before["averages_accepted"] + before["averages_rejected"])
    )
    p50, p90, p99 = (1e3 * np.percentile(lat, q) for q in (50, 90, 99))
    print(
        f"{args.clients} clients x {args.calls} GET /api/status = {lat.size} calls in {wall:.2f} s "
        f"({lat.size / wall:.0f} calls/s)"
    )
    print(f"latency ms: p50 {p50:.2f}  p90 {p90:.2f}  p99 {p99:.2f}  max {1e3 * lat.max():.2f}")
    print(f"acquisition running throughout: {running}; averages completed during the load: {n_avg}")
    ok = p99 < 50.0 and running and n_avg > 0
    print("PASS" if ok else "FAIL", "(target p99 < 50 ms while an acquisition runs)")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
