"""Benchmark: start-up of ``dimacq --help``, ``dimacq solve --help`` and a solve of the example.

Run on demand (not collected by pytest)::

    python tests/benchmarks/startup.py [--repeat 7] [--label before]

Each run is a fresh process, as a user starts it. For each command the median (and minimum)
wall time and CPU time (user + system of the child) over ``--repeat`` runs are printed and
appended to ``startup_results.md`` beside this script (``--results`` elsewhere), with the
command line, date, commit, label and the load average before and after. On a shared machine the CPU time is the steadier
figure; the wall time is what the user waits. The commands take turns run by run, so that all
see the same load. ``--importtime`` adds the cumulative import time of ``dimacq.cli.main`` plus
the modules ``dimacq --help`` loads (``python -X importtime``, median of the same runs).
"""

from __future__ import annotations

import argparse
import os
import shlex
import statistics
import subprocess
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from _results import Results, add_results_argument

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
TITLE = "Start-up: `dimacq --help`, `dimacq solve --help`, `dimacq solve` of the example"
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


def main(argv: list[str] | None = None) -> int:
    """Measure, print and append the table; returns the exit status."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=7, help="runs per command (default 7)")
    parser.add_argument("--label", default="", help="a word for the table heading (before/after)")
    parser.add_argument("--importtime", action="store_true", help="also median import time")
    add_results_argument(parser, __file__)
    args = parser.parse_args(argv)
    if args.repeat < 1:
        parser.error("--repeat: give at least 1 run")

    res = Results(__file__, TITLE, args.results, append=True, label=args.label or "run")
    if argv is not None:
        res.command = " ".join(["python", res.shown, *map(shlex.quote, argv)])
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

    res.note(f"runs per command: {args.repeat} (fresh process each, commands taking turns)")
    rows = []
    for name in COMMANDS:
        imp = f"{statistics.median(imports[name]):.0f} ms" if imports[name] else "-"
        rows.append(
            (
                f"`{name}`",
                f"{statistics.median(walls[name]):.3f} s",
                f"{min(walls[name]):.3f} s",
                f"{statistics.median(cpus[name]):.3f} s",
                f"{min(cpus[name]):.3f} s",
                imp,
            )
        )
    res.table(
        ["command", "wall median", "wall min", "CPU median", "CPU min", "imports median"], rows
    )
    print("\n\n".join([res.header(), *res.sections]))
    res.write()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
