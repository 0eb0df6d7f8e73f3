"""Uncertainty: jackknife formula vs explicit leave-one-out, bootstrap, effective samples, coverage."""

from __future__ import annotations

import numpy as np
import pytest
from _selection_support import forward_case

from dimacq.errors import SetupError
from dimacq.model.properties import vector_to_inertia
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
    # the interval is value ± t(0.975, N−1)·SE with SE the root sum of squares of its parts
    from scipy import stats

    se = np.sqrt(p.se_inputs**2 + p.se_responses**2 + p.se_geometry**2 + p.se_lines**2)
    assert p.standard_error == pytest.approx(se, rel=1e-12)
    tq = stats.t.ppf(0.975, 23)
    assert p.ci95 == pytest.approx((p.value - tq * se, p.value + tq * se), rel=1e-12)
    assert u.n_rank_deficient == 0 and u.components == ("inputs", "lines")
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


@pytest.mark.slow
def test_interval_covers_the_truth() -> None:
    """Coverage of the 95 % intervals over seeded trials with 0.5° sensor errors, as the analysis
    service computes them (inputs, sensor nodes, lines, stated geometry uncertainty): at least
    90 % of the parameters over the trials (a 95 % interval; 12 × 10 parameters)."""
    from dimacq.services.solve.analysis import AnalysisOptions, analyse

    hits = np.zeros(10)
    n = 12
    for s in range(n):
        c = forward_case(500 + s, triax_error_deg=0.5)
        rep = analyse(
            c.frf,
            c.nominal,
            AnalysisOptions(
                select_responses=False,
                select_inputs=False,
                band_hz=(20.0, 200.0),
                geometry_samples=200,
            ),
        )
        u = rep.uncertainty
        truth = c.truth.parameter_vector(np.zeros(3))
        truth[1:4] = c.truth.cg_m
        for k, name in enumerate(u.parameters):
            lo, hi = u.parameters[name].ci95
            hits[k] += lo <= truth[k] <= hi
    assert hits.sum() / (10 * n) >= 0.9


@pytest.mark.slow
def test_interval_covers_certificate_errors() -> None:
    """Coverage over draws of the calibration certificates: each accelerometer axis off by
    ``ε ~ N(0, 0.5 %)``, the hammer by ``η ~ N(0, 0.5 %)`` (every FRF × 1/(1+η)), exact geometry
    stated as exact, 0.2 % noise. With the stated transducer uncertainty the 95 % intervals of
    mass and inertia hold the truth for ≥ 90 % of (draw, parameter) pairs; with it set to zero they
    do not (the transducer term is what makes them hold)."""
    from dimacq.model.setup import GeometryUncertainty, TransducerUncertainty
    from dimacq.pipeline.selection._common import response_geometry
    from dimacq.services.solve.analysis import AnalysisOptions, analyse

    exact = GeometryUncertainty(
        sensor_position_m=0.0,
        sensor_orientation_deg=0.0,
        input_position_m=0.0,
        line_of_action_deg=0.0,
        load_cell_position_m=0.0,
        load_cell_orientation_deg=0.0,
        source="stated",
    )
    scaled_params = [0, 4, 5, 6, 7, 8, 9]  # mass and inertia: what the certificates scale
    hits = {"stated": 0, "none": 0}
    n = 0
    for s in range(10):
        c = forward_case(700 + s, noise=0.002)
        rng = np.random.default_rng(900 + s)
        rows = np.asarray(response_geometry(c.frf, c.nominal).output_index)
        f = np.full(c.frf.H.shape[1], 1.0)
        f[rows] = 1.0 + 0.005 * rng.standard_normal(rows.size)
        f /= 1.0 + 0.005 * rng.standard_normal()
        frf = c.frf.replace(H=c.frf.H * f[None, :, None])
        truth = c.truth.parameter_vector(np.zeros(3))
        for key, tu in (
            ("stated", TransducerUncertainty(source="stated")),
            (
                "none",
                TransducerUncertainty(
                    accel_sensitivity_rel=0.0, force_sensitivity_rel=0.0, loadcell_matrix_rel=0.0
                ),
            ),
        ):
            setup = c.nominal.model_copy(
                update={"geometry_uncertainty": exact, "transducer_uncertainty": tu}
            )
            rep = analyse(
                frf,
                setup,
                AnalysisOptions(
                    select_responses=False,
                    select_inputs=False,
                    band_hz=(20.0, 200.0),
                    geometry_samples=200,
                ),
            )
            names = list(rep.uncertainty.parameters)
            for k in scaled_params:
                lo, hi = rep.uncertainty.parameters[names[k]].ci95
                hits[key] += lo <= truth[k] <= hi
        n += len(scaled_params)
    assert hits["stated"] / n >= 0.9, hits
    assert hits["none"] / n < 0.7, hits


