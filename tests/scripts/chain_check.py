"""The measured chain, end to end: every impact-test scenario of ``config/scenarios/``
acquired through the simulated devices on several seeds, then solved with no flags, each result
against its truth.

For each scenario and seed, as a user would type them::

    dimacq acquire SCENARIO --seed S --averages-per-input N --frf F.uff --json A.json -q
    dimacq solve F.uff --json S.json                # no flags: the defaults
    dimacq simulate SCENARIO --seed S --frf junk.uff --truth T.json   # the truth, for this script

and then, from the JSON files only (the comparison with the truth is this script's, never the
solver's): the errors of mass (%), |CG| (mm) and the largest principal moment (%); how many of the
ten parameters (m, CG, inertia about P) and of the three principal moments have a 95 % interval
holding the truth; ``miss`` (how far the truth lies beyond the farthest edge, in half-widths);
the verdict and exit status of the solve. ``ok-miss`` counts answers reported ``ok`` whose truth
lies outside an interval by more than half its half-width; ``refused`` the solves that exited 3.

Run on demand (about a minute of simulated acquisition per calibration-mass case on the
simulated DAQ's default time-lapse; ``--jobs`` runs cases side by side)::

    python tests/scripts/chain_check.py [--scenarios a,b] [--seeds 0,1,2] [--averages 3]
        [--jobs 2] [--json OUT] [--keep DIR [--reuse]]

It writes its tables to ``chain_check_results.md`` beside it (``--results`` elsewhere).
``tests/cli/test_chain_check.py`` runs the short version in CI.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "tests"))
from _results import Results, add_results_argument  # noqa: E402

#: Scenarios that describe an impact test on a structure free enough for DIM (the others: on the
#: ground or a cube family, which the default solve refuses by design, are listed by --all).
DEFAULT_SCENARIOS = (
    "calibration-mass-bungee",
    "calibration-mass-realistic",
    "calibration-mass-air-ride",
    "reference-block-bungee",
    "x38-realistic",
)
PARAMETERS = ("m", "cx", "cy", "cz", "Ixx", "Ixy", "Ixz", "Iyy", "Iyz", "Izz")


def _dimacq(*args: str) -> subprocess.CompletedProcess[str]:
    code = "import sys; from dimacq.cli.main import main; sys.exit(main(sys.argv[1:]))"
    return subprocess.run(
        [sys.executable, "-c", code, *args], capture_output=True, text=True, check=False
    )


def truth_vector(truth: dict[str, Any], p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The ten parameters (CG in the GCS, inertia about ``p``) and the principal moments."""
    from dimacq.model.properties import RigidBodyProperties, principal_moments

    rb = RigidBodyProperties(
        mass_kg=float(truth["mass_kg"]),
        cg_m=tuple(truth["cg_m"]),
        inertia_cg_kgm2=np.asarray(truth["inertia_cg_kgm2"], float),
    )
    v = rb.parameter_vector(p)
    v[1:4] = rb.cg_m
    w, _ = principal_moments(rb.inertia_cg_kgm2)
    return v, np.asarray(w, float)


def compare(sol: dict[str, Any], truth: dict[str, Any]) -> dict[str, Any]:
    """Errors, coverage and misses of one solve's JSON against its truth's."""
    p = np.asarray(sol["reference_point_m"], float)
    tv, tw = truth_vector(truth, p)
    unc = sol["uncertainty"]
    ci = [unc[k]["ci95"] for k in PARAMETERS] + [u["ci95"] for u in unc["principal_moments"]]
    beyond = []
    for (lo, hi), t in zip(ci, [*tv, *tw], strict=True):
        half = (hi - lo) / 2
        beyond.append(max(lo - t, t - hi, 0.0) / half if half > 0 else float("inf"))
    w = np.asarray(sol["principal_moments_kgm2"], float)
    return {
        "verdict": sol["verdict"],
        "band_hz": sol["band_hz"],
        "mass_pct": 100 * (sol["mass_kg"] / tv[0] - 1),
        "cg_mm": 1000 * float(np.linalg.norm(np.asarray(sol["cg_m"]) - tv[1:4])),
        "pm_max_pct": float(np.max(np.abs(100 * (w / tw - 1)))),
        "covered": int(sum(b == 0 for b in beyond)),
        "n_intervals": len(beyond),
        "covered_parameters": int(sum(b == 0 for b in beyond[:10])),
        "miss": float(max(beyond)),
        "warn_reasons": [r["check"] for r in sol["verdict_reasons"] if r["severity"] == "warn"],
    }


