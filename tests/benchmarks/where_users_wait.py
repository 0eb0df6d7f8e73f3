"""Where a user waits: the page's FRF view and solve against the CLI, the flexible solve's CPU,
the peak memory of the demo and the bench calibration.

Each figure is measured in A/B pairs run one after the other (A, B, A, B, ...), so that a
neighbour's load hits both alike; medians and their ratio are reported. The results file
(``where_users_wait_results.md`` beside this script, ``--results`` elsewhere) carries the
command, date, commit, the load average and this host's sustainable time-lapse
(:func:`dimacq.backends.time_lapse.measure_host`, its speed) beside the figures.

1. **FRF view open** (what the page's FRFs step waits for before it draws): ``GET
   /api/frfs/{id}/data`` (JSON, parsed) against ``GET /api/frfs/{id}/data.f32`` (float32 behind
   a JSON header, decoded to arrays), over loopback HTTP (a Python client: a browser reads the
   bytes straight into typed arrays), and the server's CPU seconds for the float32 answer, for
   the shipped example set
   (``config/examples/six_triax_frf.uff``) and an X-38-size set (the ``x38-flexible-17``
   scenario's model FRFs on 2048 lines: 81 responses × 22 inputs, more than 63 × 22).
2. **Page solve vs CLI solve** on the same set (the shipped example, automatic band):
   ``POST /api/solutions`` on a running service against ``dimacq solve`` in a process of its own
   (the wall time a user waits for each, the CLI's start-up included), and the CPU seconds of
   each (the service's process; the CLI's process): on an oversubscribed host the wall times
   measure the scheduler (a thread of a busy process against a process of its own) as much as
   the work.
3. **Flexible solve CPU**: :func:`~dimacq.services.solve.analysis.analyse` of the X-38-like
   flexible vehicles' model FRFs (``x38-flexible-10``, ``-17``, ``-34``: 0.5 % noise) with the
   modal correction (``auto``) and without (target ≤ 5 s CPU with it), and of the rigid ``x38``
   (the plain solve): process time of a worker process with one BLAS thread
   (``OPENBLAS_NUM_THREADS=1``: a second thread spinning on a busy host is not work). With
   ``--before REV`` the same worker also runs on the code of commit REV (``git archive`` laid out
   as installed), one after the other per scenario, and the answers are compared.
4. **Live path** (``--live``): :func:`bench_live_path.run` (driver → blocks → FRF per record on
   one core, from a recorded stream) at 128 channels × 51.2 kS/s: the realtime factor (the
   margin) and the most channels it sustains.
5. **Peak memory** (``--memory``): ``dimacq demo`` and ``dimacq loadcell calibrate --simulated
   --method static`` under ``/usr/bin/time -v`` (maximum resident set size; the demo's step-0
   child process is a process of its own and is reported by the same tool only for the largest
   process: the figure is the largest process's). ``--memory-only`` runs this section alone,
   ``--memory-runs`` times per command (taking turns), and writes it into the results file under
   its ``--label`` (a section of the same label replaced, the file's other sections kept).

    python tests/benchmarks/where_users_wait.py [--pairs 5] [--memory] [--live]
           [--skip-flexible] [--only-flexible] [--flexible x38-flexible-17 ...] [--before REV]
    python tests/benchmarks/where_users_wait.py --memory-only [--memory-runs 2] [--label after]
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import re
import resource
import shlex
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import httpx
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from _results import Results, add_results_argument

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
EXAMPLES = ROOT / "config" / "examples"


def host_line() -> str:
    from dimacq.backends.time_lapse import measure_host

    m = measure_host(30, 1, 51200.0)
    load = os.getloadavg()
    return (
        f"load average {load[0]:.2f} / {load[1]:.2f} / {load[2]:.2f} on {os.cpu_count()} cores; "
        f"this host sustains about {m.sustainable_scale:.1f}x time-lapse now"
    )


def pairs(
    a: Callable[[], float], b: Callable[[], float], n: int
) -> tuple[list[float], list[float]]:
    """``n`` interleaved runs of ``a`` and ``b`` (each returns its seconds)."""
    xa: list[float] = []
    xb: list[float] = []
    for _ in range(n):
        xa.append(a())
        xb.append(b())
    return xa, xb


def fmt(xs: list[float]) -> str:
    return f"{statistics.median(xs):.3f} s (min {min(xs):.3f}, max {max(xs):.3f}, n {len(xs)})"


def frf_view(c: httpx.Client, fid: int, n: int, with_json: bool = True) -> dict[str, Any]:
    """Seconds to GET and decode the set's values as JSON and as float32 (``with_json``
    False: the float32 answer only, the JSON one left out: 167 MB for the X-38 size)."""
    from dimacq.io.frf_binary import decode_f32

    size = {"json": 0, "f32": 0}

    def js() -> float:
        t0 = time.perf_counter()
        r = c.get(f"/api/frfs/{fid}/data")
        r.raise_for_status()
        d = r.json()
        np.asarray(d["real"])
        size["json"] = len(r.content)
        return time.perf_counter() - t0

    def f32() -> float:
        t0 = time.perf_counter()
        r = c.get(f"/api/frfs/{fid}/data.f32")
        r.raise_for_status()
        decode_f32(r.content)
        size["f32"] = len(r.content)
        return time.perf_counter() - t0

    if not with_json:
        return {
            "json": [],
            "f32": [f32() for _ in range(n)],
            "bytes_json": 0,
            "bytes_f32": size["f32"],
        }
    a, b = pairs(js, f32, n)
    return {"json": a, "f32": b, "bytes_json": size["json"], "bytes_f32": size["f32"]}


def solve_pair(c: httpx.Client, fid: int, n: int, tmp: Path) -> dict[str, Any]:
    body = {"frf_id": fid}

    cpu: dict[str, list[float]] = {"page": [], "cli": []}

    def page() -> float:
        t0, c0 = time.perf_counter(), time.process_time()
        r = c.post("/api/solutions", json=body, timeout=600)
        r.raise_for_status()
        cpu["page"].append(time.process_time() - c0)  # the service runs in this process
        return time.perf_counter() - t0

    out = tmp / "cli.json"
    cmd = [
        "dimacq",
        "solve",
        str(EXAMPLES / "six_triax_setup.toml"),
        str(EXAMPLES / "six_triax_frf.uff"),
        "--json",
        str(out),
    ]

    def cli() -> float:
        t0 = time.perf_counter()
        u0 = resource.getrusage(resource.RUSAGE_CHILDREN)
        subprocess.run(cmd, check=True, capture_output=True)
        u1 = resource.getrusage(resource.RUSAGE_CHILDREN)
        cpu["cli"].append(u1.ru_utime - u0.ru_utime + u1.ru_stime - u0.ru_stime)
        return time.perf_counter() - t0

    a, b = pairs(page, cli, n)
    page_json = c.post("/api/solutions", json=body, timeout=600).json()
    cli_json = json.loads(out.read_text())
    same = abs(page_json["result"]["mass_kg"] - cli_json["mass_kg"]) <= 1e-9 * cli_json["mass_kg"]
    return {
        "page": a,
        "cli": b,
        "cpu": cpu,
        "same_mass": same,
        "command": " ".join(cmd[:4]) + " ...",
    }


def flexible(n: int, scenario: str) -> dict[str, Any]:
    """``n`` solves of SCENARIO's model FRFs (seed 0, 0.5 % noise) with the modal correction
    off and auto, in this process: CPU seconds, answer and verdict of each mode (the worker)."""
    from dimacq.services.solve.analysis import AnalysisOptions, analyse
    from dimacq.simulators.lab.scenarios import build_scenario

    b = build_scenario(scenario, 0)
    frf = b.model_frf(noise=0.005)
    out: dict[str, Any] = {"shape": list(frf.H.shape)}
    for mode in ("off", "auto"):
        cpu = []
        for _ in range(n):
            t0 = time.process_time()
            rep = analyse(frf, b.setup, AnalysisOptions(modal_correction=mode))
            cpu.append(time.process_time() - t0)
        out[mode] = {
            "cpu": cpu,
            "mass_kg": rep.result.properties.mass_kg,
            "truth_kg": b.truth.mass_kg,
            "band_hz": list(rep.result.band_hz),
            "verdict": rep.verdict,
            "applied": rep.modal_correction is not None and rep.modal_correction.applied,
            "report": json.loads(json.dumps(rep.to_json(), default=str)),
        }
    return out


def flexible_in_worker(n: int, scenario: str, tree: Path | None = None) -> dict[str, Any]:
    """:func:`flexible` in a process of its own with one BLAS thread, on this checkout or on
    the package tree ``tree`` (:func:`tree_of`)."""
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"}
    if tree is not None:
        env["PYTHONPATH"] = str(tree)
    p = subprocess.run(
        [sys.executable, str(Path(__file__).resolve()), "--flexible-worker", scenario, str(n)],
        capture_output=True,
        text=True,
        env=env,
        cwd=tempfile.gettempdir(),
        check=True,
    )
    return dict(json.loads(p.stdout.strip().splitlines()[-1]))


def tree_of(rev: str, where: Path) -> Path:
    """The package of commit REV laid out as installed (pyproject's ``package-dir``:
    ``drivers`` → ``dimacq.drivers``, ``simulators`` → ``dimacq.simulators``; ``config`` beside
    them, where the simulators look for it), under ``where``; returns the folder to put on the
    path."""
    pkg = where / "pkg"
    pkg.mkdir(parents=True)
    for prefix, paths in (("", ["dimacq"]), ("dimacq/", ["drivers", "simulators", "config"])):
        arc = subprocess.run(
            ["git", "archive", f"--prefix={prefix}", rev, *paths],
            capture_output=True,
            check=True,
            cwd=ROOT,
        ).stdout
        subprocess.run(["tar", "-x", "-C", str(pkg)], input=arc, check=True)
    return pkg


def same_answer(a: dict[str, Any], b: dict[str, Any]) -> str:
    """Whether two reports (JSON) are the same number for number, and where they first differ."""

    def walk(x: Any, y: Any, path: str) -> str | None:
        if isinstance(x, dict) and isinstance(y, dict):
            if list(x) != list(y):
                return f"{path}: keys {sorted(set(x) ^ set(y))}"
            for k in x:
                if k == "elapsed_s":
                    continue
                d = walk(x[k], y[k], f"{path}.{k}")
                if d:
                    return d
            return None
        if isinstance(x, list) and isinstance(y, list):
            if len(x) != len(y):
                return f"{path}: {len(x)} → {len(y)} items"
            for i, (u, v) in enumerate(zip(x, y, strict=True)):
                d = walk(u, v, f"{path}[{i}]")
                if d:
                    return d
            return None
        if isinstance(x, float) and isinstance(y, float) and x != x and y != y:
            return None  # both NaN
        return None if x == y else f"{path}: {x!r} → {y!r}"

    d = walk(a, b, "")
    return "identical" if d is None else f"differ first at {d}"


def with_section(path: Path, section: list[str]) -> str:
    """The results file at ``path`` with its section of the same heading (``section[0]``, up to
    its number) replaced by ``section``, or ``section`` added at its end."""
    old = path.read_text(encoding="utf-8") if path.exists() else "# Where a user waits\n"
    key = section[0].split(" (")[0]
    parts = re.split(r"(?m)^(?=## )", old)
    new = "\n".join(section) + "\n"
    for i, part in enumerate(parts):
        if part.startswith(key):
            parts[i] = new
            return "".join(parts).rstrip("\n") + "\n"
    return old.rstrip("\n") + "\n\n" + new


def flexible_section(args: argparse.Namespace) -> list[str]:
    """Section 3 of the results (and the comparison with ``--before``)."""
    n = max(1, min(args.pairs, 2))
    lines = [
        "## 3. Flexible solve CPU (model FRFs, 0.5 % noise, target ≤ 5 s with auto; process "
        "time, OPENBLAS_NUM_THREADS=1)",
        "",
    ]
    with tempfile.TemporaryDirectory(prefix="dimacq-before-") as tmp_s:
        tree = tree_of(args.before, Path(tmp_s)) if args.before else None
        if args.before:
            lines += [f"- before: commit {args.before}; after: this checkout", ""]
        for scenario in args.flexible:
            before = flexible_in_worker(n, scenario, tree) if tree is not None else None
            fl = flexible_in_worker(n, scenario)
            for mode in ("off", "auto"):
                d = fl[mode]
                was = ""
                if before is not None:
                    bd = before[mode]
                    was = (
                        f"; before: CPU {fmt(bd['cpu'])}, mass {bd['mass_kg']:.1f} kg, report "
                        f"{same_answer(bd['report'], d['report'])}"
                    )
                lines.append(
                    f"- {scenario} {' × '.join(map(str, fl['shape']))}, modal correction "
                    f"{mode}: CPU {fmt(d['cpu'])}; mass {d['mass_kg']:.1f} kg "
                    f"(truth {d['truth_kg']:.1f}), band {d['band_hz'][0]:g}–{d['band_hz'][1]:g} "
                    f"Hz, verdict {d['verdict']}, correction applied {d['applied']}{was}"
                )
                print(lines[-1], flush=True)
    return lines


def live_path(seconds: float) -> list[str]:
    """The live path at 128 channels and the most channels it sustains (bench_live_path)."""
    sys.path.insert(0, str(HERE))
    import bench_live_path

    out = []
    factors = {}
    for n_ch in (64, 128):
        cpu, wall = bench_live_path.run(n_ch, seconds)
        factors[n_ch] = cpu
        out.append(
            f"- {n_ch} channels at {bench_live_path.FS} S/s: realtime factor {cpu:.2f} (CPU), "
            f"{wall:.2f} (wall, on this loaded host)"
        )
    # cost per simulated second ≈ a + b·n: the most channels with a factor of 1
    b = (1 / factors[128] - 1 / factors[64]) / 64
    a = 1 / factors[64] - 64 * b
    # the two counts' noise can give a slope ≤ 0; then the cost is taken proportional to the
    # channels from the 128-channel figure (an underestimate of the most sustained)
    most = (1 - a) / b if b > 0 else 128 * factors[128]
    out += [
        f"- margin at 128 channels: {factors[128]:.2f}x real time (CPU, target ≥ 1)",
        f"- most channels sustained in real time on one core (cost linear in the channels): "
        f"about {most:.0f}",
    ]
    return out


def peak_rss(cmd: list[str], env: dict[str, str] | None = None) -> tuple[float | None, float, int]:
    t0 = time.perf_counter()
    p = subprocess.run(
        ["/usr/bin/time", "-v", *cmd],
        capture_output=True,
        text=True,
        env={**os.environ, **(env or {})},
        cwd=tempfile.gettempdir(),
    )
    m = re.search(r"Maximum resident set size \(kbytes\): (\d+)", p.stderr)
    return (int(m.group(1)) / 1024 if m else None), time.perf_counter() - t0, p.returncode


#: The commands of section 5 and their targets, MB of peak resident set.
MEMORY_COMMANDS: tuple[tuple[str, list[str], float], ...] = (
    (
        "dimacq loadcell calibrate --simulated --method static",
        ["dimacq", "loadcell", "calibrate", "--simulated", "--method", "static"],
        300.0,
    ),
    ("dimacq demo", ["dimacq", "demo", "--quiet"], 350.0),
)


def memory(runs: int) -> list[str]:
    """Section 5's lines: each command's peak RSS, ``runs`` times (the commands take turns)."""
    peaks: dict[str, list[float]] = {what: [] for what, _, _ in MEMORY_COMMANDS}
    lines = []
    for k in range(runs):
        for what, cmd, _ in MEMORY_COMMANDS:
            load = os.getloadavg()[0]
            rss, wall, rc = peak_rss(cmd)
            peaks[what].append(rss or 0.0)
            lines.append(
                f"- run {k + 1}: `{what}`: {rss or 0:.0f} MB peak (exit {rc}, {wall:.0f} s wall, "
                f"load average {load:.1f} at its start)"
            )
            print(lines[-1], flush=True)
    for what, _, target in MEMORY_COMMANDS:
        xs = peaks[what]
        lines.append(
            f"- `{what}`: largest {max(xs):.0f} MB, median {statistics.median(xs):.0f} MB over "
            f"{len(xs)} runs (target ≤ {target:.0f} MB)"
        )
    return lines


def memory_only(runs: int, label: str, results: Path) -> int:
    """Section 5 alone, written into the results file under ``label`` (module docstring)."""
    commit = subprocess.run(
        ["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True, cwd=ROOT
    ).stdout.strip()
    dirty = subprocess.run(
        ["git", "status", "--porcelain", "--", "dimacq", "simulators", "drivers"],
        capture_output=True,
        text=True,
        cwd=ROOT,
    ).stdout.strip()
    head = f"## 5. Peak memory, {label} (maximum resident set size, /usr/bin/time -v)"
    lines = [
        head,
        "",
        f"- command: `python tests/benchmarks/where_users_wait.py {shlex.join(sys.argv[1:])}`",
        f"- date: {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}, commit {commit}"
        + (" (with uncommitted changes)" if dirty else ""),
        f"- at start: {host_line()}",
        *memory(runs),
        f"- then: {host_line()}",
        "",
    ]
    old = results.read_text(encoding="utf-8") if results.exists() else ""
    sections = re.split(r"(?m)^(?=## )", old)
    kept = [x for x in sections if not x.startswith(head)]
    body = "".join(kept).rstrip("\n") + "\n\n" + "\n".join(lines)
    results.write_text(body, encoding="utf-8")
    print(f"wrote {results}")
    return 0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--pairs", type=int, default=5)
    ap.add_argument("--memory", action="store_true", help="also the demo's and calibrate's peak")
    ap.add_argument("--skip-flexible", action="store_true")
    ap.add_argument(
        "--only-flexible", action="store_true", help="only the flexible solve CPU (section 3)"
    )
    ap.add_argument(
        "--flexible",
        nargs="+",
        default=["x38-flexible-10", "x38-flexible-17", "x38-flexible-34", "x38"],
        help="scenarios solved (default the three X-38-like flexible vehicles and the rigid x38)",
    )
    ap.add_argument(
        "--before", metavar="REV", help="also solve them with the code of commit REV (git)"
    )
    ap.add_argument("--flexible-worker", nargs=2, help=argparse.SUPPRESS)
    ap.add_argument("--live", action="store_true", help="also the live path (bench_live_path)")
    ap.add_argument(
        "--big-json", action="store_true", help="also the X-38 size set's JSON /data (minutes)"
    )
    ap.add_argument("--live-seconds", type=float, default=2.0)
    ap.add_argument(
        "--memory-only", action="store_true", help="section 5 alone, into the results file"
    )
    ap.add_argument("--memory-runs", type=int, default=2, help="runs of each command (section 5)")
    ap.add_argument("--label", default="", help="--memory-only: the section's label")
    add_results_argument(ap, __file__)
    args = ap.parse_args()
    logging.disable(logging.WARNING)
    if args.memory_only:
        return memory_only(args.memory_runs, args.label or "this run", args.results)
    if args.flexible_worker:  # a process of its own: solve, print the figures as JSON
        print(json.dumps(flexible(int(args.flexible_worker[1]), args.flexible_worker[0])))
        return 0
    sys.path.insert(0, str(ROOT / "tests"))
    from _api_support import TOKEN, make_settings

    from dimacq.api import create_app
    from dimacq.api.server import BackgroundServer
    from dimacq.services.lab import Lab
    from dimacq.simulators.lab.scenarios import build_scenario

    commit = subprocess.run(
        ["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True, cwd=ROOT
    ).stdout.strip()
    lines = [
        "# Where a user waits",
        "",
        f"- command: `python tests/benchmarks/where_users_wait.py {' '.join(sys.argv[1:])}`",
        f"- date: {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}, commit {commit}",
        f"- at start: {host_line()}",
        "",
    ]
    if args.only_flexible:  # the results file's section 3 replaced, the others kept
        section = flexible_section(args)
        section[1:1] = lines[1:5]  # its command, date, commit and load
        section += [f"- then: {host_line()}", ""]
        args.results.write_text(with_section(args.results, section), encoding="utf-8")
        print(f"wrote {args.results}")
        return 0
    res = Results(__file__, "Where a user waits", args.results)
    res.note(f"at start: {host_line()}")
    lines: list[str] = []
    with tempfile.TemporaryDirectory(prefix="dimacq-wait-") as tmp_s:
        tmp = Path(tmp_s)
        settings = make_settings(tmp / "data", database_url="")
        lab = Lab(settings, open_devices=False)
        with (
            BackgroundServer(create_app(settings, lab=lab)) as srv,
            httpx.Client(
                base_url=srv.url, headers={"Authorization": f"Bearer {TOKEN}"}, timeout=900
            ) as c,
        ):
            sid = c.post(
                "/api/setups/import",
                params={"format": "toml"},
                content=(EXAMPLES / "six_triax_setup.toml").read_bytes(),
            ).json()["id"]
            small = c.post(
                "/api/frfs/import",
                params={"setup_id": sid},
                content=(EXAMPLES / "six_triax_frf.uff").read_bytes(),
            ).json()["id"]
            b = build_scenario("x38-flexible-17", 0)
            big_frf = b.model_frf(noise=0.005, frequencies_hz=np.linspace(0.125, 60.0, 2048))
            big_sid = lab.store.save_setup(b.setup)
            big = lab.store.save_frf(big_frf, big_sid, name="X-38 size")
            lines += ["## 1. FRF view open (page: GET the set's values; HTTP on loopback)", ""]
            lines += [
                "| set | lines × responses × inputs | JSON /data | float32 /data.f32 "
                "| ratio (JSON / f32) | server CPU of f32 (store read + encode) | bytes JSON "
                "| bytes f32 |",
                "|---|---|---|---|---|---|---|---|",
            ]
            for name, fid, shape in (
                ("shipped example (six_triax_frf.uff)", small, None),
                ("X-38 size (x38-flexible-17 model, 2048 lines)", big, big_frf.H.shape),
            ):
                r = frf_view(c, fid, args.pairs, with_json=args.big_json or fid == small)
                cpu = []
                for _ in range(args.pairs):  # the server's share: the store read and the encode
                    t0 = time.process_time()
                    lab.store.frf_values_f32(fid)
                    cpu.append(time.process_time() - t0)
                if shape is None:
                    shape = lab.store.frf(fid)[0].H.shape
                js = r["json"]
                ratio = f"{statistics.median(js) / statistics.median(r['f32']):.1f}" if js else "–"
                lines.append(
                    f"| {name} | {' × '.join(map(str, shape))} | {fmt(js) if js else 'not run'} "
                    f"| {fmt(r['f32'])} (target ≤ 1 s) | {ratio} | {statistics.median(cpu):.3f} s "
                    f"| {r['bytes_json']:,} | {r['bytes_f32']:,} |"
                )
                print(lines[-1], flush=True)
            lines += ["", f"- then: {host_line()}", ""]
            lines += ["## 2. Page solve vs CLI solve (shipped example, automatic band)", ""]
            s = solve_pair(c, small, args.pairs, tmp)
            ratio = statistics.median(s["page"]) / statistics.median(s["cli"])
            lines += [
                f"- page (`POST /api/solutions`, service running): {fmt(s['page'])}",
                f"- CLI (`{s['command']}`, a process of its own): {fmt(s['cli'])}",
                f"- ratio page / CLI: {ratio:.2f} (target ≤ 1.5); same mass from both: "
                f"{s['same_mass']}",
                f"- CPU seconds: page (the service's process: store read, solve, store write, "
                f"HTTP) {fmt(s['cpu']['page'])}, CLI (its process: start-up, UFF read, solve, "
                f"JSON) {fmt(s['cpu']['cli'])}; ratio "
                f"{statistics.median(s['cpu']['page']) / statistics.median(s['cpu']['cli']):.2f}",
                f"- then: {host_line()}",
                "",
            ]
            print("\n".join(lines[-7:]), flush=True)
        lab.close()
    if not args.skip_flexible:
        lines += flexible_section(args)
        lines += [f"- then: {host_line()}", ""]
    if args.live:
        lines += ["## 4. Live path (driver → blocks → FRF per record, one core)", ""]
        lines += live_path(args.live_seconds)
        lines += [f"- then: {host_line()}", ""]
        print("\n".join(lines[-6:]), flush=True)
    if args.memory:
        lines += ["## 5. Peak memory (maximum resident set size, /usr/bin/time -v)", ""]
        lines += memory(args.memory_runs)
        lines += [f"- then: {host_line()}", ""]
    res.add("\n".join(lines))
    res.write()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
