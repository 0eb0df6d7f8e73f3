"""The modal-model correction on model FRFs: DIM as measured (``--modal-correction off``), DIM with the modal correction
(the default, ``auto``), and the mass-line cross-check (from the default solve), on the same
cases, with their errors against the truth and their CPU time.

Cases: flexible X-38-like vehicles (``config/scenarios/x38-flexible-{10,17,34}.toml``: 8 089 kg on
three load cells over air-ride springs, suspension modes up to 4.8 Hz; hull bending, torsion and
lateral modes at 10/14/19, 17/24/31 and 34/48/62 Hz, modal mass one fifth of the vehicle's, 2 %
damping; 1–60 Hz), the shipped ``x38`` (chute pair and tails) and the rigid
``calibration-mass-bungee``; model FRFs with relative noise (0.5 % on the vehicles, 1 % on the
calibration mass).

Run on demand (about a minute of CPU per case and seed)::

    nice python tests/scripts/modal_must_show.py [--seeds 0 1 2] [--cases x38-flexible-17 ...]
           [--json OUT] [--results PATH]

The table goes to ``modal_must_show_results.md`` beside this script (``--results`` elsewhere)
with the command, date, commit and machine load.
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from _results import Results, add_results_argument, fmt

from dimacq.model.properties import RigidBodyProperties, principal_moments
from dimacq.model.setup import PARAMETERS
from dimacq.services.solve.analysis import AnalysisOptions, analyse
from dimacq.simulators.lab.scenarios import build_scenario

CASES = {
    "x38-flexible-10": 0.005,
    "x38-flexible-17": 0.005,
    "x38-flexible-34": 0.005,
    "x38": 0.005,
    "calibration-mass-bungee": 0.01,
}


def _errors(mass: float, cg: Any, inertia_cg: Any, truth: RigidBodyProperties) -> dict[str, float]:
    w, _ = principal_moments(np.asarray(inertia_cg, float))
    wt, _ = principal_moments(truth.inertia_cg_kgm2)
    return {
        "mass_pct": 100 * (mass / truth.mass_kg - 1),
        "cg_mm": 1000 * float(np.linalg.norm(np.asarray(cg, float) - truth.cg_m)),
        "pm_pct": float(np.max(np.abs(100 * (w / wt - 1)))),
    }


def _coverage(out: dict[str, Any], truth: RigidBodyProperties, p: np.ndarray) -> tuple[int, int]:
    tv = truth.parameter_vector(p)
    tv[1:4] = truth.cg_m
    u = out["uncertainty"]
    hold = [u[k]["ci95"][0] <= tv[i] <= u[k]["ci95"][1] for i, k in enumerate(PARAMETERS)]
    wt, _ = principal_moments(truth.inertia_cg_kgm2)
    hold += [
        x["ci95"][0] <= wt[i] <= x["ci95"][1] for i, x in enumerate(u.get("principal_moments", []))
    ]
    return int(sum(hold)), len(hold)


def run(case: str, seed: int) -> dict[str, Any]:
    b = build_scenario(case, seed)
    frf = b.model_frf(noise=CASES[case])
    row: dict[str, Any] = {"case": case, "seed": seed, "noise": CASES[case]}
    for mode in ("off", "auto"):
        t0 = time.process_time()
        rep = analyse(frf, b.setup, AnalysisOptions(modal_correction=mode))
        cpu = time.process_time() - t0
        out = rep.to_json()
        p = rep.result.properties
        row[mode] = {
            **_errors(p.mass_kg, p.cg_m, p.inertia_cg_kgm2, b.truth),
            "verdict": rep.verdict,
            "band_hz": list(rep.result.band_hz),
            "cpu_s": cpu,
            "coverage": _coverage(out, b.truth, np.asarray(b.setup.reference_point, float)),
            "refusal": [r.message for r in rep.verdict_reasons if r.severity == "fail"],
        }
        mc = out.get("modal_correction")
        if mode == "auto":
            row[mode]["applied"] = bool(mc and mc["applied"])
            row[mode]["reason"] = mc["reason"] if mc else ""
            row[mode]["modes_removed_hz"] = mc.get("modes_removed_hz", []) if mc else []
            cc = out.get("cross_check") or {}
            if cc.get("mass_kg") is not None:
                row["cross_check"] = _errors(
                    cc["mass_kg"], cc["cg_m"], cc["inertia_cg_kgm2"], b.truth
                )
    return row


def table_rows(rows: list[dict[str, Any]]) -> list[tuple[Any, ...]]:
    """One line per case, seed and solve (as measured, corrected, the mass-line cross-check)."""
    out: list[tuple[Any, ...]] = []
    for r in rows:
        for m in ("off", "auto"):
            d = r[m]
            out.append(
                (
                    r["case"],
                    r["seed"],
                    f"{r['noise'] * 100:g} %",
                    "as measured (off)" if m == "off" else "corrected (auto)",
                    d["verdict"],
                    f"{d['band_hz'][0]:g}–{d['band_hz'][1]:g}",
                    fmt(d["mass_pct"], "+.3f"),
                    fmt(d["cg_mm"], ".2f"),
                    fmt(d["pm_pct"], ".3f"),
                    f"{d['coverage'][0]}/{d['coverage'][1]}",
                    fmt(d["cpu_s"], ".1f"),
                    ("yes" if d.get("applied") else "no") if m == "auto" else "—",
                )
            )
        if "cross_check" in r:
            c = r["cross_check"]
            out.append(
                (
                    r["case"],
                    r["seed"],
                    f"{r['noise'] * 100:g} %",
                    "mass-line cross-check",
                    "—",
                    "—",
                    fmt(c["mass_pct"], "+.3f"),
                    fmt(c["cg_mm"], ".2f"),
                    fmt(c["pm_pct"], ".3f"),
                    "—",
                    "—",
                    "—",
                )
            )
    return out


HEADER = [
    "case",
    "seed",
    "noise",
    "solve",
    "verdict",
    "band Hz",
    "mass %",
    "CG mm",
    "principal moments % (largest)",
    "95 % intervals holding the truth",
    "CPU s",
    "correction applied",
]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[0])
    ap.add_argument("--cases", nargs="+", default=list(CASES))
    ap.add_argument("--json", type=Path)
    add_results_argument(ap, __file__)
    args = ap.parse_args()
    res = Results(__file__, "The modal-model correction on model FRFs", args.results)
    res.note("errors against the scenario's truth; model FRFs with relative noise")
    logging.disable(logging.WARNING)
    rows = []
    for case in args.cases:
        for seed in args.seeds:
            r = run(case, seed)
            rows.append(r)
            for m in ("off", "auto"):
                d = r[m]
                print(
                    f"{case:<24} seed {seed} {m:<5} {d['verdict']:<5} band {d['band_hz'][0]:g}–"
                    f"{d['band_hz'][1]:g} Hz  mass {d['mass_pct']:+.3f} %  CG {d['cg_mm']:.2f} mm"
                    f"  pm {d['pm_pct']:.3f} %  CI {d['coverage'][0]}/{d['coverage'][1]}  "
                    f"cpu {d['cpu_s']:.1f} s"
                    + (f"  applied={d.get('applied')}" if m == "auto" else ""),
                    flush=True,
                )
            if "cross_check" in r:
                c = r["cross_check"]
                print(
                    f"{case:<24} seed {seed} cross-check  mass {c['mass_pct']:+.3f} %  "
                    f"CG {c['cg_mm']:.2f} mm  pm {c['pm_pct']:.3f} %",
                    flush=True,
                )
            res.sections = []
            res.table(HEADER, table_rows(rows))
            res.write()
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1) + "\n")


if __name__ == "__main__":
    main()
