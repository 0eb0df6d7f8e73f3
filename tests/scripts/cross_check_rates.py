"""How often the mass-line cross-check disagrees with the default DIM: over virtual-lab
scenarios, noise levels and seeds, the largest |z| of each solve, whether an item lies outside
its combined 95 % interval (``agrees``) and whether the verdict warns (family-wise limit), beside
both estimators' errors against the simulator's truth (the comparison with the truth is this
script's, never the solver's).

Run on demand (a few seconds per solve)::

    python tests/scripts/cross_check_rates.py [--cases calibration-mass-realistic,x38-realistic]
        [--noise 0.01,0.03] [--seeds 6]

It writes its table to ``cross_check_rates_results.md`` beside it (``--results`` elsewhere).
"""

from __future__ import annotations

import argparse
import sys
import time
import warnings
from pathlib import Path

import numpy as np

from dimacq.model.properties import principal_moments
from dimacq.services.solve.analysis import AnalysisOptions, analyse
from dimacq.simulators.lab.scenarios import build_scenario

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from _results import Results, add_results_argument


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--cases", default="calibration-mass-realistic,x38-realistic,x38,calibration-mass-bungee"
    )
    ap.add_argument("--noise", default="0.01,0.03")
    ap.add_argument("--seeds", type=int, default=6)
    add_results_argument(ap, __file__)
    a = ap.parse_args(argv)
    warnings.simplefilter("ignore")
    res = Results(__file__, "How often the mass-line cross-check disagrees", a.results)
    rows: list[list[str]] = []
    n = n_out = n_warn = 0
    for scn in a.cases.split(","):
        for noise in (float(x) for x in a.noise.split(",")):
            for seed in range(a.seeds):
                b = build_scenario(scn, seed)
                t = b.truth
                pm_t = principal_moments(t.inertia_cg_kgm2)[0]
                t0 = time.time()
                rep = analyse(b.model_frf(noise=noise), b.setup, AnalysisOptions())
                cc = rep.cross_check
                n += 1
                if cc is None or cc.fit is None:
                    print(f"{scn} noise {noise:g} seed {seed}: no cross-check ({cc and cc.error})")
                    rows.append([f"`{scn}`", f"{noise:g}", str(seed), rep.verdict, "none", "", ""])
                    continue
                r, v = rep.result, cc.fit.values
                pm = principal_moments(r.inertia_cg_kgm2)[0]
                n_out += not cc.all_agree
                n_warn += not cc.family_wise_agree
                dim_ = (
                    f"{100 * (r.mass_kg / t.mass_kg - 1):+.3f} % / "
                    f"{1000 * np.max(np.abs(r.cg_m - t.cg_m)):.2f} mm / "
                    f"{100 * np.max(np.abs(pm / pm_t - 1)):.2f} %"
                )
                line = (
                    f"{100 * (v[0] / t.mass_kg - 1):+.3f} % / "
                    f"{1000 * np.max(np.abs(v[1:4] - t.cg_m)):.2f} mm / "
                    f"{100 * np.max(np.abs(v[16:19] / pm_t - 1)):.2f} %"
                )
                print(
                    f"{scn} noise {noise:g} seed {seed} ({time.time() - t0:.1f} s): verdict "
                    f"{rep.verdict}, max|z| {cc.max_abs_z:.2f}, agrees {cc.all_agree} | DIM "
                    f"{dim_} | mass line {line}",
                    flush=True,
                )
                rows.append(
                    [
                        f"`{scn}`",
                        f"{noise:g}",
                        str(seed),
                        rep.verdict,
                        f"{cc.max_abs_z:.2f}, " + ("all agree" if cc.all_agree else "outside"),
                        dim_,
                        line,
                    ]
                )
    total = f"{n} solves: {n_out} with an item outside its 95 % interval, {n_warn} warned"
    print(total)
    res.add(
        "Default solve of the simulator's model FRFs; the largest |z| of the 13 items the "
        "cross-check compares, whether all lie within their combined 95 % intervals, and both "
        "estimators' errors against the simulator's truth (mass / largest CG / largest principal "
        f"moment). **{total}.**"
    )
    res.table(["scenario", "noise", "seed", "verdict", "max \\|z\\|", "DIM", "mass line"], rows)
    res.write()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
