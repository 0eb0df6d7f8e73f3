"""Benchmark: start-up of ``dimacq --help``, ``dimacq solve --help`` and a solve of the example.

Run on demand (not collected by pytest)::

    python tests/benchmarks/startup.py [--repeat 7] [--label before]

Each run is a fresh process, as a user starts it. For each command the median (and minimum)
wall time and CPU time (user + system of the child) over ``--repeat`` runs are printed and
appended to ``startup_results.md`` beside this script, with the command line, date, commit,
label and the load average before and after. On a shared machine the CPU time is the steadier
figure; the wall time is what the user waits. The commands take turns run by run, so that all
see the same load. ``--importtime`` adds the cumulative import time of ``dimacq.cli.main`` plus
the modules ``dimacq --help`` loads (``python -X importtime``, median of the same runs).
"""

from __future__ import annotations

import argparse
import datetime as dt
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
RESULTS = HERE / "startup_results.md"
SETUP = ROOT / "config" / "examples" / "six_triax_setup.toml"
FRF = ROOT / "config" / "examples" / "six_triax_frf.uff"


def _dimacq() -> list[str]:
    """The ``dimacq`` entry point of this interpreter's environment, as a user types it."""
    return [sys.executable, "-c", "import sys; from dimacq.cli.main import main; sys.exit(main())"]


COMMANDS: dict[str, list[str]] = {
    "dimacq --help": ["--help"],
    "dimacq solve --help": ["solve", "--help"],
    "dimacq solve (shipped example)": ["solve", str(SETUP), str(FRF)],
}


def _run(argv: list[str]) -> tuple[float, float]:
    """Wall and CPU (user + system) seconds of one child process running ``argv``."""
    t0 = time.perf_counter()
    proc = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    _, status, usage = os.wait4(proc.pid, 0)
    wall = time.perf_counter() - t0
    assert proc.stderr is not None
    err = proc.stderr.read().decode()
    proc.stderr.close()
    if os.waitstatus_to_exitcode(status) not in (0, 3):
        raise SystemExit(f"{' '.join(argv)} failed:\n{err}")
    return wall, usage.ru_utime + usage.ru_stime


def _import_ms(args: list[str]) -> float:
    """Cumulative import time in ms of every top-level import a run of ``args`` makes."""
    argv = [sys.executable, "-X", "importtime", *_dimacq()[1:], *args]
    proc = subprocess.run(argv, capture_output=True, text=True, check=False)
    total = 0
    for line in proc.stderr.splitlines():
        if not line.startswith("import time:") or "cumulative" in line:
            continue
        _, cum, name = line.split("|", 2)
        if not name.startswith("  "):  # a top-level import: its figure includes its children
            total += int(cum)
    return total / 1000.0


def _commit() -> str:
    """Short commit hash of the checkout, with ``+dirty`` when the tree has changes."""
    rev = subprocess.run(
        ["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True
    ).stdout.strip()
    dirty = subprocess.run(
        ["git", "status", "--porcelain", "--untracked-files=no"],
        cwd=ROOT,
        capture_output=True,
        text=True,
    ).stdout.strip()
    return rev + ("+dirty" if dirty else "")


def _load() -> str:
    """Load averages (1, 5, 15 min) and the core count."""
    one, five, fifteen = os.getloadavg()
    return f"{one:.2f} / {five:.2f} / {fifteen:.2f} on {os.cpu_count()} cores"


def main(argv: list[str] | None = None) -> int:
    """Measure, print and append the table; returns the exit status."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=7, help="runs per command (default 7)")
    parser.add_argument("--label", default="", help="a word for the table heading (before/after)")
    parser.add_argument("--importtime", action="store_true", help="also median import time")
    args = parser.parse_args(argv)
    if args.repeat < 1:
        parser.error("--repeat: give at least 1 run")

    load_before = _load()
    walls: dict[str, list[float]] = {name: [] for name in COMMANDS}
    cpus: dict[str, list[float]] = {name: [] for name in COMMANDS}
    imports: dict[str, list[float]] = {name: [] for name in COMMANDS}
    _run(_dimacq() + ["--help"])  # warm the bytecode cache and the page cache
    for _ in range(args.repeat):
        for name, cmd_args in COMMANDS.items():
            wall, cpu = _run(_dimacq() + cmd_args)
            walls[name].append(wall)
            cpus[name].append(cpu)
            if args.importtime:
                imports[name].append(_import_ms(cmd_args))
    load_after = _load()

    now = dt.datetime.now(dt.UTC).strftime("%Y-%m-%d %H:%M UTC")
    command = "python tests/benchmarks/startup.py " + " ".join(
        sys.argv[1:] if argv is None else argv
    )
    lines = [
        "",
        f"## {args.label or 'run'}: {now}, commit {_commit()}",
        "",
        f"- command: `{command.strip()}`",
        f"- load average before: {load_before}; after: {load_after}",
        f"- runs per command: {args.repeat} (fresh process each, commands taking turns)",
        "",
        "| command | wall median | wall min | CPU median | CPU min | imports median |",
        "|---|---|---|---|---|---|",
    ]
    for name in COMMANDS:
        imp = f"{statistics.median(imports[name]):.0f} ms" if imports[name] else "-"
        lines.append(
            f"| `{name}` | {statistics.median(walls[name]):.3f} s | {min(walls[name]):.3f} s"
            f" | {statistics.median(cpus[name]):.3f} s | {min(cpus[name]):.3f} s | {imp} |"
        )
    text = "\n".join(lines) + "\n"
    print(text)
    if not RESULTS.exists():
        RESULTS.write_text(
            "# Start-up: `dimacq --help`, `dimacq solve --help`, `dimacq solve` of the example\n\n"
            "Written by `tests/benchmarks/startup.py`; each section is one run of it.\n"
        )
    with RESULTS.open("a") as fh:
        fh.write(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