def one(scenario: str, seed: int, averages: int, work: Path, reuse: bool = False) -> dict[str, Any]:
    """Acquire, solve and compare one case (files in ``work``; ``reuse``: an acquisition
    already there is solved again, not repeated)."""
    stem = work / f"{scenario}-s{seed}-a{averages}"
    out: dict[str, Any] = {"scenario": scenario, "seed": seed, "averages": averages}
    t0 = time.monotonic()
    uff = stem.with_suffix(".uff")
    if reuse and uff.is_file():
        acq = subprocess.CompletedProcess([], 0, "", "")
    else:
        acq = _dimacq(
            "acquire", scenario, "--seed", str(seed), "--averages-per-input", str(averages),
            "--frf", str(uff), "--json", str(stem) + "-acquire.json", "-q",
        )  # fmt: skip
    out["acquire_s"] = time.monotonic() - t0
    if acq.returncode != 0:
        out.update(status="acquire failed", error=(acq.stderr.strip().splitlines() or ["?"])[-1])
        return out
    tr = _dimacq(
        "simulate", scenario, "--seed", str(seed), "--frf", str(stem) + "-model.uff",
        "--truth", str(stem) + "-truth.json",
    )  # fmt: skip
    if tr.returncode != 0:
        out.update(status="truth failed", error=tr.stderr.strip()[-300:])
        return out
    t1 = time.monotonic()
    sol_path = Path(str(stem) + "-solve.json")
    sv = _dimacq("solve", str(uff), "--json", str(sol_path))
    out["solve_s"] = time.monotonic() - t1
    out["exit"] = sv.returncode
    if sv.returncode not in (0, 3) or not sol_path.is_file():
        out.update(status="solve error", error=(sv.stderr.strip().splitlines() or ["?"])[-1])
        return out
    sol = json.loads(sol_path.read_text(encoding="utf-8"))
    truth = json.loads(Path(str(stem) + "-truth.json").read_text(encoding="utf-8"))
    out.update(compare(sol, truth))
    out["status"] = "refused" if sv.returncode == 3 else "solved"
    if sv.returncode == 3:
        out["reason"] = [r["message"] for r in sol["verdict_reasons"] if r["severity"] == "fail"]
    return out


