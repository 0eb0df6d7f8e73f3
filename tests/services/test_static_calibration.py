"""Static (dead-weight) calibration through the CAN wire: the simulated bench behind the
amplifier simulator, the real driver, the virtual operator."""

from __future__ import annotations

import numpy as np
import pytest

from dimacq.errors import SetupError
from dimacq.pipeline.loadcell_calibration import LoadPlan, standard_load_plan
from dimacq.services.loadcell_calibration import (
    StaticSettings,
    run_static_calibration,
    simulated_static_calibration,
)
from dimacq.simulators.lab.bridge import strain_gauge_cell

FAST = StaticSettings(sample_rate_hz=10, settle_s=8.0, average_s=2.0, max_wait_s=20.0)


def test_static_calibration_over_the_wire_recovers_the_cell() -> None:
    cell = strain_gauge_cell(
        3, 501, creep_tau_s=1.5, swing_tau_s=0.8, temperature_ramp_k_per_s=2e-4
    )
    prompts: list[str] = []
    run = simulated_static_calibration(
        seed=3,
        cell=cell,
        minimal_plan=True,
        settings=FAST,
        time_scale=200.0,
        progress=lambda i, n, m: prompts.append(m),
    )
    cert = run.run.certificate
    assert run.matrix_error_rel < 1e-3
    np.testing.assert_allclose(cert.nonlinearity_pct_fs, 100 * cell.nonlinearity, rtol=0.1)
    np.testing.assert_allclose(cert.hysteresis_pct_fs, 100 * cell.hysteresis, rtol=0.1)
    assert cert.verdict == "ok", cert.reasons
    assert not run.run.unsettled.any()
    assert len(prompts) == len(run.run.plan.cases) + 1
    assert "kg on the hanger" in prompts[1]


def test_plan_that_cannot_determine_the_matrix_is_refused_before_any_load() -> None:
    plan = standard_load_plan(strain_gauge_cell(0, 501).rated_load)
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
