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
CEILINGS: dict[tuple[str, str], int] = {
    ("dimacq/cli/commands/acquire.py", "run"): 267,
    ("dimacq/services/acquisition/session.py", "ImpactSession.run"): 239,
    ("dimacq/services/solve/analysis.py", "_analyse"): 212,
    ("dimacq/cli/commands/demo.py", "_demo"): 234,
    ("dimacq/services/lab/acquisitions.py", "AcquisitionService._run"): 206,
    ("dimacq/services/geometry/digitizer_selftest.py", "run_selftest"): 184,
    ("dimacq/services/solve/verdict.py", "verdict"): 170,
    ("dimacq/services/calibration/inertial_calibration.py", "run_inertial_calibration"): 166,
    ("dimacq/pipeline/uncertainty.py", "geometry_spread"): 154,
    ("dimacq/pipeline/loadcell_calibration.py", "static_certificate"): 154,
    ("dimacq/cli/commands/solve.py", "register"): 139,
    ("dimacq/pipeline/selection/responses.py", "select_responses"): 136,
    ("dimacq/pipeline/sensitivity.py", "monte_carlo"): 135,
    ("dimacq/cli/commands/solve.py", "print_report"): 129,
    ("dimacq/services/lab/acquisitions.py", "AcquisitionService._start"): 125,
    ("dimacq/pipeline/frf_estimation.py", "estimate_frf"): 125,
    ("dimacq/backends/simulated.py", "SimulatedWorld.__init__"): 132,
    ("dimacq/pipeline/output_error/model.py", "_Problem.residual"): 122,
    # the photo-geometry chain, not yet split into named steps
    ("dimacq/services/geometry/photo_geometry.py", "geometry_from_photos"): 222,
    # the photo-geometry chain, not yet split into named steps
    ("dimacq/pipeline/photogrammetry/bundle.py", "adjust"): 165,
}


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
