"""Benchmark: per-line DIM solve, 8 triaxes + 1 load cell × 24 inputs × 2000 lines.

Run on demand (not collected by pytest)::

    python tests/benchmarks/bench_dim.py [--lines 2000] [--repeat 15]

Prints the median and minimum times of :func:`dimacq.pipeline.dim.assemble` (match, condense,
sum forces; target ≤ 5 ms) and :func:`dimacq.pipeline.dim.solve_system` (per-line spectrum and
joint band solve, on an assembled system) and of the baseline it must beat: a Python loop of
``np.linalg.lstsq`` over lines on the same stacked real/imaginary system, and their ratio.
Pins BLAS to one thread first, so the figure is for one core.
"""

from __future__ import annotations

import argparse
import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"

import time  # noqa: E402

import numpy as np  # noqa: E402

from dimacq.model.frf import Channel, FrfData  # noqa: E402
from dimacq.model.setup import Excitation, LoadCell, ResponseChannel, TestSetup  # noqa: E402
from dimacq.pipeline import dim  # noqa: E402


def build(n_lines: int, seed: int = 0) -> tuple[FrfData, TestSetup]:
    """Random but consistent-shaped problem: 8 triaxes, 24 inputs, 1 load cell."""
    rng = np.random.default_rng(seed)
    resp = []
    for t in range(8):
        r = rng.uniform(-0.2, 0.2, 3)
        q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
        for k in range(3):
            resp.append(
                ResponseChannel(
                    node=t + 1, direction=k + 1, position_m=tuple(r), direction_gcs=tuple(q[:, k])
                )
            )
    exc = []
    for j in range(24):
        d = rng.normal(size=3)
        exc.append(
            Excitation(
                node=100 + j,
                position_m=tuple(rng.uniform(-0.2, 0.2, 3)),
                direction_gcs=tuple(d / np.linalg.norm(d)),
            )
        )
    setup = TestSetup(
        responses=tuple(resp),
        excitations=tuple(exc),
        load_cells=(LoadCell(node=500, position_m=(0.0, 0.0, -0.3)),),
    )
    outs = tuple(Channel(c.node, c.direction) for c in resp) + tuple(
        Channel(500, k) for k in range(1, 7)
    )
    kinds = ("acceleration",) * 24 + ("reaction",) * 6
    H = rng.normal(size=(n_lines, 30, 24)) + 1j * rng.normal(size=(n_lines, 30, 24))
    frf = FrfData(
        np.linspace(10, 200, n_lines), H, outs, kinds, tuple(Channel(e.node, 1) for e in exc)
    )
    return frf, setup


def lstsq_loop(system: dim.DimSystem) -> np.ndarray:
    """Baseline: stack real/imag and inputs per line, ``np.linalg.lstsq`` in a Python loop."""
    A = dim.design_matrices(system.K)
    b = np.moveaxis(system.F, -1, -2)
    n_lines = A.shape[0]
    out = np.empty((n_lines, 10))
    for i in range(n_lines):
        Ai = A[i].reshape(-1, 10)
        bi = b[i].reshape(-1)
        out[i] = np.linalg.lstsq(
            np.concatenate([Ai.real, Ai.imag]), np.concatenate([bi.real, bi.imag]), rcond=None
        )[0]
    return out


def times(fn, repeat: int) -> tuple[float, float]:
    """(minimum, median) wall time of ``repeat`` runs: on a shared machine the minimum is the figure."""
    out = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        out.append(time.perf_counter() - t0)
    return float(np.min(out)), float(np.median(out))


def cpu_times(fn, repeat: int) -> tuple[float, float]:
    """(minimum, median) CPU time of ``repeat`` runs (one thread: other processes' load inflates
    it far less than the wall clock)."""
    out = []
    for _ in range(repeat):
        t0 = time.process_time()
        fn()
        out.append(time.process_time() - t0)
    return float(np.min(out)), float(np.median(out))


def median_time(fn, repeat: int) -> float:
    return times(fn, repeat)[1]


def main() -> int:
    """Run the benchmark; exit status 1 when a target is missed (each line says PASS/FAIL)."""
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--lines", type=int, default=2000)
    ap.add_argument("--repeat", type=int, default=15)
    args = ap.parse_args()
    frf, setup = build(args.lines)
    system = dim.assemble(frf, setup)
    a_min, t_assemble = times(lambda: dim.assemble(frf, setup), args.repeat)
    a_cpu_min, a_cpu_med = cpu_times(lambda: dim.assemble(frf, setup), args.repeat)
    s_min, t_solve = times(lambda: dim.solve_system(system, check_plausibility=False), args.repeat)
    t_loop = median_time(lambda: lstsq_loop(system), max(3, args.repeat // 5))
    x_fast = dim.solve_system(system, check_plausibility=False).per_line
    x_loop = lstsq_loop(system)
    s = x_loop[:, 1:4] / x_loop[:, :1]
    agree = np.nanmax(np.abs(x_fast[:, 0] - x_loop[:, 0]) / np.abs(x_loop[:, 0]))
    print(f"problem: 8 triaxes + 1 load cell, 24 inputs, {args.lines} lines (one BLAS thread)")
    print(
        f"assemble (match, condense, sum forces): {t_assemble * 1e3:8.2f} ms median, "
        f"{a_min * 1e3:.2f} ms min  (target <= 5 ms); CPU {a_cpu_min * 1e3:.2f} ms min, "
        f"{a_cpu_med * 1e3:.2f} ms median (load average {os.getloadavg()[0]:.1f})"
    )
    print(
        f"dimacq solve_system (per line + joint): {t_solve * 1e3:8.2f} ms median, "
        f"{s_min * 1e3:.2f} ms min  (target <= 20 ms)"
    )
    print(f"np.linalg.lstsq loop over lines:        {t_loop * 1e3:8.2f} ms median")
    print(
        f"speed-up: {t_loop / t_solve:6.1f}x  (target >= 20x); max rel. mass difference {agree:.1e}"
    )
    del s
    verdicts = {
        "assemble <= 5 ms (min)": a_min <= 5e-3,
        "solve_system <= 20 ms (min)": s_min <= 20e-3,
        "speed-up >= 20x (medians)": t_loop / t_solve >= 20,
    }
    print("; ".join(f"{k}: {'PASS' if v else 'FAIL'}" for k, v in verdicts.items()))
    return 0 if all(verdicts.values()) else 1


if __name__ == "__main__":
    raise SystemExit(main())