def test_geometry_monte_carlo_matches_linearisation() -> None:
    """The vectorised joint solve over geometries reproduces solve_system at the nominal geometry,
    and the Monte Carlo spread agrees with first-order propagation (two independent answers)."""
    from dimacq.pipeline.selection._common import response_geometry
    from dimacq.pipeline.uncertainty import (
        band_sums,
        geometry_spread,
        joint_parameters_for_geometry,
    )

    c = forward_case(4, triax_error_deg=0.5)
    frf = c.frf.band(20.0, 200.0)
    sy = assemble(frf, c.nominal)
    res = solve_system(sy)
    geo = response_geometry(frf, c.nominal)
    ipos = np.array([e.position_m for e in c.nominal.excitations])
    idir = np.array([e.direction_gcs for e in c.nominal.excitations])
    H = frf.H[:, geo.output_index]
    w = np.ones(len(geo.channels))
    p0 = joint_parameters_for_geometry(
        sy,
        band_sums(sy, H),
        geo.positions_m[None],
        geo.directions[None],
        w,
        ipos[None],
        idir[None],
    )[0]
    assert p0 == pytest.approx(res.parameters, rel=1e-8, abs=1e-12)
    g = geometry_spread(
        sy,
        H,
        geo.positions_m,
        geo.directions,
        geo.nodes,
        w,
        ipos,
        idir,
        sensor_position_m=0.002,
        sensor_orientation_deg=0.5,
        input_position_m=0.002,
        line_of_action_deg=1.0,
        n_samples=2000,
        seed=1,
    )
    assert np.all(g.se > 0)
    # 2000 samples: the standard deviation is known to about 1.6 % (1σ); allow 10 %
    assert g.se == pytest.approx(g.se_linear, rel=0.10)


