"""A 1 M-point CSV sent to ``POST /api/digitizer/points/import`` while ``GET /api/status`` is
polled: the import is refused by the row limit (``MAX_POINTS``) and the status calls keep
answering. Then a file of ``MAX_POINTS`` points (the largest accepted) is imported, parsed in a
worker thread, with the same polling.

Runs the service in this process on a loopback port (simulated devices, a fresh data folder);
writes its figures to ``bench_big_import.results.txt`` beside this script with the command, the
date, the commit and the machine's load. Targets: the refusal in under 1 s; every status call
during the imports within 100 ms.

    python tests/benchmarks/bench_big_import.py [--points 1000000]
"""

from __future__ import annotations

import argparse
import datetime as dt
import os
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import httpx

TESTS = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(TESTS))

from _api_support import TOKEN, make_settings  # noqa: E402

from dimacq.api import create_app  # noqa: E402
from dimacq.api.server import BackgroundServer  # noqa: E402
from dimacq.io.measured_points import MAX_POINTS  # noqa: E402

RESULTS = Path(__file__).with_name("bench_big_import.results.txt")


def _csv(n: int) -> bytes:
    rows = [f"P{i},{i * 1e-3:.3f},{(i % 997) * 1e-3:.3f},{(i % 31) * 1e-3:.3f}" for i in range(n)]
    return ("label,x_mm,y_mm,z_mm\n" + "\n".join(rows) + "\n").encode()


def _poll(url: str, stop: threading.Event, out: list[float]) -> None:
    with httpx.Client(base_url=url, timeout=30) as c:
        while not stop.is_set():
            t = time.perf_counter()
            r = c.get("/api/status")
            out.append(time.perf_counter() - t)
            assert r.status_code == 200
            time.sleep(0.01)


def _during(url: str, fn) -> tuple[float, list[float], httpx.Response]:  # type: ignore[no-untyped-def]
    stop = threading.Event()
    lat: list[float] = []
    poller = threading.Thread(target=_poll, args=(url, stop, lat))
    poller.start()
    time.sleep(0.2)
    t = time.perf_counter()
    try:
        r = fn()
    finally:
        took = time.perf_counter() - t
        time.sleep(0.2)
        stop.set()
        poller.join()
    return took, lat, r


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--points", type=int, default=1_000_000)
    args = ap.parse_args()
    tmp = Path(tempfile.mkdtemp(prefix="bench-big-import-"))
    lines = []
    try:
        big = _csv(args.points)
        fits = _csv(MAX_POINTS)
        srv = BackgroundServer(create_app(make_settings(tmp / "data")))
        srv.start(timeout_s=300)  # a loaded host: the start may take long
        with (
            httpx.Client(
                base_url=srv.url, headers={"Authorization": f"Bearer {TOKEN}"}, timeout=600
            ) as c,
        ):
            c.get("/api/status")
            url = "/api/digitizer/points/import?format=csv"
            took, lat, r = _during(srv.url, lambda: c.post(url, content=big))
            lines.append(
                f"{args.points} points ({len(big) / 2**20:.1f} MiB): HTTP {r.status_code} in "
                f"{took:.3f} s ({r.json()['detail'][:90]!r}); status calls during it: "
                f"{len(lat)}, max {max(lat) * 1e3:.1f} ms"
            )
            took2, lat2, r2 = _during(srv.url, lambda: c.post(url, content=fits))
            lines.append(
                f"{MAX_POINTS} points ({len(fits) / 2**20:.1f} MiB, MAX_POINTS): HTTP "
                f"{r2.status_code} in {took2:.3f} s; status calls during it: {len(lat2)}, "
                f"max {max(lat2) * 1e3:.1f} ms, median "
                f"{sorted(lat2)[len(lat2) // 2] * 1e3:.1f} ms"
            )
            t = time.perf_counter()
            page = c.get("/api/digitizer/points")
            lines.append(
                f"GET /api/digitizer/points after it: {len(page.json())} points of "
                f"{page.headers['x-total-count']} (one page) in {time.perf_counter() - t:.3f} s"
            )
            t = time.perf_counter()
            d = c.delete("/api/digitizer/points")
            lines.append(
                f"DELETE /api/digitizer/points: {d.json()} in {time.perf_counter() - t:.3f} s"
            )
        srv.stop()
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    commit = subprocess.run(
        ["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True, cwd=TESTS
    ).stdout.strip()
    head = (
        f"# {' '.join(['python', *sys.argv])}\n# {dt.datetime.now(dt.UTC).isoformat()} "
        f"commit {commit}, {os.cpu_count()} CPUs, load average "
        f"{' '.join(f'{x:.1f}' for x in os.getloadavg())}\n"
    )
    text = head + "\n".join(lines) + "\n"
    print(text)
    RESULTS.write_text(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
