"""The README's "Planning" table: ``dimacq plan`` on the shipped candidate sets (config/plans/) for
K = 6 and 8 triaxes and 12 and 24 inputs, predicted 95 % bounds against the median of random
layouts, and a Monte Carlo of default solves of the chosen layout.

    nice python tests/scripts/plan_table.py [--trials 40] [--workers 2] [--seed 0]

One LocalCluster (``--workers`` processes) serves every case. Columns: predicted bounds (mass %,
largest CG component mm, largest principal moment %), the random median, the factor (random
median / plan) without the hammer's common scale (what the layout controls), the Monte Carlo's
95 % bounds, the share of trials inside the predicted bounds, and the coverage of the solves' own
95 % intervals (mass, CG components, principal moments).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
CASES = [("calibration mass", "calibration-mass", k, m) for k in (6, 8) for m in (12, 24)] + [
    ("X-38", "x38", k, m) for k in (6, 8) for m in (12, 24)
]


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--trials", type=int, default=40)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args()
    from dask.distributed import LocalCluster

    from dimacq.cli.commands.plan import read_properties
    from dimacq.io.setup_file import load_setup
    from dimacq.services.solve.planning import make_plan

    rows, docs = [], []
    with LocalCluster(
        n_workers=args.workers, threads_per_worker=1, dashboard_address=None
    ) as cluster:
        for label, name, k, m in CASES:
            t0 = time.perf_counter()
            setup = load_setup(ROOT / "config" / "plans" / f"{name}-candidates.toml")
            props = read_properties(ROOT / "config" / "plans" / f"{name}-properties.json")
            plan = make_plan(
                setup, props, k, m, trials=args.trials, seed=args.seed,
                scheduler=cluster.scheduler_address,
            )  # fmt: skip
            dt = time.perf_counter() - t0
            p, r, mc = plan["predicted"], plan["random_median"], plan.get("monte_carlo") or {}
            f = plan["layout_controlled"]["factor_over_random"]
            b, w, c = mc.get("bounds", {}), mc.get("within_predicted", {}), mc.get("coverage", {})

            def t3(d: dict, fmt: str = "{:.3g}") -> str:
                return " / ".join(fmt.format(d[x]) for x in ("mass_pct", "cg_mm", "principal_pct"))

            rows.append(
                f"| {label} | {k} | {m} | {t3(p)} | {t3(r)} | {t3(f, '{:.2f}')} | "
                f"{t3(b) if b else ''} | {t3(w, '{:.2f}') if w else ''} | "
                f"{c.get('mass', '')} / {c.get('cg', '')} / {c.get('principal', '')} | {dt:.0f} s |"
            )
            docs.append({"case": label, "k": k, "m": m, "plan": plan, "seconds": dt})
            print(rows[-1], file=sys.stderr, flush=True)
    print(
        "| article | triaxes | inputs | predicted 95 % (mass % / CG mm / PM %) | random median | "
        "factor (layout part) | Monte Carlo 95 % | share within predicted | coverage of the "
        "solves' intervals | time |"
    )
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    print("\n".join(rows))
    if args.json:
        args.json.write_text(json.dumps(docs, indent=1))


if __name__ == "__main__":
    main()
