"""Run a pytest selection under BLAS code paths and thread counts, several times, and record
each run's counts and wall time.

    python tests/scripts/machine_independence.py                       # the suite, 5 runs each
    python tests/scripts/machine_independence.py --fresh-clone         # on a fresh clone of HEAD
    python tests/scripts/machine_independence.py --runs 1 -- \\
        -n 0 tests/cli/test_solve_reference_numbers.py                  # a small selection

Numbers that a test compares against stored references move with the BLAS kernel (OpenBLAS
picks AVX-512, AVX2 or SSE code at run time; MKL and Accelerate have their own) and with its
thread count (the order of a parallel sum). The suite must pass whichever runs. Each variant
sets environment variables for the whole pytest process tree:

- ``default``: the environment as it is, without ``OPENBLAS_*`` overrides (under ``-n`` the
  suite's conftest gives every worker one BLAS thread);
- ``threads-1``: ``OPENBLAS_NUM_THREADS=1``;
- ``threads-N``: ``OPENBLAS_NUM_THREADS`` = the cores (explicit: wins over the conftest's 1);
- ``nehalem``: ``OPENBLAS_CORETYPE=NEHALEM`` (SSE kernels);
- ``haswell``: ``OPENBLAS_CORETYPE=Haswell`` (AVX2 kernels; the default on an AVX2 machine,
  not on an AVX-512 one).

The kernel and threads that actually ran (``threadpoolctl`` in the same environment) are
recorded with each run. ``--fresh-clone``: ``git clone`` of this repository's HEAD (committed
work only) into a temporary folder, a venv there with ``pip install -e ".[dev]"``, and the
command run in it, as a new user would. The results are appended to
``tests/scripts/machine_independence_results.md`` (``--results`` elsewhere) through
``tests/_results.py`` (command, date, commit of the tree tested, machine load, and per
run: variant, kernel, passed / failed / skipped / errors, wall time, the failed tests).
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from _results import Results, commit

ROOT = Path(__file__).resolve().parents[2]
RESULTS = Path(__file__).with_name("machine_independence_results.md")
TITLE = "Machine independence: the tests under BLAS code paths and thread counts"
#: the README's test command, after ``pytest``
README_ARGS = ["-q", "-p", "no:cacheprovider", "-n", "auto"]
_CORES = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1
VARIANTS: dict[str, dict[str, str]] = {
    "default": {},
    "threads-1": {"OPENBLAS_NUM_THREADS": "1"},
    f"threads-{_CORES}": {"OPENBLAS_NUM_THREADS": str(_CORES)},
    "nehalem": {"OPENBLAS_CORETYPE": "NEHALEM"},
    "haswell": {"OPENBLAS_CORETYPE": "Haswell"},
}
_BLAS_VARS = ("OPENBLAS_NUM_THREADS", "OPENBLAS_CORETYPE", "OMP_NUM_THREADS", "MKL_NUM_THREADS")
_COUNT = re.compile(r"(\d+) (passed|failed|skipped|errors?|xfailed|xpassed|deselected)")
_PROBE = (
    "import json, numpy, scipy.linalg, threadpoolctl; "
    "print(json.dumps(sorted({(i.get('internal_api'), i.get('architecture'), i.get('num_threads'))"
    " for i in threadpoolctl.threadpool_info() if i.get('user_api') == 'blas'})))"
)


@dataclass
class Run:
    variant: str
    kernel: str
    counts: dict[str, int]
    wall_s: float
    returncode: int
    failed: list[str]


def environment(variant: str) -> dict[str, str]:
    """The environment of VARIANT: this one without BLAS overrides, then the variant's."""
    env = {k: v for k, v in os.environ.items() if k not in _BLAS_VARS}
    env.update(VARIANTS[variant])
    return env


def kernel(python: str, env: dict[str, str], cwd: Path) -> str:
    """The BLAS libraries numpy and scipy load in ENV: ``api architecture×threads`` each."""
    got = subprocess.run(
        [python, "-c", _PROBE], env=env, cwd=cwd, capture_output=True, text=True, check=False
    )
    if got.returncode != 0:
        return f"(not probed: {got.stderr.strip().splitlines()[-1:]})"
    return ", ".join(f"{api} {arch}×{n}" for api, arch, n in json.loads(got.stdout))


def run_once(python: str, args: list[str], variant: str, cwd: Path, log: Path) -> Run:
    env = environment(variant)
    arch = kernel(python, env, cwd)
    t0 = time.monotonic()
    with log.open("w") as out:
        proc = subprocess.run(
            [python, "-m", "pytest", *args],
            env=env,
            cwd=cwd,
            stdout=out,
            stderr=subprocess.STDOUT,
            check=False,
        )
    wall = time.monotonic() - t0
    text = log.read_text(errors="replace")
    summary = next(
        (ln for ln in reversed(text.splitlines()) if _COUNT.search(ln) and " in " in ln), ""
    )
    counts = {
        k.rstrip("s") if k.startswith("error") else k: int(n) for n, k in _COUNT.findall(summary)
    }
    failed = [
        ln.split(" ", 1)[1].split(" - ")[0]
        for ln in text.splitlines()
        if ln.startswith(("FAILED ", "ERROR "))
    ]
    return Run(variant, arch, counts, wall, proc.returncode, failed)


