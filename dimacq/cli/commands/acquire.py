"""``dimacq acquire``: an impact test of a virtual-lab scenario through the simulated devices.

Usage::

    dimacq acquire SCENARIO --impacts-per-input N --frf OUT.uff [--seed S] [--data DIR]
                   [--json OUT] [--record-samples N] [--exp-tau S] [--noise-free]

The virtual lab of SCENARIO (:data:`dimacq.cli.simulated_lab.SCENARIOS`) is read through the
simulated USB DAQ (pyusb backend) and one simulated CAN FD amplifier per load cell (python-can
``virtual``), by the real drivers; an impact session strikes every input N accepted times, and
the FRFs (accelerances and the load cells' six loads, as the drivers' calibration matrices give
them) are written as one whole-test UFF file (geometry + 58 records, binary) that
``dimacq solve OUT.uff`` reads. ``--data DIR`` keeps the raw blocks in ``DIR/acquisition.h5`` and the FRFs with their
coherence (which UFF 58 cannot carry) in ``DIR/frf.npz``.
Progress goes to stderr; a summary (with the FRFs' agreement with the true model) to stdout.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from dimacq.errors import SetupError


def register(subparsers: Any) -> None:
    p = subparsers.add_parser(
        "acquire",
        help="impact test of a virtual-lab scenario through the simulated DAQ and load cells",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("scenario", metavar="SCENARIO", help="virtual-lab scenario name")
    p.add_argument(
        "--impacts-per-input",
        type=int,
        required=True,
        metavar="N",
        help="accepted averages per input",
    )
    p.add_argument("--frf", type=Path, required=True, metavar="OUT.uff", help="FRF output (UFF)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--data", type=Path, metavar="DIR", help="keep the raw data (HDF5) in DIR")
    p.add_argument("--json", type=Path, metavar="OUT", help="write the summary as JSON")
    p.add_argument("--record-samples", type=int, default=4096, help="samples per average")
    p.add_argument(
        "--exp-tau", type=float, default=None, metavar="S", help="exponential window time constant"
    )
    p.add_argument("--noise-free", action="store_true", help="no transducer noise")
    p.set_defaults(func=run)


def _scenario_band(name: str) -> tuple[float, float]:
    """The scenario's recommended band (config/scenarios), else the simulated DIM band."""
    from dimacq.cli.simulated_lab import DIM_BAND_HZ
    from dimacq.simulators.lab.scenarios import list_scenarios, load_scenario

    if name in list_scenarios():
        band = load_scenario(name).band
        return (float(band.lo_hz), float(band.hi_hz))
    return DIM_BAND_HZ


def run(args: argparse.Namespace) -> int:
    from dimacq.cli.simulated_lab import (
        frf_agreement,
        run_scenario,
        scenario_model,
    )
    from dimacq.io.uff import write_uff_test
    from dimacq.services.acquisition import Progress
    from dimacq.simulators.lab.timedomain import LabNoise

    if args.impacts_per_input < 1:
        raise SetupError(f"--impacts-per-input {args.impacts_per_input}: give at least 1")
    if args.frf.suffix.lower() not in (".uff", ".unv"):
        raise SetupError(f"--frf {args.frf}: give a .uff (or .unv) file name")
    model = scenario_model(args.scenario, args.seed)
    n_in = len(model.setup.excitations)
    t0 = time.monotonic()

    def progress(p: Progress) -> None:
        done = p.input_index * p.wanted + p.accepted
        sys.stderr.write(
            f"\r[{done:4d}/{n_in * p.wanted}] {p.message[:90]:<90}"
            + ("\n" if p.rejected and "rejected" in p.message else "")
        )
        sys.stderr.flush()

    data_path = args.data / "acquisition.h5" if args.data else None
    run_ = run_scenario(
        model,
        averages_per_input=args.impacts_per_input,
        seed=args.seed,
        record_samples=args.record_samples,
        exponential_tau_s=args.exp_tau,
        noise=LabNoise() if args.noise_free else None,
        data_path=data_path,
        progress=progress,
    )
    sys.stderr.write("\n")
    args.frf.parent.mkdir(parents=True, exist_ok=True)
    write_uff_test(args.frf, run_.setup, run_.frf, binary=True)
    if args.data:
        # UFF 58 holds no coherence: keep it (with the FRFs) next to the raw data.
        np.savez(
            args.data / "frf.npz",
            frequencies_hz=run_.frf.frequencies_hz,
            H=run_.frf.H,
            coherence=np.asarray(run_.frf.coherence if run_.frf.coherence is not None else []),
        )
    elapsed = time.monotonic() - t0
    res = run_.result
    rejected = [a for a in res.averages if not a.accepted]
    # one average per input has no coherence (NaN): compare every value then
    coherent = run_.frf.coherence is not None and bool(np.isfinite(run_.frf.coherence).any())
    agreement = frf_agreement(
        run_.frf,
        model,
        exponential_tau_s=args.exp_tau,
        band_hz=_scenario_band(args.scenario),
        coherence_threshold=0.99 if coherent else None,
    )
    kept = set(res.input_indices or range(len(run_.setup.excitations)))
    incomplete = [e.name for j, e in enumerate(run_.setup.excitations) if j not in kept]
    summary: dict[str, Any] = {
        "scenario": args.scenario,
        "setup": run_.setup.name,
        "seed": args.seed,
        "frf_file": str(args.frf),
        "raw_data": str(data_path) if data_path else None,
        "record_samples": args.record_samples,
        "exponential_tau_s": args.exp_tau,
        "n_inputs": n_in,
        "n_outputs": len(run_.frf.outputs),
        "n_lines": run_.frf.n_lines,
        "averages_accepted": list(res.n_accepted),
        "min_averages": res.min_averages,
        "incomplete_inputs": incomplete,
        "averages_rejected": [
            {"input": run_.setup.excitations[a.input_index].name, "reasons": list(a.reasons)}
            for a in rejected
        ],
        "frf_vs_model": agreement.to_json(),
        "elapsed_s": elapsed,
    }
    out = sys.stdout
    out.write(
        f"{run_.setup.name}: {n_in} inputs × {args.impacts_per_input} averages, "
        f"{len(run_.frf.outputs)} outputs ({len(run_.setup.load_cells)} load cells), "
        f"{run_.frf.n_lines} lines {run_.frf.frequencies_hz[0]:g}–{run_.frf.frequencies_hz[-1]:g} Hz\n"
    )
    out.write(f"rejected averages: {len(rejected)}\n")
    for a in rejected:
        out.write(f"  input {run_.setup.excitations[a.input_index].name}: {'; '.join(a.reasons)}\n")
    if incomplete:
        out.write(
            f"incomplete inputs (fewer than {res.min_averages} accepted averages, no FRF): "
            f"{', '.join(incomplete)}\n"
        )
    where = (
        f"where coherence > {agreement.coherence_threshold}"
        if agreement.coherence_threshold is not None
        else "(one average: no coherence, every value)"
    )
    out.write(
        f"FRFs vs model {where}: "
        f"{100 * agreement.fraction_kept:.1f} % of values, median error "
        f"{100 * agreement.median_rel_error:.3f} %, 99th percentile "
        f"{100 * agreement.p99_rel_error:.2f} %, max {100 * agreement.max_rel_error:.2f} %\n"
    )
    out.write(f"wrote {args.frf} in {elapsed:.1f} s\n")
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(summary, indent=2) + "\n", encoding="utf-8")
    return 0
