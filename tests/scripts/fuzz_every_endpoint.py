"""A long run of ``tests/api/test_hardening_every_endpoint_fuzz.py``: every operation of the
spec, ``--examples`` hostile requests each, on SQLite and PostgreSQL (random examples, not the
default run's fixed ones), and the counts per database and status class written to
``fuzz_every_endpoint_results.md`` beside this script (``--results`` elsewhere) with the
command, date, commit and load.

    python tests/scripts/fuzz_every_endpoint.py [--examples 40] [-n 2] [--results PATH]
"""

from __future__ import annotations

import argparse
import collections
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "tests"))
from _results import Results, add_results_argument  # noqa: E402


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--examples", type=int, default=40, help="hostile requests per operation")
    ap.add_argument("-n", default="2", help="pytest-xdist workers (at most 2 on a shared host)")
    add_results_argument(ap, __file__)
    args = ap.parse_args()
    res = Results(__file__, "Hostile values on every endpoint (long run)", args.results)
    with tempfile.NamedTemporaryFile(prefix="fuzz-counts-", suffix=".tsv", delete=False) as fh:
        counts_path = Path(fh.name)
    env = {
        **os.environ,
        "DIMACQ_FUZZ_EXAMPLES": str(args.examples),
        "DIMACQ_FUZZ_COUNTS": str(counts_path),
    }
    t0 = time.monotonic()
    run = subprocess.run(
        [
            sys.executable,
            "-m",
            "pytest",
            "-q",
            "-p",
            "no:cacheprovider",
            "-n",
            args.n,
            "tests/api/test_hardening_every_endpoint_fuzz.py",
        ],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
    )
    took = time.monotonic() - t0
    rows = [line.split("\t") for line in counts_path.read_text().splitlines() if line]
    counts_path.unlink()
    per: dict[str, collections.Counter[str]] = collections.defaultdict(collections.Counter)
    ops: dict[str, set[str]] = collections.defaultdict(set)
    where: dict[str, collections.Counter[str]] = collections.defaultdict(collections.Counter)
    for backend, op, place, status in rows:
        per[backend][f"{status[0]}xx"] += 1
        ops[backend].add(op)
        where[backend][place.split(":", 1)[0]] += 1
    summary = run.stdout.strip().splitlines()[-1] if run.stdout.strip() else run.stderr[-300:]
    res.note(f"pytest: {summary} ({took:.0f} s)")
    lines = [
        "| database | operations | requests | 2xx | 3xx | 4xx | 5xx | hostile value in |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for backend in sorted(per):
        c = per[backend]
        places = ", ".join(f"{k} {v}" for k, v in sorted(where[backend].items()))
        lines.append(
            f"| {backend} | {len(ops[backend])} | {sum(c.values())} | {c['2xx']} | {c['3xx']} | "
            f"{c['4xx']} | {c['5xx']} | {places} |"
        )
    if run.returncode != 0:
        lines += ["", "Failures:", "", "```", run.stdout[-4000:], "```"]
    res.add("\n".join(lines))
    print("\n\n".join([res.header(), *res.sections]))
    res.write()
    return run.returncode


if __name__ == "__main__":
    raise SystemExit(main())
