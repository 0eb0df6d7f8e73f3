"""Static (dead-weight) calibration session: a plan that cannot determine the matrix is refused
before anyone is asked to lift a weight (the run through the wire is in
test_loadcell_calibration_real.py and, with the circular check, in tests/cli)."""

from __future__ import annotations

import pytest

from dimacq.errors import SetupError
from dimacq.pipeline.loadcell_calibration import LoadPlan, standard_load_plan
from dimacq.services.calibration.loadcell_calibration import run_static_calibration
from dimacq.simulators.lab.bridge import strain_gauge_cell


def test_plan_that_cannot_determine_the_matrix_is_refused_before_any_load() -> None:
    plan = standard_load_plan(strain_gauge_cell(501).rated_load)
    keep = tuple(c for c in plan.cases if c.gravity[2] == 0)  # cell never upright: no Fz
    asked: list[object] = []

    class NoCell:
        def __getattr__(self, name: str) -> object:
            raise AssertionError(f"the amplifier was used ({name}) for a refused plan")

    with pytest.raises(SetupError, match="Fz"):
        run_static_calibration(
            NoCell(),  # type: ignore[arg-type]
            LoadPlan(keep, plan.rated_load),
            lambda c, k: asked.append(c),  # type: ignore[arg-type,func-returns-value]
        )
    assert not asked
