"""Accuracy of the estimators on realistic virtual-lab cases, against the simulator's truth.

Run on demand (several minutes on a loaded machine)::

    nice python tests/scripts/accuracy_must_show.py [--seeds 6] [--bias-seeds 12] [--json OUT]

Cases (every one solved through :func:`dimacq.services.solve.analysis.analyse`, as ``dimacq solve``):

1. Realistic rigid cases, 1 % FRF noise, the scenarios' geometry errors (2 mm positions, 0.5° triax
   orientation, 1° hammer line of action, 2 mis-mounted axes, 2 bad impacts):
   ``calibration-mass-realistic`` (band 20–100 Hz) and ``x38-realistic`` made rigid (band 7–9 Hz).
   Solvers: *plain* (equation-error DIM on every channel and input), *selection* (response and
   input selection, equation error), *refinement* (selection + output-error with geometry
   self-calibration), all in the scenario's band, and *default* (``dimacq solve`` as shipped: the
   same with the automatic band). Worst of the seeds: mass %, |CG| mm, principal moments %.
2. Errors-in-variables bias: 5 % FRF noise, true geometry, calibration mass: mean and standard
   deviation over the seeds of the mass and principal-moment errors, equation error against
   output error.
3. X-38-like vehicle with elastic modes at about 4× the top suspension frequency (suspension 3.5 Hz
   bounce → rigid-body modes up to 4.2 Hz; drogue-chute pair 17 / 24 Hz, tails 31 Hz), 0.5 % noise,
   the realistic geometry errors, band 6–13 Hz: selection only, refinement, refinement + residual
   flexibility.

Also the coverage of the 95 % intervals of the refined solution (fraction of the ten parameters and
the three principal moments of every seed whose interval holds the truth).

It writes its tables to ``accuracy_must_show_results.md`` beside it (``--results`` elsewhere).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from dimacq.model.properties import RigidBodyProperties, principal_moments
from dimacq.model.setup import PARAMETERS
from dimacq.pipeline import dim
from dimacq.services.solve.analysis import AnalysisOptions, analyse
from dimacq.simulators.lab.scenarios import Scenario, build_scenario, load_scenario

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from _results import Results, add_results_argument, fmt


def errors(params: np.ndarray, truth: RigidBodyProperties, p: np.ndarray) -> dict[str, float]:
    from dimacq.model.properties import vector_to_inertia

    est = RigidBodyProperties.from_about_point(
        float(params[0]), params[1:4], vector_to_inertia(params[4:]), p
    )
    w, _ = principal_moments(est.inertia_cg_kgm2)
    wt, _ = principal_moments(truth.inertia_cg_kgm2)
    pm = 100 * (w / wt - 1)
    return {
        "mass_pct": float(100 * (est.mass_kg / truth.mass_kg - 1)),
        "cg_mm": float(1000 * np.linalg.norm(est.cg_m - truth.cg_m)),
        "pm_pct": [float(x) for x in pm],
        "pm_max_pct": float(np.max(np.abs(pm))),
    }


def spec_with(
    name: str, article: dict[str, Any] | None = None, band=None, errors_=None
) -> Scenario:
    d = load_scenario(name).model_dump()
    d["article"].update(article or {})
    if band is not None:
        d["band"] = {"lo_hz": band[0], "hi_hz": band[1]}
    if errors_ is not None:
        d["errors"].update(errors_)
    return Scenario.model_validate(d)


def run_case(spec: Scenario, seed: int, noise: float, method: str, true_geometry: bool = False):
    b = build_scenario(spec, seed)
    frf = b.model_frf(noise=noise)
    setup = b.model.setup if true_geometry else b.setup
    if true_geometry:  # the true geometry, stated as exact as the scenario's errors say
        setup = setup.model_copy(update={"geometry_uncertainty": b.setup.geometry_uncertainty})
    t0 = time.perf_counter()
    coverage = None
    if method == "plain":
        res = dim.solve(frf, setup, band_hz=b.band_hz)
        params = res.parameters
    elif method == "default":  # everything as `dimacq solve` does it, band chosen automatically
        rep = analyse(frf, setup, AnalysisOptions())
        params = rep.result.parameters
        coverage = _coverage(rep, b.truth, setup)
    else:
        sel = method != "oe-only" and method != "ee-only"
        opts = AnalysisOptions(
            select_responses=sel,
            select_inputs=sel,
            band_hz=b.band_hz,
            unbiased=method not in ("selection", "ee-only"),
            refine_geometry=method in ("refinement", "refinement+rf"),
            residual_flexibility=method == "refinement+rf",
        )
        rep = analyse(frf, setup, opts)
        params = rep.result.parameters
        coverage = _coverage(rep, b.truth, setup)
    dt = time.perf_counter() - t0
    out = errors(params, b.truth, setup.reference_point)
    out["time_s"] = dt
    out["coverage95"] = coverage
    if method != "plain":  # what the data support: the 95 % half-widths the solve states
        pu = rep.uncertainty
        out["pm_halfwidth95_pct"] = float(
            max(50 * (p.ci95[1] - p.ci95[0]) / p.value for p in pu.principal)
        )
        out["cg_halfwidth95_mm"] = float(
            np.linalg.norm([500 * np.subtract(*pu.parameters[k].ci95[::-1]) for k in CG_KEYS])
        )
    return out


CG_KEYS = ("cx", "cy", "cz")


def _coverage(rep: Any, truth: RigidBodyProperties, setup: Any) -> float:
    """Share of the ten parameters and the three principal moments whose 95 % interval holds
    the truth."""
    truth_vec = truth.parameter_vector(setup.reference_point)
    truth_vec[1:4] = truth.cg_m
    wt, _ = principal_moments(truth.inertia_cg_kgm2)
    ci = [rep.uncertainty.parameters[k].ci95 for k in PARAMETERS]
    ci += [p.ci95 for p in rep.uncertainty.principal]
    vals = [*truth_vec, *wt]
    return float(np.mean([lo <= t <= hi for (lo, hi), t in zip(ci, vals, strict=True)]))


def worst(rows: list[dict[str, Any]]) -> dict[str, float]:
    return {
        "mass_pct": max(abs(r["mass_pct"]) for r in rows),
        "cg_mm": max(r["cg_mm"] for r in rows),
        "pm_pct": max(r["pm_max_pct"] for r in rows),
        "time_s_median": float(np.median([r["time_s"] for r in rows])),
        "pm_halfwidth95_pct_median": _median(rows, "pm_halfwidth95_pct"),
        "cg_halfwidth95_mm_median": _median(rows, "cg_halfwidth95_mm"),
    }


def _median(rows: list[dict[str, Any]], key: str) -> float | None:
    v = [r[key] for r in rows if r.get(key) is not None]
    return float(np.median(v)) if v else None


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=6)
    ap.add_argument("--bias-seeds", type=int, default=12)
    ap.add_argument("--json", type=Path)
    ap.add_argument("--only", choices=("rigid", "bias", "flexible"), default=None)
    ap.add_argument(
        "--methods",
        nargs="+",
        default=["plain", "selection", "refinement", "default"],
        choices=("plain", "selection", "refinement", "default"),
        help="plain: equation error on all data; selection: + response/input selection; "
        "refinement: + output error with the geometry refined (scenario band); default: "
        "`dimacq solve` as shipped (automatic band)",
    )
    add_results_argument(ap, __file__)
    args = ap.parse_args()
    res = Results(__file__, "Accuracy of the estimators on the realistic scenarios", args.results)
    report: dict[str, Any] = {}
    rigid_rows: list[list[str]] = []
    bias_rows: list[list[str]] = []
    flex_rows: list[list[str]] = []

    if args.only in (None, "rigid"):
        cases = {
            "calibration mass (realistic)": spec_with("calibration-mass-realistic"),
            "X-38-sized vehicle, rigid (realistic)": spec_with(
                "x38-realistic", {"flexible": False}
            ),
        }
        for label, spec in cases.items():
            for method in args.methods:
                rows = [run_case(spec, s, 0.01, method) for s in range(args.seeds)]
                w = worst(rows)
                cov = [r["coverage95"] for r in rows if r["coverage95"] is not None]
                w["coverage95"] = float(np.mean(cov)) if cov else None
                report[f"{label} / {method}"] = {"worst": w, "seeds": rows}
                rigid_rows.append([label, method, *_worst_cells(w)])
                print(
                    f"{label:40s} {method:11s} worst of {args.seeds}: mass {w['mass_pct']:.3f} %, "
                    f"CG {w['cg_mm']:.2f} mm, principal moments {w['pm_pct']:.3f} %, "
                    f"median time {w['time_s_median']:.2f} s"
                    + (f", 95 % coverage {w['coverage95']:.2f}" if cov else "")
                    + (
                        f"; stated 95 % half-widths (median): principal moments "
                        f"{w['pm_halfwidth95_pct_median']:.2f} %, |CG| "
                        f"{w['cg_halfwidth95_mm_median']:.2f} mm"
                        if w["pm_halfwidth95_pct_median"] is not None
                        else ""
                    ),
                    flush=True,
                )

    if args.only in (None, "bias"):
        spec = spec_with("calibration-mass-realistic")
        for method, label in (("ee-only", "equation error"), ("oe-only", "output error")):
            rows = [
                run_case(spec, s, 0.05, method, true_geometry=True) for s in range(args.bias_seeds)
            ]
            m = np.array([r["mass_pct"] for r in rows])
            pm = np.array([r["pm_pct"] for r in rows])
            stats = {
                "mass_mean_pct": float(m.mean()),
                "mass_std_pct": float(m.std(ddof=1)),
                "pm_mean_pct": pm.mean(axis=0).tolist(),
                "pm_std_pct": pm.std(axis=0, ddof=1).tolist(),
            }
            report[f"bias 5 % noise / {label}"] = stats
            bias_rows.append(
                [
                    label,
                    f"{stats['mass_mean_pct']:+.3f}",
                    f"{stats['mass_std_pct']:.3f}",
                    f"{abs(stats['mass_mean_pct']) / stats['mass_std_pct']:.2f}",
                    ", ".join(
                        f"{abs(a) / b:.2f}"
                        for a, b in zip(stats["pm_mean_pct"], stats["pm_std_pct"], strict=True)
                    ),
                ]
            )
            print(
                f"5 % noise, true geometry, {args.bias_seeds} seeds, {label:15s}: mass mean "
                f"{stats['mass_mean_pct']:+.3f} % sd {stats['mass_std_pct']:.3f} % "
                f"(|mean|/sd {abs(stats['mass_mean_pct']) / stats['mass_std_pct']:.2f}); "
                "principal moments |mean|/sd "
                + ", ".join(
                    f"{abs(a) / b:.2f}"
                    for a, b in zip(stats["pm_mean_pct"], stats["pm_std_pct"], strict=True)
                ),
                flush=True,
            )

    if args.only in (None, "flexible"):
        spec = spec_with(
            "x38-realistic",
            {
                "flexible": True,
                "suspension_hz": 3.5,
                "chute_modes_hz": (17.0, 24.0),
                "deformation_mode_hz": 31.0,
            },
            band=(6.0, 13.0),
        )
        for method in [m for m in args.methods if m != "plain"] + ["refinement+rf"]:
            rows = [run_case(spec, s, 0.005, method) for s in range(args.seeds)]
            w = worst(rows)
            report[f"x38 flexible / {method}"] = {"worst": w, "seeds": rows}
            cov = [r["coverage95"] for r in rows if r["coverage95"] is not None]
            w["coverage95"] = float(np.mean(cov)) if cov else None
            flex_rows.append([method, *_worst_cells(w)])
            print(
                f"X-38 elastic modes 17/24/31 Hz, suspension ≤ 4.2 Hz, 0.5 % noise, {method:13s} "
                f"worst of {args.seeds}: mass {w['mass_pct']:.3f} %, CG {w['cg_mm']:.2f} mm, "
                f"principal moments {w['pm_pct']:.3f} %",
                flush=True,
            )
    _write_results(res, args, rigid_rows, bias_rows, flex_rows)
    if args.json:
        args.json.write_text(json.dumps(report, indent=2) + "\n", encoding="utf-8")


def _worst_cells(w: dict[str, Any]) -> list[str]:
    """Table cells of one case's worst-of-seeds figures."""
    return [
        f"{w['mass_pct']:.3f}",
        f"{w['cg_mm']:.2f}",
        f"{w['pm_pct']:.3f}",
        f"{w['time_s_median']:.2f}",
        fmt(w.get("coverage95"), ".2f"),
        fmt(w["pm_halfwidth95_pct_median"], ".2f"),
        fmt(w["cg_halfwidth95_mm_median"], ".2f"),
    ]


