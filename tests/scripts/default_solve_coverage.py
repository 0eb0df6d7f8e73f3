"""Default ``dimacq solve`` (``analyse`` with its defaults: automatic band, selection, refinement)
over virtual-lab scenarios and seeds: errors, verdicts, 95 % coverage, and ``ok`` answers whose
truth lies outside an interval (the comparison with the simulator's truth is this script's, never
the solver's).

For each seed: the errors of mass (%), |CG| (mm) and the largest principal moment (%); the share of
the mass, the three CG coordinates and the three principal moments whose 95 % interval holds the
truth; ``miss``, how far the truth lies beyond the farthest interval edge, in half-widths.
``ok-miss`` counts the seeds with verdict ``ok`` and ``miss > 0.5``.

Run on demand (a few seconds per solve)::

    python tests/scripts/default_solve_coverage.py [--cases x38,cm-realistic] [--seeds 6]
        [--noise 0.03] [--options '{"residual_flexibility": true}']

It writes its tables to ``default_solve_coverage_results.md`` beside it (``--results``
elsewhere).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
from accuracy_must_show import errors, spec_with  # type: ignore[import-not-found]

from dimacq.model.properties import principal_moments
from dimacq.model.setup import PARAMETERS
from dimacq.services.solve.analysis import AnalysisOptions, analyse
from dimacq.simulators.lab.scenarios import build_scenario

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from _results import Results, add_results_argument

FLEXIBLE_35 = {
    "flexible": True,
    "suspension_hz": 3.5,
    "chute_modes_hz": (17.0, 24.0),
    "deformation_mode_hz": 31.0,
}
#: name → (scenario, article overrides, FRF noise)
CASES: dict[str, tuple[str, dict[str, Any] | None, float]] = {
    "x38": ("x38", None, 0.01),
    "x38-realistic": ("x38-realistic", None, 0.01),
    "x38-rigid-realistic": ("x38-realistic", {"flexible": False}, 0.01),
    "x38-flex3.5": ("x38-realistic", FLEXIBLE_35, 0.005),
    "cm-realistic": ("calibration-mass-realistic", None, 0.01),
    "cm-bungee": ("calibration-mass-bungee", None, 0.01),
    "cm-air-ride": ("calibration-mass-air-ride", None, 0.01),
    "cm-ground": ("calibration-mass-ground", None, 0.01),
    "refblock": ("reference-block-bungee", None, 0.01),
    "cube-2": ("cube-2", None, 0.01),
}


def one(name: str, seed: int, noise: float | None, options: dict[str, Any]) -> dict[str, Any]:
    scenario, article, default_noise = CASES[name]
    b = build_scenario(spec_with(scenario, article), seed)
    frf = b.model_frf(noise=default_noise if noise is None else noise)
    t0 = time.perf_counter()
    rep = analyse(frf, b.setup, AnalysisOptions(**options))
    took = time.perf_counter() - t0
    e = errors(rep.result.parameters, b.truth, b.setup.reference_point)
    truth = b.truth.parameter_vector(b.setup.reference_point)
    truth[1:4] = b.truth.cg_m
    wt, _ = principal_moments(b.truth.inertia_cg_kgm2)
    ci = [rep.uncertainty.parameters[k].ci95 for k in PARAMETERS[:4]]
    ci += [p.ci95 for p in rep.uncertainty.principal]
    beyond = []
    for (lo, hi), t in zip(ci, [*truth[:4], *wt], strict=True):
        half = (hi - lo) / 2
        beyond.append(max(lo - t, t - hi, 0.0) / half if half > 0 else np.inf)
    return {
        "seed": seed,
        "band_hz": list(rep.result.band_hz),
        "verdict": rep.verdict,
        "mass_pct": e["mass_pct"],
        "cg_mm": e["cg_mm"],
        "pm_max_pct": e["pm_max_pct"],
        "coverage95": float(np.mean([b_ == 0 for b_ in beyond])),
        "miss": float(max(beyond)),
        "time_s": took,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", default=",".join(CASES), help="comma-separated: " + ", ".join(CASES))
    ap.add_argument("--seeds", type=int, default=6)
    ap.add_argument("--noise", type=float, default=None, help="FRF noise (default: the case's)")
    ap.add_argument("--options", default="{}", help="AnalysisOptions as JSON")
    ap.add_argument("--json", type=Path)
    add_results_argument(ap, __file__)
    args = ap.parse_args()
    options = json.loads(args.options)
    res = Results(__file__, "The default solve: errors, verdicts and 95 % coverage", args.results)
    report: dict[str, Any] = {}
    summary: list[list[str]] = []
    per_seed: list[list[str]] = []
    for name in args.cases.split(","):
        rows = []
        for s in range(args.seeds):
            r = one(name, s, args.noise, options)
            rows.append(r)
            print(
                f"  {name} seed {s}: band {r['band_hz'][0]:g}–{r['band_hz'][1]:g} Hz "
                f"{r['verdict']:5s} mass {r['mass_pct']:+.3f} % CG {r['cg_mm']:.2f} mm principal "
                f"{r['pm_max_pct']:.3f} % coverage {r['coverage95']:.2f} miss {r['miss']:.2f} "
                f"({r['time_s']:.1f} s)",
                flush=True,
            )
            per_seed.append(
                [
                    f"`{name}`",
                    str(s),
                    f"{r['band_hz'][0]:g}–{r['band_hz'][1]:g}",
                    r["verdict"],
                    f"{r['mass_pct']:+.3f}",
                    f"{r['cg_mm']:.2f}",
                    f"{r['pm_max_pct']:.3f}",
                    f"{r['coverage95']:.2f}",
                    f"{r['miss']:.2f}",
                    f"{r['time_s']:.1f}",
                ]
            )
        ok_miss = sum(1 for r in rows if r["verdict"] == "ok" and r["miss"] > 0.5)
        print(
            f"{name}: worst of {len(rows)}: mass {max(abs(r['mass_pct']) for r in rows):.3f} % "
            f"CG {max(r['cg_mm'] for r in rows):.2f} mm principal "
            f"{max(r['pm_max_pct'] for r in rows):.3f} %; verdicts "
            + ",".join(r["verdict"] for r in rows)
            + f"; coverage {np.mean([r['coverage95'] for r in rows]):.2f}; ok-miss {ok_miss}",
            flush=True,
        )
        report[name] = rows
        _, _, default_noise = CASES[name]
        summary.append(
            [
                f"`{name}`",
                f"{100 * (default_noise if args.noise is None else args.noise):g} %",
                str(len(rows)),
                f"{max(abs(r['mass_pct']) for r in rows):.3f}",
                f"{max(r['cg_mm'] for r in rows):.2f}",
                f"{max(r['pm_max_pct'] for r in rows):.3f}",
                ", ".join(r["verdict"] for r in rows),
                f"{np.mean([r['coverage95'] for r in rows]):.2f}",
                str(ok_miss),
            ]
        )
    res.add(
        "`analyse` with its defaults (automatic band, selection, output error with geometry "
        f"refinement){'' if not options else f', options `{json.dumps(options)}`'}, on the "
        "scenario's model FRFs. Coverage: share of mass, CG (3) and principal moments (3) whose "
        "95 % interval holds the truth; miss: how far the truth lies beyond the farthest interval "
        "edge, in half-widths; ok-miss: seeds with verdict `ok` and miss > 0.5."
    )
    res.table(
        [
            "case",
            "noise",
            "seeds",
            "worst mass %",
            "worst \\|CG\\| mm",
            "worst principal %",
            "verdicts",
            "coverage",
            "ok-miss",
        ],
        summary,
        "Worst of the seeds",
    )
    res.table(
        ["case", "seed", "band Hz", "verdict", "mass %", "\\|CG\\| mm", "principal %"]
        + ["coverage", "miss", "solve s"],
        per_seed,
        "Per seed",
    )
    res.write()
    if args.json:
        args.json.write_text(json.dumps(report, indent=2) + "\n", encoding="utf-8")


if __name__ == "__main__":
    main()
