"""Issue 10 "must show": the default solve (no flags) on held-out style cases, several seeds.

Run: ``python tests/scripts/trust_must_show.py [--seeds 5] [--json OUT]``

Rigid cases (must be solved, verdict not ``fail``): ``calibration-mass-realistic`` and the
``x38-realistic`` vehicle built rigid (``article.flexible = false``), model FRFs with 1 % noise,
2 mm positions, 0.5° triax orientation, 1° line of action, 2 mis-mounted channels and 2 bad impacts
(the scenarios' ``[errors]``). Criteria: mass within 0.5 %, principal moments within 2 %, and the
95 % intervals hold the true value for ≥ 90 % of parameters over all seeds.

Flexible cases: X-38-like vehicles whose elastic modes (drogue-chute pair, tails) lie at 2–6× the
suspension frequency, 0.5 % noise, lines 1–60 Hz: each must be either solved (mass within 1 %,
principal moments within 5 %, honest intervals) or refused (verdict ``fail``, with a reason).

Everything goes through :func:`dimacq.services.solve.analysis.analyse` with default options, i.e. what
``dimacq solve`` does with no flags.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from dimacq.model.setup import PARAMETERS
from dimacq.services.solve.analysis import AnalysisOptions, analyse
from dimacq.simulators.lab.scenarios import Scenario, build_scenario, load_scenario


def _scenario(name: str, **article: Any) -> Scenario:
    d = load_scenario(name).model_dump()
    d["article"].update(article)
    return Scenario.model_validate(d)


def _errors(rep: Any, truth: Any) -> dict[str, Any]:
    r = rep.result
    w = np.linalg.eigvalsh(r.inertia_cg_kgm2)
    w0 = np.linalg.eigvalsh(truth.inertia_cg_kgm2)
    true = truth.parameter_vector(r.reference_point_m)
    true[1:4] = truth.cg_m
    inside = [
        bool(
            rep.uncertainty.parameters[p].ci95[0]
            <= true[i]
            <= rep.uncertainty.parameters[p].ci95[1]
        )
        for i, p in enumerate(PARAMETERS)
    ]
    return {
        "mass_pct": float(100 * (r.mass_kg - truth.mass_kg) / truth.mass_kg),
        "cg_mm": float(1000 * np.linalg.norm(r.cg_m - truth.cg_m)),
        "principal_pct": float(100 * np.max(np.abs(w - w0) / w0)),
        "inside": inside,
        "band_hz": list(r.band_hz),
        "verdict": rep.verdict,
        "reasons": [x.to_json() for x in rep.verdict_reasons if x.severity != "ok"],
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--first-seed", type=int, default=100)
    ap.add_argument("--json", type=Path)
    args = ap.parse_args(argv)
    seeds = range(args.first_seed, args.first_seed + args.seeds)
    t0 = time.perf_counter()
    rows: list[dict[str, Any]] = []

    rigid = [
        ("calibration-mass-realistic", load_scenario("calibration-mass-realistic")),
        ("x38-realistic rigid", _scenario("x38-realistic", flexible=False)),
    ]
    print("RIGID (1 % noise, 2 mm, 0.5°, 1°, 2 mis-mounted channels, 2 bad impacts)")
    n_in = n_par = 0
    rigid_ok = True
    for label, scn in rigid:
        for s in seeds:
            b = build_scenario(scn, s)
            frf = b.model_frf(noise=0.01)
            rep = analyse(frf, b.setup, AnalysisOptions())
            e = _errors(rep, b.truth)
            n_in += sum(e["inside"])
            n_par += len(e["inside"])
            good = e["verdict"] != "fail" and abs(e["mass_pct"]) <= 0.5 and e["principal_pct"] <= 2
            rigid_ok &= good
            rows.append({"case": label, "seed": s, **e})
            print(
                f"  {label:<28} seed {s:>4}: band {e['band_hz'][0]:g}–{e['band_hz'][1]:g} Hz, "
                f"mass {e['mass_pct']:+.3f} %, CG {e['cg_mm']:.2f} mm, principal {e['principal_pct']:.3f} %, "
                f"{sum(e['inside'])}/10 in 95 % CI, verdict {e['verdict']}{'' if good else '  <-- MISS'}"
            )
    cover = n_in / max(n_par, 1)
    print(
        f"  rigid coverage: {n_in}/{n_par} = {100 * cover:.1f} % (need ≥ 90 %); all within limits: {rigid_ok}"
    )

    print("FLEXIBLE (0.5 % noise, 1–60 Hz, elastic modes at 2–6× suspension)")
    flex_ok = True
    n_in_f = n_par_f = 0
    rng = np.random.default_rng(args.first_seed)
    for s in seeds:
        for _ in range(2):
            fs = float(rng.uniform(1.2, 2.5))
            k1, k2 = sorted(rng.uniform(2.0, 6.0, 2))
            kd = float(rng.uniform(max(k2, 3.0), 8.0))
            art = {
                "flexible": True,
                "suspension_hz": fs,
                "chute_modes_hz": (round(k1 * fs, 3), round(max(k2, k1 * 1.05) * fs, 3)),
                "deformation_mode_hz": round(kd * fs, 3),
            }
            d = _scenario("x38", **art).model_dump()
            d["frequency_axis"] = {"max_hz": 60.0, "resolution_hz": 0.125}
            d["band"] = {"lo_hz": 7.0, "hi_hz": 9.0}
            scn = Scenario.model_validate(d)
            b = build_scenario(scn, s)
            frf = b.model_frf(noise=0.005).band(1.0, 60.0)
            rep = analyse(frf, b.setup, AnalysisOptions())
            e = _errors(rep, b.truth)
            if e["verdict"] == "fail":
                good, what = bool(e["reasons"]), "refused"
            else:
                good = abs(e["mass_pct"]) <= 1 and e["principal_pct"] <= 5
                what = "solved"
                n_in_f += sum(e["inside"])
                n_par_f += 10
            flex_ok &= good
            rows.append({"case": "x38 flexible", "seed": s, "article": art, **e})
            print(
                f"  susp {fs:.2f} Hz, chute {art['chute_modes_hz']}, tails {art['deformation_mode_hz']:g} Hz, "
                f"seed {s}: {what}, band {e['band_hz'][0]:g}–{e['band_hz'][1]:g} Hz, mass {e['mass_pct']:+.3f} %, "
                f"principal {e['principal_pct']:.3f} %, {sum(e['inside'])}/10 in CI"
                + ("" if good else "  <-- MISS")
                + (f"; reason: {e['reasons'][0]['message'][:120]}" if what == "refused" else "")
            )
    print(
        f"  flexible: all solved-within-limits or refused: {flex_ok}; coverage of the solved "
        f"{n_in_f}/{n_par_f}"
    )
    print(f"time {time.perf_counter() - t0:.0f} s")
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1) + "\n", encoding="utf-8")
    return 0 if (rigid_ok and cover >= 0.9 and flex_ok) else 1


if __name__ == "__main__":
    sys.exit(main())