def summarise(rows: list[dict[str, Any]]) -> dict[str, Any]:
    solved = [r for r in rows if r.get("status") == "solved"]
    refused = [r for r in rows if r.get("status") == "refused"]
    failed = [r for r in rows if r.get("status") not in ("solved", "refused")]
    cov = sum(r["covered"] for r in solved)
    n = sum(r["n_intervals"] for r in solved)
    return {
        "cases": len(rows),
        "solved": len(solved),
        "refused": len(refused),
        "errors": len(failed),
        "coverage95": cov / n if n else float("nan"),
        "ok_miss": sum(r["verdict"] == "ok" and r["miss"] > 0.5 for r in solved),
        "worst_mass_pct": max((abs(r["mass_pct"]) for r in solved), default=float("nan")),
        "worst_cg_mm": max((r["cg_mm"] for r in solved), default=float("nan")),
        "worst_pm_pct": max((r["pm_max_pct"] for r in solved), default=float("nan")),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenarios", default=",".join(DEFAULT_SCENARIOS))
    ap.add_argument("--seeds", default="0,1,2")
    ap.add_argument("--averages", type=int, default=3)
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--json", type=Path)
    ap.add_argument("--keep", type=Path, help="keep the files in DIR")
    ap.add_argument(
        "--reuse", action="store_true", help="with --keep: solve acquisitions already in DIR again"
    )
    add_results_argument(ap, __file__)
    a = ap.parse_args()
    res = Results(__file__, "The measured chain: acquire, solve with no flags, compare", a.results)
    seeds = [int(s) for s in a.seeds.split(",")]
    cases = [(s, seed) for s in a.scenarios.split(",") for seed in seeds]
    with tempfile.TemporaryDirectory() as tmp:
        work = a.keep or Path(tmp)
        work.mkdir(parents=True, exist_ok=True)
        with ThreadPoolExecutor(max_workers=max(1, a.jobs)) as ex:
            rows = list(ex.map(lambda c: one(c[0], c[1], a.averages, work, a.reuse), cases))
    for r in rows:
        if r.get("status") in ("solved", "refused"):
            print(
                f"  {r['scenario']:28s} seed {r['seed']}: {r['status']:7s} {r['verdict']:4s} "
                f"band {r['band_hz'][0]:g}–{r['band_hz'][1]:g} Hz  mass {r['mass_pct']:+.3f} %  "
                f"CG {r['cg_mm']:.2f} mm  principal {r['pm_max_pct']:.3f} %  intervals "
                f"{r['covered']}/{r['n_intervals']} (parameters {r['covered_parameters']}/10)  "
                f"miss {r['miss']:.2f}  acquire {r['acquire_s']:.0f} s  solve {r['solve_s']:.1f} s"
            )
        else:
            print(f"  {r['scenario']:28s} seed {r['seed']}: {r['status']}: {r.get('error')}")
    by: dict[str, list[dict[str, Any]]] = {}
    for r in rows:
        by.setdefault(r["scenario"], []).append(r)
    summary = {name: summarise(rs) for name, rs in by.items()}
    summary["all"] = summarise(rows)
    for name, s in summary.items():
        print(
            f"{name}: {s['solved']} solved, {s['refused']} refused, {s['errors']} errors; worst "
            f"mass {s['worst_mass_pct']:.3f} %, CG {s['worst_cg_mm']:.2f} mm, principal "
            f"{s['worst_pm_pct']:.3f} %; coverage {s['coverage95']:.2f}; ok-miss {s['ok_miss']}"
        )
    _write_results(res, a.averages, rows, summary)
    if a.json:
        a.json.write_text(json.dumps({"rows": rows, "summary": summary}, indent=2) + "\n")


def _write_results(
    res: Results, averages: int, rows: list[dict[str, Any]], summary: dict[str, Any]
) -> None:
    """The per-scenario summary and the per-case rows, into the results file."""
    res.add(
        f"`dimacq acquire SCENARIO --seed S --averages-per-input {averages}` through the simulated "
        "devices (their default imperfections on), then `dimacq solve F.uff --json S.json` with no "
        "flags; each answer against the scenario's truth. Intervals: the ten parameters and the "
        "three principal moments (13 per case); ok-miss: `ok` answers whose truth lies beyond an "
        "interval by more than half its half-width."
    )
    res.table(
        ["scenario", "solved", "refused", "errors", "worst mass %", "worst \\|CG\\| mm"]
        + ["worst principal %", "95 % coverage", "ok-miss"],
        [
            [
                name if name == "all" else f"`{name}`",
                s["solved"],
                s["refused"],
                s["errors"],
                f"{s['worst_mass_pct']:.3f}",
                f"{s['worst_cg_mm']:.2f}",
                f"{s['worst_pm_pct']:.3f}",
                f"{s['coverage95']:.2f}",
                s["ok_miss"],
            ]
            for name, s in summary.items()
        ],
        "Per scenario",
    )
    cases = []
    for r in rows:
        if r.get("status") in ("solved", "refused"):
            cases.append(
                [
                    f"`{r['scenario']}`",
                    r["seed"],
                    f"{r['status']} {r['verdict']}",
                    f"{r['band_hz'][0]:g}–{r['band_hz'][1]:g}",
                    f"{r['mass_pct']:+.3f}",
                    f"{r['cg_mm']:.2f}",
                    f"{r['pm_max_pct']:.3f}",
                    f"{r['covered']}/{r['n_intervals']}",
                    f"{r['miss']:.2f}",
                    f"{r['acquire_s']:.0f}",
                    f"{r['solve_s']:.1f}",
                ]
            )
        else:
            cases.append([f"`{r['scenario']}`", r["seed"], f"{r['status']}: {r.get('error')}"])
            cases[-1] += [""] * 8
    res.table(
        ["scenario", "seed", "answer", "band Hz", "mass %", "\\|CG\\| mm", "principal %"]
        + ["intervals holding the truth", "miss", "acquire s", "solve s"],
        cases,
        "Per case",
    )
    res.write()


if __name__ == "__main__":
    main()