def fresh_clone(where: Path) -> tuple[Path, str]:
    """``git clone`` of HEAD into WHERE, a venv with the package and its dev extras; its
    folder and its python."""
    dest = where / "dimacq"
    subprocess.run(["git", "clone", "--quiet", str(ROOT), str(dest)], check=True)
    subprocess.run([sys.executable, "-m", "venv", str(dest / ".venv")], check=True)
    py = str(dest / ".venv" / "bin" / "python")
    subprocess.run([py, "-m", "pip", "install", "-q", "-e", ".[dev]"], cwd=dest, check=True)
    return dest, py


def report(runs: list[Run], command: str, where: str, res: Results) -> None:
    """The run's section: where, the pytest command, the BLAS settings, one row per run."""
    res.note(f"tests: `{command}`")
    res.note(f"where: {where}")
    res.note(
        "environment's own BLAS settings: "
        + (", ".join(f"{k}={os.environ[k]}" for k in _BLAS_VARS if k in os.environ) or "none")
    )
    rows = [
        (
            i,
            r.variant,
            r.kernel,
            r.counts.get("passed", 0),
            r.counts.get("failed", 0),
            r.counts.get("error", 0),
            r.counts.get("skipped", 0),
            f"{r.wall_s:.0f}",
        )
        for i, r in enumerate(runs, 1)
    ]
    res.table(
        [
            "run",
            "variant",
            "BLAS (numpy, scipy)",
            "passed",
            "failed",
            "errors",
            "skipped",
            "wall s",
        ],
        rows,
    )
    bad = [(i, r) for i, r in enumerate(runs, 1) if r.failed or r.returncode != 0]
    verdict = [
        f"All green: {'yes' if not bad else 'NO'} ({len(runs) - len(bad)} of {len(runs)} runs)."
    ]
    verdict += [
        f"- run {i} ({r.variant}, exit {r.returncode}): " + ", ".join(r.failed[:20]) for i, r in bad
    ]
    res.add("\n".join(verdict))


def main() -> int:
    ap = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    ap.add_argument("--runs", type=int, default=5, help="runs of each variant (default 5)")
    ap.add_argument(
        "--variants",
        default=",".join(VARIANTS),
        help=f"comma-separated, of {', '.join(VARIANTS)} (default: all)",
    )
    ap.add_argument("--fresh-clone", action="store_true", help="on a fresh clone of HEAD")
    ap.add_argument(
        "--clone-dir",
        type=Path,
        help="where to clone (default: a temporary folder, removed at the end)",
    )
    ap.add_argument("--results", type=Path, default=RESULTS, help="the results file (appended)")
    ap.add_argument(
        "pytest_args", nargs="*", help="after --: pytest's arguments (default: the README's)"
    )
    args = ap.parse_args()
    variants = [v.strip() for v in args.variants.split(",") if v.strip()]
    unknown = [v for v in variants if v not in VARIANTS]
    if unknown:
        ap.error(f"unknown variant(s) {unknown}; give some of {list(VARIANTS)}")
    pytest_args = args.pytest_args or README_ARGS
    res = Results(__file__, TITLE, args.results, append=True)
    tmp = Path(tempfile.mkdtemp(prefix="machine-independence-"))
    try:
        if args.fresh_clone:
            base = args.clone_dir or tmp
            base.mkdir(parents=True, exist_ok=True)
            cwd, python = fresh_clone(base)
            where = (
                f'a fresh clone of {ROOT} at {cwd} (`git clone`, venv, `pip install -e ".[dev]"`)'
            )
        else:
            cwd, python = ROOT, sys.executable
            where = f"this tree ({ROOT}), {sys.executable}"
        res.commit = commit(cwd)
        runs: list[Run] = []
        for k in range(args.runs):
            for v in variants:
                log = tmp / f"run{len(runs) + 1}-{v}.log"
                r = run_once(python, pytest_args, v, cwd, log)
                runs.append(r)
                c = r.counts
                print(
                    f"run {len(runs)} ({k + 1}/{args.runs}) {v:10s} {r.kernel}: "
                    f"{c.get('passed', 0)} passed, {c.get('failed', 0)} failed, "
                    f"{c.get('error', 0)} errors, {r.wall_s:.0f} s",
                    flush=True,
                )
                if r.failed:
                    print("  failed: " + ", ".join(r.failed[:10]), flush=True)
                    keep = args.results.with_name(f"machine_independence_failed_run{len(runs)}.log")
                    shutil.copy(log, keep)
                    print(f"  its output: {keep}", flush=True)
        command = "pytest " + " ".join(pytest_args)
        report(runs, command, where, res)
        res.write()
        print("\n\n".join([res.header(), *res.sections]))
        return 0 if all(not r.failed and r.returncode == 0 for r in runs) else 1
    finally:
        if args.clone_dir is None:
            shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    sys.exit(main())
