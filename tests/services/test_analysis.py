"""Analysis service: the whole chain on the forward model, JSON keys for ``dimacq solve``."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from _selection_support import forward_case

from dimacq.services.analysis import AnalysisOptions, analyse


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