@pytest.mark.slow
def test_transducer_calibration_enters_the_spread_as_derived() -> None:
    """A hammer whose certificate is off by η divides every FRF (accelerations and load-cell
    reactions) by (1+η). Solving those data equals solving the unscaled data with the input forces
    scaled by (1+η) — what the spread samples — checked against the real solver with and without
    load cells; without them mass and inertia scale by exactly (1+η), so the force term of the mass
    spread is m·σ_f (closed form). Per-channel accelerometer errors: Monte Carlo against first-order
    propagation, and against re-solving data whose channels are really rescaled (a second method,
    not the Ψ-row scaling the spread uses)."""
    from dimacq.pipeline.selection._common import response_geometry
    from dimacq.pipeline.uncertainty import (
        band_sums,
        geometry_spread,
        joint_parameters_for_geometry,
    )

    eta = 0.02
    common = dict(
        sensor_position_m=0.0,
        sensor_orientation_deg=0.0,
        input_position_m=0.0,
        line_of_action_deg=0.0,
        n_samples=2000,
        seed=3,
    )
    for support in ("bungee", "free"):
        c = forward_case(2, noise=0.0, support=support)
        frf = c.frf.band(20.0, 200.0)
        sy = assemble(frf, c.nominal)
        assert (len(sy.load_cells) > 0) == (support == "bungee")
        geo = response_geometry(frf, c.nominal)
        ipos = np.array([e.position_m for e in c.nominal.excitations])
        idir = np.array([e.direction_gcs for e in c.nominal.excitations])
        H = frf.H[:, geo.output_index]
        w = np.ones(len(geo.channels))
        scaled = solve_system(assemble(frf.replace(H=frf.H / (1 + eta)), c.nominal)).parameters
        equivalent = joint_parameters_for_geometry(
            sy, band_sums(sy, H), geo.positions_m[None], geo.directions[None], w,
            ipos[None], idir[None] * (1 + eta),
        )[0]  # fmt: skip
        assert equivalent == pytest.approx(scaled, rel=1e-8, abs=1e-12)
        g = geometry_spread(
            sy, H, geo.positions_m, geo.directions, geo.nodes, w, ipos, idir,
            force_sensitivity_rel=0.01, **common,
        )  # fmt: skip
        assert g.se == pytest.approx(g.se_linear, rel=0.10, abs=1e-12)
        # the CG is a ratio: no hammer term without reactions, a trace (< 1 µm) with them
        assert g.se[1:4] == pytest.approx(0.0, abs=1e-9 if support == "free" else 1e-6)
        if support == "free":
            base = solve_system(sy).parameters
            assert scaled[[0, *range(4, 10)]] == pytest.approx(
                base[[0, *range(4, 10)]] * (1 + eta), rel=1e-9, abs=1e-12
            )
            assert g.se_linear[0] == pytest.approx(0.01 * base[0], rel=1e-3)

    ga = geometry_spread(
        sy, H, geo.positions_m, geo.directions, geo.nodes, w, ipos, idir,
        accel_sensitivity_rel=0.01, **common,
    )  # fmt: skip
    assert ga.se == pytest.approx(ga.se_linear, rel=0.10)
    rng = np.random.default_rng(7)
    out_rows = np.asarray(geo.output_index)
    draws = []
    for _ in range(300):
        f = np.ones(frf.H.shape[1])
        f[out_rows] = 1.0 + rng.normal(scale=0.01, size=out_rows.size)
        draws.append(solve_system(assemble(frf.replace(H=frf.H * f[None, :, None]), c.nominal)))
    se_data = np.std([d.parameters for d in draws], axis=0, ddof=1)
    # 300 re-solves: the standard deviation is known to about 4 % (1σ); allow 15 %
    assert ga.se_linear == pytest.approx(se_data, rel=0.15)


def test_principal_moment_uncertainty() -> None:
    """Principal moments: value equals the solution's (from the tensor about the CG); the input
    term is the jackknife of the leave-one-out solutions' principal moments, each computed
    independently through RigidBodyProperties; a first-order propagation of the parameters'
    jackknife covariance agrees."""
    from dimacq.model.properties import RigidBodyProperties

    c = forward_case(1, triax_error_deg=0.5)
    sy = assemble(c.frf, c.nominal)
    res = solve_system(sy)
    u = estimate_uncertainty(sy, res)
    w_res = np.linalg.eigvalsh(res.inertia_cg_kgm2)
    assert [p.value for p in u.principal] == pytest.approx(list(w_res), rel=1e-12)

    def principal(p: np.ndarray) -> np.ndarray:
        props = RigidBodyProperties.from_about_point(
            p[0], p[1:4], vector_to_inertia(p[4:]), res.reference_point_m
        )
        return np.linalg.eigvalsh(props.inertia_cg_kgm2)

    w = np.array([principal(s) for s in u.samples])
    se = np.sqrt(23 / 24 * np.sum((w - w.mean(axis=0)) ** 2, axis=0))
    assert [p.se_inputs for p in u.principal] == pytest.approx(list(se), rel=1e-9)
    # first order: J Σ Jᵀ with J the numerical gradient of the principal moments
    cov = 23 / 24 * (u.samples - u.samples.mean(axis=0)).T @ (u.samples - u.samples.mean(axis=0))
    J = np.empty((3, 10))
    for k in range(10):
        h = 1e-6 * max(abs(res.parameters[k]), 1e-3)
        dp = np.zeros(10)
        dp[k] = h
        J[:, k] = (principal(res.parameters + dp) - principal(res.parameters - dp)) / (2 * h)
    se_lin = np.sqrt(np.diag(J @ cov @ J.T))
    assert [p.se_inputs for p in u.principal] == pytest.approx(list(se_lin), rel=0.1)
    rel = u.relative_se()
    assert set(rel) == {"m", "I1", "I2", "I3"}
    assert rel["I1"] == pytest.approx(u.principal[0].standard_error / w_res[0])
    assert len(u.to_json()["principal_moments"]) == 3
