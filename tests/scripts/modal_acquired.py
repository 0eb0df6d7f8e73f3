"""The modal-model correction on the acquired chain: a default ``dimacq solve`` of FRFs
acquired through the simulated devices, against the scenario's truth (errors, interval coverage,
verdict, the modal correction's fit range and where it held).

Acquire first (3–6 min each on a loaded machine; ``daq_time_scale`` low enough that the host
keeps up), then solve as often as needed::

    DIMACQ_SIMULATION_IMPERFECTIONS='{"daq_time_scale": 10}' \\
        dimacq acquire x38-flexible-17 --averages-per-input 3 --seed 1 --frf /tmp/f17-s1.uff
    nice python tests/scripts/modal_acquired.py /tmp/f17-s1.uff x38-flexible-17 1 [--mode auto]

Each solve is appended as a section to ``modal_acquired_results.md`` beside this script
(``--results`` elsewhere) with the command, date, commit and machine load.
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from _results import Results, add_results_argument, fmt
from modal_must_show import _coverage, _errors

from dimacq.io.uff import read_uff_test
from dimacq.services.solve.analysis import AnalysisOptions, analyse
from dimacq.simulators.lab.scenarios import build_scenario


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("uff", type=Path)
    ap.add_argument("scenario")
    ap.add_argument("seed", type=int)
    ap.add_argument("--mode", default="auto", choices=("auto", "on", "off"))
    add_results_argument(ap, __file__)
    args = ap.parse_args()
    res = Results(
        __file__,
        "The modal-model correction on the acquired chain",
        args.results,
        append=True,
        label=f"{args.uff.name}, {args.scenario} seed {args.seed}, --mode {args.mode}",
    )
    logging.disable(logging.WARNING)
    setup, frf = read_uff_test(args.uff)
    truth = build_scenario(args.scenario, args.seed).truth
    t0 = time.process_time()
    rep = analyse(frf, setup, AnalysisOptions(modal_correction=args.mode))
    cpu = time.process_time() - t0
    out = rep.to_json()
    p = rep.result.properties
    e = _errors(p.mass_kg, p.cg_m, p.inertia_cg_kgm2, truth)
    held, n = _coverage(out, truth, np.asarray(rep.result.reference_point_m, float))
    mc = out.get("modal_correction") or {}
    print(
        f"{args.uff.name} {args.mode}: {rep.verdict} band {rep.result.band_hz[0]:g}–"
        f"{rep.result.band_hz[1]:g} Hz  mass {e['mass_pct']:+.3f} %  CG {e['cg_mm']:.2f} mm  "
        f"pm {e['pm_pct']:.3f} %  CI {held}/{n}  cpu {cpu:.1f} s  applied={mc.get('applied')}"
    )
    res.table(
        [
            "verdict",
            "band Hz",
            "mass %",
            "CG mm",
            "principal moments % (largest)",
            "95 % intervals holding the truth",
            "CPU s",
            "correction applied",
        ],
        [
            (
                rep.verdict,
                f"{rep.result.band_hz[0]:g}–{rep.result.band_hz[1]:g}",
                fmt(e["mass_pct"], "+.3f"),
                fmt(e["cg_mm"], ".2f"),
                fmt(e["pm_pct"], ".3f"),
                f"{held}/{n}",
                fmt(cpu, ".1f"),
                mc.get("applied", "—"),
            )
        ],
    )
    said = []
    for r in rep.verdict_reasons:
        if r.severity != "ok":
            said.append(f"- {r.severity}: {r.check}: {r.message}")
            print(f"  {r.severity}: {r.check}: {r.message}")
    if mc:
        fit = json.dumps({"reason": mc.get("reason"), **mc.get("fit_quality", {})})
        said.append(f"- modal correction: `{fit}`")
        print("  modal_correction:", fit)
    if said:
        res.add("\n".join(said))
    res.write()


if __name__ == "__main__":
    main()
