"""Uncertainty: jackknife formula vs explicit leave-one-out, bootstrap, effective samples, coverage."""

from __future__ import annotations

import numpy as np
import pytest
from _selection_support import forward_case

from dimacq.errors import SetupError
from dimacq.pipeline.dim import assemble, solve_system
from dimacq.pipeline.uncertainty import effective_samples, estimate_uncertainty


def test_jackknife_standard_error_formula() -> None:
    c = forward_case(1, triax_error_deg=0.5)
    sy = assemble(c.frf, c.nominal)
    res = solve_system(sy)
    u = estimate_uncertainty(sy, res)
    loo = np.array(
        [
            solve_system(sy.select_inputs([k for k in range(24) if k != j])).parameters
            for j in range(24)
        ]
    )
    se = np.sqrt(23 / 24 * np.sum((loo - loo.mean(axis=0)) ** 2, axis=0))
    assert u.parameters["m"].se_inputs == pytest.approx(se[0], rel=1e-9)
    assert u.parameters["Izz"].se_inputs == pytest.approx(se[9], rel=1e-9)
    p = u.parameters["m"]
    assert p.ci95[0] < p.value < p.ci95[1]
    assert p.standard_error >= p.se_inputs
    assert u.to_json()["m"]["ci95"] == list(p.ci95)


def test_bootstrap_is_seeded_and_close_to_jackknife() -> None:
    c = forward_case(2, triax_error_deg=0.5)
    sy = assemble(c.frf, c.nominal)
    res = solve_system(sy)
    b1 = estimate_uncertainty(sy, res, method="bootstrap", n_bootstrap=80, seed=3)
    b2 = estimate_uncertainty(sy, res, method="bootstrap", n_bootstrap=80, seed=3)
    j = estimate_uncertainty(sy, res)
    assert b1.parameters["m"].se_inputs == b2.parameters["m"].se_inputs
    assert 0.4 < b1.parameters["m"].se_inputs / j.parameters["m"].se_inputs < 2.5
    with pytest.raises(SetupError):
        estimate_uncertainty(sy, res, method="nope")  # type: ignore[arg-type]


def test_known_parameters_have_zero_uncertainty() -> None:
    c = forward_case(3)
    sy = assemble(c.frf, c.nominal)
    res = solve_system(sy, known={"m": 18.175})
    u = estimate_uncertainty(sy, res, known={"m": 18.175})
    assert u.parameters["m"].standard_error == 0.0 and u.parameters["cx"].standard_error > 0


def test_effective_samples() -> None:
    rng = np.random.default_rng(0)
    assert effective_samples(rng.normal(size=400)) > 200
    ar = np.zeros(400)
    for k in range(1, 400):
        ar[k] = 0.95 * ar[k - 1] + rng.normal()
    assert effective_samples(ar) < 40  # τ ≈ (1 + 0.95)/(1 − 0.95) = 39


def test_interval_covers_the_truth() -> None:
    """Coverage of the 95 % intervals over seeded trials with 0.5° sensor errors (sensor-node
    jackknife included, as the analysis service does)."""
    hits = np.zeros(10)
    n = 12
    for s in range(n):
        c = forward_case(500 + s, triax_error_deg=0.5)
        sy = assemble(c.frf, c.nominal)
        res = solve_system(sy)
        nodes = np.array([o.node for o in c.frf.outputs if o.node < 100])
        rs = [
            assemble(c.frf, c.nominal, response_weights=(nodes != g).astype(float))
            for g in np.unique(nodes)
        ]
        u = estimate_uncertainty(sy, res, response_systems=rs)
        truth = c.truth.parameter_vector(np.zeros(3))
        truth[1:4] = c.truth.cg_m
        for k, name in enumerate(u.parameters):
            lo, hi = u.parameters[name].ci95
            hits[k] += lo <= truth[k] <= hi
    assert hits.sum() / (10 * n) > 0.8
