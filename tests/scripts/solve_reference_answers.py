"""Write or check the answers ``dimacq solve`` gives on fixed test sets (issue #27's "same answer").

Run on demand (not collected by pytest)::

    python tests/scripts/solve_reference_answers.py --write            # regenerate the fixtures
    python tests/scripts/solve_reference_answers.py [--acquired A.uff]  # compare with them

The sets: the shipped example (``config/examples/six_triax_*``), two noisy whole-test files made
by ``dimacq simulate SCENARIO --noise 0.01`` (seed 0; calibration-mass-bungee, the file
``tests/benchmarks/bench_solve.py`` solves, and x38-realistic) and, with ``--acquired``, a file of
``dimacq acquire calibration-mass-bungee --seed 0 --averages-per-input 3 --frf A.uff`` (too large
and too slow to make for a test: its answer is kept in ``tests/cli/solve_reference/acquired.json``
and compared here only; an acquisition does not repeat bit for bit, so another acquired file has
its own answer, ``--name NAME`` for ``solve_reference/NAME.json``: ``acquired-wt-solve`` is the
file whose sha256 starts 9eb82ccd7627, made by that command at the time-lapse it measured). Each solve runs in this process after numpy is imported, as pytest runs
it (``tests/cli/test_solve_reference_numbers.py`` compares the first three on every run).
Regenerate only with a method change, and say which in the commit.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import sys
import tempfile
from pathlib import Path
from typing import Any

import numpy as np  # noqa: F401  (before the CLI, as under pytest: BLAS keeps its thread count)

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "tests" / "cli"))

from test_solve_reference_numbers import (  # noqa: E402
    REFERENCE_DIR,
    SIMULATED,
    compare,
    simulate,
    solve_json,
)

EXAMPLES = ROOT / "config" / "examples"


def _strip(doc: dict[str, Any]) -> dict[str, Any]:
    doc.get("output_error", {}).pop("elapsed_s", None)
    return doc


def main() -> None:
    ap = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    ap.add_argument("--write", action="store_true", help="write the fixtures instead of comparing")
    ap.add_argument("--acquired", type=Path, metavar="A.uff", help="an acquired whole-test file")
    ap.add_argument(
        "--name",
        default="acquired",
        help="the acquired file's answer is solve_reference/NAME.json (default: acquired); an "
        "acquisition is not repeatable (wall-time DAQ), so each kept file has its own answer",
    )
    args = ap.parse_args()
    with tempfile.TemporaryDirectory(prefix="solve-ref-") as tmp_name:
        tmp = Path(tmp_name)
        cases: dict[str, list[str]] = {}
        for name in SIMULATED:
            cases[name] = [str(simulate(name, tmp))]
        if args.acquired is not None:
            cases[args.name] = [str(args.acquired)]
        failed = 0
        for name, files in cases.items():
            with contextlib.redirect_stdout(io.StringIO()):
                got = _strip(solve_json(files, tmp / f"{name}.json"))
            ref_path = REFERENCE_DIR / f"{name}.json"
            if args.write:
                ref_path.parent.mkdir(parents=True, exist_ok=True)
                ref_path.write_text(json.dumps(got, indent=2, allow_nan=True) + "\n")
                print(f"{name}: wrote {ref_path.relative_to(ROOT)}")
                continue
            bad: list[str] = []
            compare(got, json.loads(ref_path.read_text()), "", bad)
            failed += bool(bad)
            print(f"{name}: {'same answer' if not bad else f'{len(bad)} numbers changed'}")
            for b in bad[:20]:
                print(f"  {b}")
    sys.exit(1 if failed else 0)


if __name__ == "__main__":
    main()
