"""Entry point of the ``dimacq`` command.

Subcommands are discovered from :mod:`dimacq.cli.commands`: every module there exposes
``register(subparsers)``. Errors derived from :class:`dimacq.errors.DimacqError` are printed as one
clear line on stderr with exit status 2; anything else is a bug and keeps its traceback.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import os
import pkgutil
import sys
from collections.abc import Sequence

# One BLAS thread unless the caller chose otherwise, set before numpy loads OpenBLAS. The
# numerical core multiplies many small matrices (6×2J Gram matrices per line, 10×10 systems);
# on those OpenBLAS's worker threads spin instead of helping: the DIM normal equations of a
# 1357-line test took 6.1 ms of CPU with two threads and 1.0 ms with one, and on a machine
# shared with other jobs the spinning threads wait for cores (dimacq solve: issue #27).
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

from dimacq.cli import commands  # noqa: E402
from dimacq.errors import DimacqError  # noqa: E402


def build_parser() -> argparse.ArgumentParser:
    """Build the top-level parser with every discovered subcommand."""
    parser = argparse.ArgumentParser(
        prog="dimacq",
        description="Rigid-body inertia properties by the Dynamic Inertia Method.",
    )
    parser.add_argument("-v", "--verbose", action="count", default=0, help="more log output")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for info in sorted(pkgutil.iter_modules(commands.__path__), key=lambda m: m.name):
        module = importlib.import_module(f"{commands.__name__}.{info.name}")
        register = getattr(module, "register", None)
        if register is not None:
            register(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line; return the process exit status."""
    parser = build_parser()
    args = parser.parse_args(argv)
    level = logging.WARNING - 10 * min(args.verbose, 2)
    logging.basicConfig(level=level, format="%(levelname)s %(name)s: %(message)s")
    try:
        return int(args.func(args) or 0)
    except DimacqError as err:
        print(f"dimacq {args.command}: error: {err}", file=sys.stderr)
        return 2


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