_WORST = [
    "worst mass %",
    "worst \\|CG\\| mm",
    "worst principal %",
    "median solve s",
    "95 % coverage",
    "stated 95 % half-width, principal % (median)",
    "\\|CG\\| mm (median)",
]


def _write_results(
    res: Results,
    args: argparse.Namespace,
    rigid: list[list[str]],
    bias: list[list[str]],
    flex: list[list[str]],
) -> None:
    """The three studies' tables, into the results file."""
    res.add(
        "Every case solved through `analyse` as `dimacq solve` does; errors against the "
        "simulator's truth. *plain*: equation-error DIM on every channel and input; *selection*: "
        "response and input selection; *refinement*: selection + output error with geometry "
        "refinement (scenario band); *default*: `dimacq solve` as shipped (automatic band). "
        "Coverage: share of the ten parameters and three principal moments whose 95 % interval "
        "holds the truth."
    )
    if rigid:
        res.table(
            ["case", "solver", *_WORST],
            rigid,
            f"Rigid cases, 1 % FRF noise, the scenarios' geometry errors (worst of {args.seeds} "
            "seeds)",
        )
    if bias:
        res.table(
            ["estimator", "mass mean %", "mass sd %", "mass \\|mean\\|/sd"]
            + ["principal moments \\|mean\\|/sd"],
            bias,
            f"Errors-in-variables bias: 5 % FRF noise, true geometry, calibration mass "
            f"({args.bias_seeds} seeds)",
        )
    if flex:
        res.table(
            ["solver", *_WORST],
            flex,
            "X-38-like, elastic modes 17 / 24 / 31 Hz, suspension ≤ 4.2 Hz, 0.5 % noise, "
            f"band 6–13 Hz (worst of {args.seeds} seeds)",
        )
    res.write()


if __name__ == "__main__":
    main()
