"""Throughput of listing and saving with 10 concurrent clients, SQLite against PostgreSQL.

For each backend: a fresh database (SQLite in the service's data folder; a database on a
throwaway PostgreSQL 15 server from the installed binaries, fsync on), one ``dimacq serve``
process (or, with ``--services 2``, two stands on the PostgreSQL database, the clients split
between them), ``--prefill`` setups stored, then ``--clients`` threads, each with its own
keep-alive connection, for ``--seconds`` each:

- list: ``GET /api/setups`` (every setup with its body: ``--prefill`` of them),
- save: ``POST /api/setups`` (the six-triax example setup as JSON; 201 each).

Prints requests per second and the p50/p95 latency of each, and checks nothing was lost: the
number of setups afterwards equals prefill + successful saves.

    python tests/benchmarks/bench_db_concurrency.py [--clients 10] [--seconds 8] [--prefill 50]
           [--services 2] [--results PATH]

The table goes to ``bench_db_concurrency_results.md`` beside this script (``--results``
elsewhere) with the command, date, commit and machine load.
"""

from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
import threading
import time
from pathlib import Path

import httpx
import numpy as np

TESTS = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(TESTS))

from _pg_support import PgServer, pg_binaries_missing  # noqa: E402
from _results import Results, add_results_argument, markdown_table  # noqa: E402
from _serve_support import Service  # noqa: E402

from dimacq.api.server import free_port  # noqa: E402
from dimacq.io.setup_file import dump_setup_dict, load_setup  # noqa: E402

TOKEN = "bench-db"
EXAMPLE = TESTS.parent / "config" / "examples" / "six_triax_setup.toml"


def _phase(
    urls: list[str], clients: int, seconds: float, call: str, body: dict
) -> tuple[int, int, list[float]]:
    lat: list[float] = []
    errors = [0]
    lock = threading.Lock()
    stop = time.monotonic() + seconds

    def worker(k: int) -> None:
        mine: list[float] = []
        bad = 0
        with httpx.Client(
            base_url=urls[k % len(urls)], headers={"Authorization": f"Bearer {TOKEN}"}, timeout=60
        ) as c:
            while time.monotonic() < stop:
                t0 = time.perf_counter()
                r = c.get("/api/setups") if call == "list" else c.post("/api/setups", json=body)
                mine.append(time.perf_counter() - t0)
                if r.status_code not in (200, 201):
                    bad += 1
        with lock:
            lat.extend(mine)
            errors[0] += bad

    threads = [threading.Thread(target=worker, args=(k,)) for k in range(clients)]
    t0 = time.monotonic()
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    wall = time.monotonic() - t0
    return len(lat), errors[0], [len(lat) / wall, *np.percentile(lat, [50, 95]) * 1e3]


def run(backend: str, args: argparse.Namespace, pg: PgServer | None, n_services: int) -> dict:
    tmp = Path(tempfile.mkdtemp(prefix=f"dimacq-bench-{backend}-"))
    env: dict[str, str] = {}
    if pg is not None:
        env["DIMACQ_DATABASE_URL"] = pg.create_database()
    services = [
        Service(
            tmp / f"s{i}",
            free_port(),
            TOKEN,
            {**env, "DIMACQ_STAND": f"bench{i}", "DIMACQ_DIGITIZER_URL": f"simdigitizer://b{i}"},
        )
        for i in range(n_services)
    ]
    try:
        body = dump_setup_dict(load_setup(EXAMPLE))
        for _ in range(args.prefill):
            services[0].client.post("/api/setups", json=body).raise_for_status()
        urls = [s.url for s in services]
        _n_list, e_list, f_list = _phase(urls, args.clients, args.seconds, "list", body)
        n_save, e_save, f_save = _phase(urls, args.clients, args.seconds, "save", body)
        total = len(services[-1].client.get("/api/setups").json())
        return {
            "backend": backend,
            "services": n_services,
            "list": f_list,
            "save": f_save,
            "errors": e_list + e_save,
            "lost": args.prefill + (n_save - e_save) - total,
        }
    finally:
        for s in services:
            s.stop()
        shutil.rmtree(tmp, ignore_errors=True)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--clients", type=int, default=10)
    ap.add_argument("--seconds", type=float, default=8.0)
    ap.add_argument("--prefill", type=int, default=50)
    ap.add_argument("--services", type=int, default=1, help="stands sharing the PostgreSQL DB")
    add_results_argument(ap, __file__)
    args = ap.parse_args()
    res = Results(
        __file__, "Listing and saving with concurrent clients, SQLite and PostgreSQL", args.results
    )
    rows = [run("sqlite", args, None, 1)]
    why = pg_binaries_missing()
    if why:
        print(f"PostgreSQL skipped: {why}")
        res.note(f"PostgreSQL skipped: {why}")
    else:
        pg = PgServer(durable=True)
        try:
            rows.append(run("postgresql", args, pg, 1))
            if args.services > 1:
                rows.append(run("postgresql", args, pg, args.services))
        finally:
            pg.close()
    what = (
        f"{args.clients} concurrent clients, {args.seconds:.0f} s per phase, list = GET "
        f"/api/setups with {args.prefill} setups, save = POST /api/setups (six-triax setup)"
    )
    res.note(what)
    table = []
    for r in rows:
        lr, lp50, lp95 = r["list"]
        sr, sp50, sp95 = r["save"]
        table.append(
            (
                r["backend"],
                r["services"],
                f"{lr:.0f}",
                f"{lp50:.0f} / {lp95:.0f}",
                f"{sr:.0f}",
                f"{sp50:.0f} / {sp95:.0f}",
                r["errors"],
                r["lost"],
            )
        )
    header = [
        "backend",
        "services",
        "list req/s",
        "list p50 / p95 ms",
        "save req/s",
        "save p50 / p95 ms",
        "errors",
        "lost",
    ]
    res.table(header, table)
    print(f"\n{what}\n\n{markdown_table(header, table)}")
    res.write()
    return 0 if all(r["errors"] == 0 and r["lost"] == 0 for r in rows) else 1


if __name__ == "__main__":
    raise SystemExit(main())
