"""Benchmark: peak memory and time of a simulated static and inertial load cell calibration.

Run on demand (not collected by pytest)::

    python tests/benchmarks/bench_loadcell_calibration.py [--method static inertial]
                                                          [--tracemalloc] [--json OUT]

Each method runs in its own fresh process (``dimacq loadcell calibrate --simulated --method M``
in-process through its CLI entry point: the calibration and the circular check, through the rig
builder and the simulated backends), so its peak resident memory is its own: ``ru_maxrss``
of the child (MB, including the ~135 MB of the imported libraries), the wall and CPU seconds,
and with ``--tracemalloc`` the peak of Python/numpy allocations traced by :mod:`tracemalloc`
(slower). The static run's time is mostly the operator's settling: the simulated amplifier's clock
runs 200× faster than real time.
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import time
from pathlib import Path


def one(method: str, trace: bool) -> dict[str, float | str]:
    import contextlib
    import io
    import tempfile
    import tracemalloc

    from dimacq.cli.main import main as dimacq

    if trace:
        tracemalloc.start()
    with tempfile.TemporaryDirectory() as tmp:
        out_json = Path(tmp) / "cal.json"
        t0, c0 = time.perf_counter(), time.process_time()
        with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
            rc = dimacq(
                [
                    "loadcell",
                    "calibrate",
                    "--simulated",
                    "--method",
                    method,
                    "--json",
                    str(out_json),
                ]
            )
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
        res = json.loads(out_json.read_text())
    out: dict[str, float | str] = {
        "method": method,
        "exit_status": rc,
        "wall_s": wall,
        "cpu_s": cpu,
        "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
        "matrix_error_rel": res["matrix_error_rel"],
        "circular_mass_error_pct": res["circular_mass_error_pct"],
    }
    if trace:
        out["tracemalloc_peak_mb"] = tracemalloc.get_traced_memory()[1] / 1e6
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--method", nargs="+", default=["static", "inertial"])
    ap.add_argument("--tracemalloc", action="store_true")
    ap.add_argument("--json", type=Path)
    ap.add_argument("--child", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        print(json.dumps(one(args.child, args.tracemalloc)))
        return 0
    results = []
    for m in args.method:
        cmd = [sys.executable, __file__, "--child", m] + (
            ["--tracemalloc"] if args.tracemalloc else []
        )
        p = subprocess.run(cmd, capture_output=True, text=True, check=True)
        r = json.loads(p.stdout.strip().splitlines()[-1])
        results.append(r)
        print(
            f"{m:9s} peak RSS {r['peak_rss_mb']:7.1f} MB  wall {r['wall_s']:6.1f} s  "
            f"CPU {r['cpu_s']:6.1f} s  matrix error {100 * r['matrix_error_rel']:.4f} %  "
            f"circular mass {r['circular_mass_error_pct']:+.4f} %"
            + (
                f"  traced peak {r['tracemalloc_peak_mb']:.1f} MB"
                if "tracemalloc_peak_mb" in r
                else ""
            )
        )
    if args.json:
        args.json.write_text(json.dumps(results, indent=2) + "\n", encoding="utf-8")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
