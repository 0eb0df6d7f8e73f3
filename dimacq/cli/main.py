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
# shared with other jobs the spinning threads wait for cores (dimacq solve).
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

from dimacq.cli import commands  # noqa: E402
from dimacq.errors import DimacqError  # noqa: E402


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """Build the top-level parser with every discovered subcommand.

    With ``command`` (the subcommand a command line names), only the module of that name is
    imported when it registers that subcommand: ``dimacq solve`` then does not import the
    acquisition, the simulators or the sensitivity study (half a second of start-up).
    Any other name, or none, builds the whole parser (``dimacq --help``, a mistyped command).
    """
    if command is not None:
        parser = _parser_for(command)
        if parser is not None:
            return parser
    parser = _base_parser()
    sub = _subparsers(parser)
    for info in sorted(pkgutil.iter_modules(commands.__path__), key=lambda m: m.name):
        module = importlib.import_module(f"{commands.__name__}.{info.name}")
        register = getattr(module, "register", None)
        if register is not None:
            register(sub)
    return parser


def _base_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="dimacq",
        description="Rigid-body inertia properties by the Dynamic Inertia Method.",
    )
    parser.add_argument("-v", "--verbose", action="count", default=0, help="more log output")
    return parser


def _subparsers(
    parser: argparse.ArgumentParser,
) -> argparse._SubParsersAction[argparse.ArgumentParser]:
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    return sub


def _parser_for(command: str) -> argparse.ArgumentParser | None:
    """The parser with the one module named like ``command``; None when it has no such command."""
    name = command.replace("-", "_")
    if not name.isidentifier() or name not in {
        m.name for m in pkgutil.iter_modules(commands.__path__)
    }:
        return None
    module = importlib.import_module(f"{commands.__name__}.{name}")
    register = getattr(module, "register", None)
    if register is None:
        return None
    parser = _base_parser()
    sub = _subparsers(parser)
    register(sub)
    return parser if command in sub.choices else None


def _command_name(argv: Sequence[str]) -> str | None:
    """The subcommand of a command line: its first word that is not an option."""
    for word in argv:
        if word == "--":
            return None
        if not word.startswith("-"):
            return word
    return None


#: Commands whose process ends without the interpreter's teardown (:func:`_end_process`).
FAST_EXIT_COMMANDS = frozenset({"solve"})


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line; return the process exit status.

    Called as the program (``argv`` None: the ``dimacq`` script, ``python -m dimacq.cli.main``),
    a command of :data:`FAST_EXIT_COMMANDS` ends the process itself once its work is done
    (:func:`_end_process`); called with ``argv`` (tests, scripts) it always returns.
    """
    words = sys.argv[1:] if argv is None else list(argv)
    parser = build_parser(_command_name(words))
    args = parser.parse_args(words)
    level = logging.WARNING - 10 * min(args.verbose, 2)
    logging.basicConfig(level=level, format="%(levelname)s %(name)s: %(message)s")
    ends_process = argv is None and args.command in FAST_EXIT_COMMANDS
    if ends_process:
        # a batch command whose process ends with it: freed arrays are reused, not faulted in
        # anew (a test or script calling main([...]) keeps its process's allocator as it is)
        from dimacq.cli._process import keep_freed_memory

        keep_freed_memory()
    try:
        rc = int(args.func(args) or 0)
    except DimacqError as err:
        print(f"dimacq {args.command}: error: {err}", file=sys.stderr)
        rc = 2
    if ends_process:
        _end_process(rc)
    return rc


def _end_process(rc: int) -> None:
    """Flush what the command wrote and end the process with ``rc``, skipping the interpreter's
    teardown.

    ``dimacq solve`` has written its files (closed) and its report when it returns; what is left
    is the interpreter's finalisation: every module torn down and every object freed one by one
    (numpy, pydantic's schemas, the solve's 190 MB of arrays), which the kernel does at once when
    the process ends. Measured on the acquired calibration-mass set: 0.07 s of CPU at the
    minimum, 0.2 s at the median on the shared machine. Only for commands that
    leave no thread running and no file open (:data:`FAST_EXIT_COMMANDS`).
    """
    logging.shutdown()
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):  # a closed pipe or stream: nothing more can be written
            pass
    os._exit(rc)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
