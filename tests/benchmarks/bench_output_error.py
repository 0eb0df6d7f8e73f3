"""Benchmark: output-error DIM with geometry refinement, 8 triaxes + 1 load cell × 24 inputs × 2000 lines.

Run on demand (not collected by pytest)::

    python tests/benchmarks/bench_output_error.py [--lines 2000] [--repeat 5]

The calibration mass of ``calibration-mass-realistic`` (seed 0; 1 % FRF noise, the scenario's
geometry errors, its gross errors left out as selection would) with 2000 lines in its 20–100 Hz
band (0.04 Hz resolution). Prints the median wall time of
:func:`dimacq.pipeline.output_error.solve_output_error` — noise estimate, equation-error start,
geometry identifiability, Levenberg–Marquardt on the sufficient statistics, posterior — with the
geometry refined, without it, and with residual flexibility as well (two fits and the test).
Pins BLAS to one thread first, so the figure is for one core.
"""

from __future__ import annotations

import argparse
import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"

import time  # noqa: E402

import numpy as np  # noqa: E402

from dimacq.pipeline.output_error import OutputErrorOptions, solve_output_error  # noqa: E402
from dimacq.pipeline.selection._common import response_geometry  # noqa: E402
from dimacq.simulators.lab.scenarios import build_scenario, gross_errors  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--lines", type=int, default=2000)
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args()
    b = build_scenario("calibration-mass-realistic", 0)
    f = np.linspace(20.0, 100.0, args.lines)
    frf = b.model_frf(noise=0.01, frequencies_hz=f)
    bad_ch, bad_in = gross_errors(b.model.setup, b.spec.errors, 0)
    w = np.ones(len(response_geometry(frf, b.setup).channels))
    w[list(bad_ch)] = 0
    keep = np.ones(len(frf.inputs), bool)
    keep[list(bad_in)] = False
    print(
        f"{int(np.sum(w > 0))} channels × {int(keep.sum())} inputs (of {len(frf.inputs)}) × "
        f"{args.lines} lines"
    )
    for label, opt in (
        ("refine geometry", OutputErrorOptions(refine_geometry=True)),
        ("no refinement (unbiased only)", OutputErrorOptions(refine_geometry=False)),
        (
            "refine + residual flexibility",
            OutputErrorOptions(refine_geometry=True, residual_flexibility=True),
        ),
    ):
        times = []
        for _ in range(args.repeat):
            t0 = time.perf_counter()
            r = solve_output_error(frf, b.setup, response_weights=w, input_keep=keep, options=opt)
            times.append(time.perf_counter() - t0)
        err = 100 * (r.parameters[0] / b.truth.mass_kg - 1)
        print(
            f"{label:32s} median {np.median(times):.3f} s (min {min(times):.3f} s), "
            f"{r.iterations} iterations, mass error {err:+.4f} %"
        )


if __name__ == "__main__":
    main()
