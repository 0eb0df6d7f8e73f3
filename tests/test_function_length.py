"""No function in ``dimacq/`` grows past 120 lines: long functions are split into named steps.

The functions that were already longer are listed with their length as a ceiling: each may only
shrink, and leaves the list once it is split below the limit (``tests/scripts/long_functions.py``
prints them all). A new function over the limit fails here.
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent / "scripts"))
from long_functions import LIMIT, REPO, long_functions

#: (path, qualified name) → its length today, the most it may have until it is split.
CEILINGS: dict[tuple[str, str], int] = {}


def test_no_function_in_dimacq_grows_past_the_limit() -> None:
    found = {(path, name): n for n, path, _line, name in long_functions(REPO / "dimacq")}
    new = {k: n for k, n in found.items() if k not in CEILINGS}
    grown = {k: (n, CEILINGS[k]) for k, n in found.items() if k in CEILINGS and n > CEILINGS[k]}
    assert not new, f"functions over {LIMIT} lines; split them into named steps: {new}"
    assert not grown, f"listed long functions that grew (lines, ceiling): {grown}"


def test_the_ceiling_list_names_only_functions_still_over_the_limit() -> None:
    found = {(path, name) for _n, path, _line, name in long_functions(REPO / "dimacq")}
    stale = sorted(set(CEILINGS) - found)
    assert not stale, f"split below {LIMIT} lines: remove from CEILINGS: {stale}"
