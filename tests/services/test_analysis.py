"""Analysis service: the whole chain on the forward model, JSON keys for ``dimacq solve``."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from _selection_support import forward_case

from dimacq.services.solve.analysis import AnalysisOptions, analyse


@pytest.mark.slow
def test_full_chain_finds_bad_channels_and_inputs(tmp_path: Path) -> None:
    c = forward_case(
        11, triax_error_deg=0.5, n_bad_channels=2, bad_channel_deg=20.0, n_bad_inputs=2
    )
    opts = AnalysisOptions(
        select_responses=True, select_inputs=True, repair_orientation=True, plots_dir=tmp_path
    )
    rep = analyse(c.frf, c.nominal, opts)
    j = json.loads(json.dumps(rep.to_json()))
    assert {(e["node"], e["direction"]) for e in j["excluded_responses"]} == set(c.bad_channels)
    assert {(e["node"], e["direction"]) for e in j["excluded_inputs"]} == set(c.bad_inputs)
    for key in (
        "uncertainty",
        "orientation_corrections",
        "band_selection",
        "mass_kg",
        "excitation_check",
    ):
        assert key in j
    assert all(o["applied"] for o in j["orientation_corrections"])
    assert j["selection_applied"]["orientation_repair"]
    assert abs(rep.result.mass_kg - c.truth.mass_kg) / c.truth.mass_kg < 0.005
    assert np.linalg.norm(rep.result.cg_m - c.truth.cg_m) < 1e-3
    lo, hi = j["uncertainty"]["m"]["ci95"]
    assert lo <= c.truth.mass_kg <= hi  # the interval holds the truth, not only the estimate
    assert len(rep.plots) == 8 and all(p.exists() for p in rep.plots)


@pytest.mark.slow
def test_defaults_and_user_overrides() -> None:
    c = forward_case(12)
    rep = analyse(c.frf, c.nominal)  # defaults: automatic band, both selections, intervals
    assert rep.band_selection["automatic"] and rep.band_selection["qualified"]
    assert rep.excluded_responses == [] and rep.excluded_inputs == []
    assert rep.verdict in ("ok", "warn") and rep.verdict_reasons
    assert "geometry" in rep.uncertainty.components and "responses" in rep.uncertainty.components
    off = analyse(
        c.frf,
        c.nominal,
        AnalysisOptions(auto_band=False, select_responses=False, select_inputs=False),
    )
    assert off.response_selection is None and off.input_selection is None
    assert (
        off.orientation_corrections == [] and "whole measured span" in off.band_selection["reason"]
    )
    ch = c.nominal.responses[0]
    ex = c.nominal.excitations[0]
    rep2 = analyse(
        c.frf,
        c.nominal,
        AnalysisOptions(
            band_hz=(50.0, 150.0), force_out=[(ch.node, ch.direction), (ex.node, ex.direction)]
        ),
    )
    assert rep2.excluded_responses == [{"node": ch.node, "direction": ch.direction}]
    assert rep2.excluded_inputs == [{"node": ex.node, "direction": ex.direction}]
    assert rep2.result.band_hz[0] >= 50.0 and rep2.band_selection["reason"] == "given by the user"


def test_verdict_warns_on_an_interval_too_wide_to_be_useful() -> None:
    """The same data and solution: with the stated geometry uncertainty of a careful lab the
    intervals are narrow enough (precision ok); with 1 cm positions and 3° directions stated they
    are not, and the verdict warns naming the widest ones; far wider than the limits it fails."""
    from dimacq.model.setup import GeometryUncertainty
    from dimacq.services.solve.analysis import CI95_LIMIT_PRINCIPAL

    c = forward_case(13)
    # the equation-error estimate: the stated uncertainty changes its intervals, not the estimate
    # (the refined estimate depends on it through the priors)
    est = {"unbiased": False, "refine_geometry": False}
    opts = AnalysisOptions(
        select_responses=False, select_inputs=False, band_hz=(50.0, 150.0), **est
    )
    fine = analyse(c.frf, c.nominal, opts)
    prec = next(r for r in fine.verdict_reasons if r.check == "precision")
    assert prec.severity == "ok" and fine.verdict == "ok"
    loose = c.nominal.model_copy(
        update={
            "geometry_uncertainty": GeometryUncertainty(
                sensor_position_m=0.01,
                sensor_orientation_deg=3.0,
                input_position_m=0.01,
                line_of_action_deg=3.0,
                source="stated",
            )
        }
    )
    wide = analyse(c.frf, loose, opts)
    assert wide.result.parameters == pytest.approx(fine.result.parameters, rel=1e-12)
    prec = next(r for r in wide.verdict_reasons if r.check == "precision")
    half = [0.5 * (p.ci95[1] - p.ci95[0]) / p.value for p in wide.uncertainty.principal]
    assert max(half) > CI95_LIMIT_PRINCIPAL
    assert prec.severity == "warn" and wide.verdict == "warn" and "I1 ±" in prec.message
    strict = analyse(
        c.frf,
        loose,
        AnalysisOptions(
            select_responses=False,
            select_inputs=False,
            band_hz=(50.0, 150.0),
            ci95_limit_principal=max(half) / 20,
            **est,
        ),
    )
    assert strict.verdict == "fail"
    assert next(r for r in strict.verdict_reasons if r.check == "precision").severity == "fail"
