"""Benchmark: ``dimacq plan`` — selection, and a 1,000-solve Monte Carlo on a Dask cluster.

Run on demand (not collected by pytest)::

    python tests/benchmarks/bench_plan.py [--trials 1000] [--workers 2] [--scheduler local]
                                          [--article calibration-mass|x38] [-k 6] [-m 12]

Times the planning (candidates from ``config/plans/``, greedy + exchange selection, random
layouts, error budget, one more triax/input) and then the Monte Carlo check of the chosen layout:
``--trials`` simulated tests each solved by the default ``dimacq solve``, on a LocalCluster of
``--workers`` single-threaded processes (``--scheduler local``), on a running scheduler
(``--scheduler tcp://host:8786``) or in this process (``--scheduler none``). Prints the wall time,
solves per second and per worker, and the Monte Carlo's bounds against the predicted ones.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def main() -> None:
    ap = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    ap.add_argument("--trials", type=int, default=1000)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--scheduler", default="local")
    ap.add_argument("--article", default="calibration-mass", choices=("calibration-mass", "x38"))
    ap.add_argument("-k", type=int, default=6)
    ap.add_argument("-m", type=int, default=12)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()

    from dimacq.cli.commands.plan import read_properties
    from dimacq.io.setup_file import load_setup
    from dimacq.services.solve.planning import make_plan

    setup = load_setup(ROOT / "config" / "plans" / f"{args.article}-candidates.toml")
    props = read_properties(ROOT / "config" / "plans" / f"{args.article}-properties.json")
    t0 = time.perf_counter()
    plan0 = make_plan(setup, props, args.k, args.m, seed=args.seed)
    t_plan = time.perf_counter() - t0
    print(f"planning ({args.article}, K={args.k}, M={args.m}): {t_plan:.2f} s")

    last = [0.0]

    def progress(done: int, total: int, left: float) -> None:
        now = time.perf_counter()
        if now - last[0] > 10 or done == total:
            last[0] = now
            print(f"  {done}/{total} solves, about {left:.0f} s left", file=sys.stderr)

    t0 = time.perf_counter()
    plan = make_plan(
        setup, props, args.k, args.m, trials=args.trials, seed=args.seed,
        scheduler=args.scheduler, workers=args.workers, progress=progress,
    )  # fmt: skip
    wall = time.perf_counter() - t0 - t_plan
    mc = plan["monte_carlo"]
    w = max(args.workers, 1)
    print(
        f"Monte Carlo: {mc['n_solved']}/{mc['n_trials']} solves in {wall:.0f} s wall "
        f"({args.scheduler}, {args.workers} workers): {mc['n_trials'] / wall:.2f} solves/s, "
        f"{wall * w / mc['n_trials']:.2f} s per solve and worker"
    )
    for k in ("mass_pct", "cg_mm", "principal_pct"):
        print(
            f"  {k}: predicted {plan0['predicted'][k]:.4g}, Monte Carlo {mc['bounds'][k]:.4g}, "
            f"share inside the predicted bound {mc['within_predicted'][k]:.3f}"
        )
    print(f"  coverage of the solves' 95 % intervals: {mc['coverage']}")
    print(f"  verdicts: {mc['verdicts']}")


if __name__ == "__main__":
    main()
