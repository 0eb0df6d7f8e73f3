"""``dimacq frf-from-time SETUP TIME --frf OUT.uff``: FRFs from impact time data in a file.

TIME is a UFF file of dataset 58 time responses (function type 1) or a TDMS file
(:mod:`dimacq.io.time_data` documents both layouts); the FRFs are estimated per input with the
acquisition's estimator and windows (:func:`dimacq.services.acquisition.time_frf.frf_from_time`) and written
as a UFF file of FRFs that ``dimacq solve SETUP OUT.uff`` reads.
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path
from typing import Any

from dimacq.cli.progress import plain


def register(subparsers: Any) -> None:
    p = subparsers.add_parser(
        "frf-from-time",
        help="FRFs from impact time data (UFF 58 time records or TDMS)",
        description=plain(__doc__),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("setup", type=Path, help="the test's setup file (TOML or JSON)")
    p.add_argument("time", type=Path, help="time data: .uff/.unv (58, function type 1) or .tdms")
    p.add_argument("--frf", type=Path, required=True, metavar="OUT", help="FRF UFF to write")
    p.add_argument("--pretrigger", type=int, default=0, metavar="N", help="samples before the hit")
    p.add_argument(
        "--force-window", type=int, default=None, metavar="N", help="force window length, samples"
    )
    p.add_argument(
        "--tau", type=float, default=None, metavar="S", help="exponential window time constant, s"
    )
    p.add_argument("--estimator", choices=("H1", "H2", "Hv"), default="H1")
    p.add_argument(
        "--fft-threads",
        type=_threads,
        default=None,
        metavar="N",
        help="threads of the FFTs (default: the cores this process may use)",
    )
    p.set_defaults(func=run)


def _threads(text: str) -> int:
    try:
        n = int(text)
    except ValueError:
        n = 0
    if n < 1:
        raise argparse.ArgumentTypeError(f"{text!r}: give a whole number of threads, 1 or more")
    return n


def default_fft_threads() -> int:
    """The cores this process may run on (its CPU affinity; ``os.cpu_count()`` where the
    platform has no affinity)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # macOS, Windows
        return os.cpu_count() or 1


def run(args: argparse.Namespace) -> int:
    from dimacq.io.setup_file import load_setup
    from dimacq.io.time_data import read_time_data
    from dimacq.io.uff import write_frf_uff
    from dimacq.services.acquisition.time_frf import frf_from_time

    setup = load_setup(args.setup)
    records = read_time_data(args.time)
    frf = frf_from_time(
        records,
        setup,
        pretrigger_samples=args.pretrigger,
        force_window_samples=args.force_window,
        exponential_tau_s=args.tau,
        estimator=args.estimator,
        source=f"time data {args.time.name}",
        fft_threads=args.fft_threads or default_fft_threads(),
    )
    write_frf_uff(args.frf, frf)
    print(
        f"{len(records)} time records → FRFs of {len(frf.outputs)} outputs × {len(frf.inputs)} "
        f"inputs, {frf.frequencies_hz.size} lines up to {frf.frequencies_hz[-1]:g} Hz: {args.frf}"
    )
    return 0
