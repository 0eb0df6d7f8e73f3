"""``GET /api/status`` latency while ``POST /api/digitizer/points/import`` takes big CSV files.

Starts ``dimacq serve`` as its own process on a loopback port (simulated devices, a fresh data
folder in a temporary directory), then, while a thread polls ``/api/status`` every 20 ms:

1. posts a CSV of ``--points`` points (1,000,000 by default, about 27 MiB) with its
   ``Content-Length``: refused by the size limit (``MAX_POINTS_BYTES``) before it is read;
2. posts the same file chunked (no ``Content-Length``): refused once the limit is passed;
3. posts 300,000 short rows (within the size limit): refused by the row limit (``MAX_POINTS``);
4. posts a CSV of ``MAX_POINTS`` points (the largest accepted): parsed and stored in a worker;
5. pages through ``GET /api/digitizer/points`` and deletes the points in bulk.

For each step it reports the HTTP status and the time taken, and the number, maximum, 99th
percentile and median of the status calls' latencies. Targets: a refusal in under 1 s, every
status call within 100 ms. The figures go to ``import_status_results.md`` beside this script
(``--results`` elsewhere) with the command, the date, the commit and the machine's load.

    python tests/benchmarks/import_status.py [--points 1000000] [--no-write] [--results PATH]
"""

from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import httpx

TESTS = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(TESTS))

from _results import Results, add_results_argument  # noqa: E402
from _serve_support import Service  # noqa: E402

from dimacq.api.server import free_port  # noqa: E402
from dimacq.io.measured_points import MAX_POINTS  # noqa: E402

TOKEN = "import-status-token"
POLL_S = 0.020


def _csv(n: int) -> bytes:
    """``n`` labelled points in millimetres, one per row."""
    rows = [f"P{i},{i * 1e-3:.3f},{(i % 997) * 1e-3:.3f},{(i % 31) * 1e-3:.3f}" for i in range(n)]
    return ("label,x_mm,y_mm,z_mm\n" + "\n".join(rows) + "\n").encode()


def _chunks(data: bytes, size: int = 256 * 1024) -> Iterator[bytes]:
    for i in range(0, len(data), size):
        yield data[i : i + size]


def _poll(url: str, stop: threading.Event, out: list[float]) -> None:
    """``GET /api/status`` every ``POLL_S`` until ``stop``; each call's latency in seconds."""
    with httpx.Client(base_url=url, timeout=30) as c:
        while not stop.is_set():
            t = time.perf_counter()
            r = c.get("/api/status")
            out.append(time.perf_counter() - t)
            if r.status_code != 200:
                raise RuntimeError(f"/api/status answered {r.status_code}")
            time.sleep(POLL_S)


def _during(
    url: str, fn: Callable[[], httpx.Response]
) -> tuple[float, list[float], httpx.Response]:
    """Run ``fn`` while ``/api/status`` is polled (from 0.2 s before to 0.2 s after)."""
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


def _idle(c: httpx.Client) -> httpx.Response:
    """The noise floor: 2 s with no request but the polling, then one status call."""
    time.sleep(2.0)
    return c.get("/api/status")


def _stats(lat: list[float]) -> str:
    s = sorted(lat)
    p99 = s[min(len(s) - 1, int(0.99 * len(s)))]
    return (
        f"{len(s)} | {s[-1] * 1e3:.1f} | {p99 * 1e3:.1f} | {s[len(s) // 2] * 1e3:.1f}"
        if s
        else "0 | – | – | –"
    )


def _row(step: str, r: httpx.Response, took: float, lat: list[float]) -> str:
    detail = ""
    if r.status_code >= 400:
        detail = f" ({str(r.json().get('detail'))[:70]})"
    return f"| {step} | {r.status_code}{detail} | {took:.3f} | {_stats(lat)} |"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--points", type=int, default=1_000_000)
    ap.add_argument("--no-write", action="store_true", help="print only; keep the results file")
    add_results_argument(ap, __file__)
    args = ap.parse_args()
    res = Results(__file__, "/api/status latency during big CSV imports", args.results)
    tmp = Path(tempfile.mkdtemp(prefix="import-status-"))
    rows: list[str] = []
    worst: list[float] = []
    try:
        big = _csv(args.points)
        fits = _csv(MAX_POINTS)
        many = b"label,x_mm,y_mm,z_mm\n" + b"p,0,0,0\n" * 300_000
        svc = Service(tmp / "data", free_port(), TOKEN)
        try:
            c = svc.client
            c.timeout = httpx.Timeout(900)
            url = "/api/digitizer/points/import?format=csv"
            steps: list[tuple[str, Callable[[], httpx.Response]]] = [
                ("idle, for comparison (2 s of nothing)", lambda: _idle(c)),
                (
                    f"{args.points:,} points ({len(big) / 2**20:.1f} MiB), Content-Length",
                    lambda: c.post(url, content=big),
                ),
                (
                    f"{args.points:,} points ({len(big) / 2**20:.1f} MiB), chunked",
                    lambda: c.post(url, content=_chunks(big)),
                ),
                (
                    f"300,000 short rows ({len(many) / 2**20:.1f} MiB)",
                    lambda: c.post(url, content=many),
                ),
                (
                    f"{MAX_POINTS:,} points ({len(fits) / 2**20:.2f} MiB, MAX_POINTS)",
                    lambda: c.post(url, content=fits),
                ),
                (
                    f"{MAX_POINTS:,} points again (a second patch)",
                    lambda: c.post(url, content=fits),
                ),
                ("GET /api/digitizer/points (first page)", lambda: c.get("/api/digitizer/points")),
                ("DELETE /api/digitizer/points (bulk)", lambda: c.delete("/api/digitizer/points")),
            ]
            for step, fn in steps:
                took, lat, r = _during(svc.url, fn)
                rows.append(_row(step, r, took, lat))
                worst.extend(lat)
        finally:
            svc.stop()
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    text = "\n".join(
        [
            f"`dimacq serve` in its own process; `/api/status` polled every {POLL_S * 1e3:.0f} ms "
            "from 0.2 s before each request to 0.2 s after it. Targets: a refusal in under 1 s, "
            "every status call within 100 ms.",
            "",
            "| request | HTTP | took (s) | status calls | max (ms) | p99 (ms) | median (ms) |",
            "|---|---|---|---|---|---|---|",
            *rows,
            "",
            "All status calls (count, max, p99, median in ms): "
            + _stats(worst).replace(" | ", ", ")
            + ".",
        ]
    )
    res.add(text)
    print("\n\n".join([res.header(), *res.sections]))
    if not args.no_write:
        res.write()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
