"""The estimator step's guard (dimacq.services.solve.estimation): an output-error fit left on the
stated geometry is used only when its misfit is near the FRFs' measured noise — also when the
refinement was asked for and refused, whose fit carries the refined fit's variance factor.

Found on an acquired chain check through the USB-1808X (reference block 48.38 kg): the refinement
was refused, the fit on the stated geometry reported a reduced χ² of 1.18 (9.5·10⁴ against the
measured noise) and its 49.54 kg (+2.4 %) became the chain factor; the equation-error estimate
on the same data is 48.38 kg."""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np
import pytest
from _selection_support import MASS_KG, make_case

from dimacq.pipeline.dim import solve
from dimacq.pipeline.output_error import OutputErrorResult, solve_output_error
from dimacq.services.solve import estimation
from dimacq.services.solve.analysis import AnalysisOptions

#: stands for the step's Uncertainty argument, which these cases return or pass on untouched
SENTINEL: Any = object()


def _smooth_errors(seed: int) -> Any:
    """Triaxes off by up to 3° (stated 0.5°) and a 10 % complex error per FRF that varies slowly
    over the band (the line-to-line scatter the noise is estimated from does not see it): the
    refinement is refused and the a posteriori variance factor has scaled the noise."""
    case = make_case(seed, noise=0.002, triax_error_deg=3.0)
    rng = np.random.default_rng(seed + 10)
    f = case.frf.frequencies_hz
    x = ((f - f[0]) / (f[-1] - f[0]))[:, None, None]
    shape = case.frf.H.shape[1:]

    def cn() -> np.ndarray:
        return (rng.normal(size=shape) + 1j * rng.normal(size=shape))[None]

    frf = dataclasses.replace(case.frf, H=case.frf.H * (1 + 0.1 * (cn() * x + cn() * (1 - x))))
    return case, frf


@pytest.mark.slow
def test_a_refused_refinement_leaves_a_fit_whose_misfit_is_judged_on_the_measured_noise(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    case, frf = _smooth_errors(0)
    oe = solve_output_error(frf, case.setup)
    # the situation: refused, χ² near 1 after the variance factor, far above the noise without
    assert not oe.refine_geometry and "refused" in oe.noise["refinement_refused"]
    assert oe.chi2_reduced < estimation.OE_MAX_CHI2_UNREFINED
    assert oe.noise["chi2_reduced_stated_noise"] > 100 * estimation.OE_MAX_CHI2_UNREFINED
    assert oe.parameters[0] / MASS_KG - 1 > 0.02  # the stated-geometry fit's bias (mass high)

    ee = solve(frf, case.setup)
    monkeypatch.setattr(estimation, "solve_output_error", lambda *a, **k: oe)
    n_in = len(frf.inputs)
    got, unc = estimation.output_error_step(
        frf,
        case.setup,
        ee,
        SENTINEL,  # returned untouched when the fit is not used
        np.ones(24),
        np.ones(n_in, bool),
        {},
        AnalysisOptions(),
        np.zeros((0, 3)),
    )
    note: dict[str, Any] = got.extras["output_error"]
    assert note["used"] is False
    assert "against the measured noise" in note["reason"]
    assert "refinement that would absorb it was refused" in note["reason"]
    assert note["refinement_refused"] == oe.noise["refinement_refused"]  # for the verdict
    np.testing.assert_array_equal(got.parameters, ee.parameters)  # the equation-error estimate
    assert unc is SENTINEL
    assert abs(got.parameters[0] / MASS_KG - 1) < abs(oe.parameters[0] / MASS_KG - 1)


def test_a_refined_fit_is_used_whatever_its_variance_factor(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """The guard is for fits on the stated geometry only: a refined fit's large variance factor
    (smooth errors the line scatter does not see) is in its intervals, not a reason to drop it."""
    case = make_case(2, noise=0.002, triax_error_deg=1.0)
    oe: OutputErrorResult = solve_output_error(case.frf, case.setup)
    assert oe.refine_geometry
    oe = dataclasses.replace(
        oe, noise={**oe.noise, "chi2_reduced_stated_noise": 1e4, "variance_factor": 1e4}
    )
    calls: list[bool] = []

    def applied(result: Any, fit: Any, unc: Any, hull: Any, setup: Any) -> tuple[Any, Any]:
        calls.append(fit is oe)
        return result, unc

    monkeypatch.setattr(estimation, "solve_output_error", lambda *a, **k: oe)
    monkeypatch.setattr(estimation, "_apply_output_error", applied)
    estimation.output_error_step(
        case.frf,
        case.setup,
        solve(case.frf, case.setup),
        SENTINEL,
        np.ones(24),
        np.ones(len(case.frf.inputs), bool),
        {},
        AnalysisOptions(),
        np.zeros((0, 3)),
    )
    assert calls == [True]


def test_the_refusal_stays_in_the_verdict_when_the_equation_error_estimate_is_reported() -> None:
    """The equation-error estimate that stays is no answer to the data the refinement could not
    reconcile: the verdict keeps its ``estimator:refinement`` warn (an x38-flexible-17 with the
    realistic scenario's errors: CG 10.9 mm off, reported ``ok`` without it)."""
    from dimacq.services.solve.verdict import estimator_checks

    note = {"used": False, "reason": "…", "refinement_refused": "geometry refinement refused: x"}
    (r,) = estimator_checks(note)
    assert (r.check, r.severity) == ("estimator:refinement", "warn")
    assert "equation-error estimate is reported" in r.message
    assert estimator_checks({"used": False, "reason": "χ² 12 with the stated geometry"}) == []
