"""The planning core (dimacq.pipeline.planning) against independent answers: the full information
assembled row by row, the covariance of a maximum a posteriori fit with a numerical Jacobian over
simulated tests, brute force over every layout of a small candidate set, and a case whose best
choice is known (triaxes far from the body's centre beat the same triaxes near it)."""

from __future__ import annotations

import itertools
from dataclasses import replace

import numpy as np
import pytest
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from dimacq.model.properties import THESIS_CALIBRATION_MASS, RigidBodyProperties
from dimacq.model.setup import Excitation, ResponseChannel, TestSetup
from dimacq.pipeline import planning as pl

PROPS = THESIS_CALIBRATION_MASS


def _setup(triax_pos: np.ndarray, inputs: list[tuple[np.ndarray, np.ndarray]]) -> TestSetup:
    rng = np.random.default_rng(5)
    responses = []
    for n, p in enumerate(triax_pos, start=1):
        R = Rotation.from_rotvec(rng.normal(scale=0.3, size=3)).as_matrix()
        for k in range(3):
            responses.append(
                ResponseChannel(
                    node=n, direction=k + 1, position_m=tuple(p), direction_gcs=tuple(R[:, k])
                )
            )
    exc = [
        Excitation(node=100 + j, position_m=tuple(p), direction_gcs=tuple(d / np.linalg.norm(d)))
        for j, (p, d) in enumerate(inputs)
    ]
    return TestSetup(responses=tuple(responses), excitations=tuple(exc))


def _box_inputs(n: int, seed: int = 1) -> list[tuple[np.ndarray, np.ndarray]]:
    """Inputs on the faces of a 0.4 m box, struck inwards (slightly oblique)."""
    rng = np.random.default_rng(seed)
    out = []
    for j in range(n):
        axis = j % 3
        p = rng.uniform(-0.2, 0.2, 3)
        p[axis] = 0.2 if (j // 3) % 2 == 0 else -0.2
        d = -np.sign(p[axis]) * np.eye(3)[axis] + rng.normal(scale=0.1, size=3)
        out.append((p, d))
    return out


CORNERS = np.array(list(itertools.product((-1, 1), repeat=3)), float)


def _model(setup: TestSetup, **kw: float) -> pl.PlanModel:
    errors = replace(pl.ErrorModel.from_setup(setup, noise=0.01, n_lines=41), **kw)
    return pl.build_model(pl.candidates_from_setup(setup), PROPS, errors)


def test_eliminated_forms_equal_the_full_information() -> None:
    setup = _setup(0.2 * CORNERS[:5], _box_inputs(9))
    model = _model(setup)
    lay = pl.Layout((0, 2, 3, 4), (0, 1, 3, 5, 6, 8))
    full = pl.x_covariance(pl.dense_information(model, lay), model)
    S = pl.input_information(model, lay.triaxes)[list(lay.inputs)].sum(axis=0)
    S[10:, 10:] += np.eye(S.shape[0] - 10)
    T = pl.triax_information(model, lay.inputs)[list(lay.triaxes)].sum(axis=0)
    T[10:, 10:] += np.eye(T.shape[0] - 10)
    for cov in (pl.x_covariance(S, model), pl.x_covariance(T, model)):
        np.testing.assert_allclose(cov, full, rtol=1e-7, atol=1e-12 * np.abs(full).max())


def _forward(theta: np.ndarray, cand: pl.Candidates, lay: pl.Layout, P: np.ndarray) -> np.ndarray:
    """H of the layout for parameters [x (10), per triax δr δθ, per channel gain, per input δp
    δβ] — the physics written again, independently of the planning module's derivatives.

    ``theta`` of shape (n,) gives H (n_channels, n_inputs); shape (K, n) gives K of them at
    once (the columns of a finite-difference Jacobian in one call)."""
    th = np.atleast_2d(theta)
    K = th.shape[0]
    x = th[:, :10]
    T, J = lay.triaxes, lay.inputs
    nT, nJ = len(T), len(J)
    ch = [c for c in range(cand.channel_triax.size) if cand.channel_triax[c] in T]
    slot = [T.index(int(cand.channel_triax[c])) for c in ch]
    o = 10
    tri = th[:, o : o + 6 * nT].reshape(K, nT, 6)
    o += 6 * nT
    gain = 1 + th[:, o : o + len(ch)]
    o += len(ch)
    inp = th[:, o : o + 6 * nJ].reshape(K, nJ, 6)
    m, s, i6 = x[:, 0], x[:, 1:4], x[:, 4:]
    I = i6[:, [0, 1, 2, 1, 3, 4, 2, 4, 5]].reshape(K, 3, 3)
    z = np.zeros(K)
    S = np.stack([z, -s[:, 2], s[:, 1], s[:, 2], z, -s[:, 0], -s[:, 1], s[:, 0], z], 1)
    S = S.reshape(K, 3, 3)
    M = np.block([[m[:, None, None] * np.eye(3), -S], [S, I]])
    r = cand.positions[ch] - P + tri[:, slot, :3]
    R = Rotation.from_rotvec(tri[:, slot, 3:].reshape(-1, 3)).as_matrix()
    d = np.einsum("knij,nj->kni", R.reshape(K, len(ch), 3, 3), cand.directions[ch])
    psi = np.concatenate([d, np.cross(r, d)], axis=2)
    Re = Rotation.from_rotvec(inp[:, :, 3:].reshape(-1, 3)).as_matrix().reshape(K, nJ, 3, 3)
    e = np.einsum("knij,nj->kni", Re, cand.input_directions[list(J)])
    p = cand.input_positions[list(J)] - P + inp[:, :, :3]
    phi = np.concatenate([e, np.cross(p, e)], axis=2).transpose(0, 2, 1)
    H = gain[:, :, None] * (psi @ np.linalg.solve(M, phi))
    return H if theta.ndim == 2 else H[0]


@pytest.mark.slow
def test_predicted_covariance_matches_map_fits_of_simulated_tests() -> None:
    """Fisher information vs Monte Carlo: 150 simulated tests of a small layout (errors drawn
    from the error model by ``simulated_frf``), each fitted by MAP with scipy's numerical
    Jacobian; the spread of the fitted parameters matches the predicted standard deviations."""
    setup = _setup(0.2 * CORNERS[[0, 3, 5, 6]], _box_inputs(8))
    model = _model(setup, force_gain_rel=0.0, noise=0.02)
    cand, errors = model.candidates, model.errors
    lay = pl.Layout((0, 1, 2, 3), tuple(range(8)))
    cov = pl.layout_covariance(model, lay)
    P = cand.reference_point_m
    x0 = model.x0
    nT, nJ = len(lay.triaxes), len(lay.inputs)
    n_ch = 3 * nT
    deg = np.pi / 180
    sig = np.concatenate(
        [
            model.x_scale,
            np.tile([errors.sensor_position_m] * 3 + [errors.sensor_orientation_deg * deg] * 3, nT),
            [errors.accel_gain_rel] * n_ch,
            np.tile([errors.input_position_m] * 3 + [errors.line_of_action_deg * deg] * 3, nJ),
        ]
    )
    theta0 = np.concatenate([x0, np.zeros(sig.size - 10)])
    H0 = _forward(theta0, cand, lay, P)
    assert np.allclose(H0, model.H)  # the layout is every candidate
    sd = errors.noise * pl.noise_scale(model.H, errors.noise_model) / np.sqrt(2 * errors.n_lines)
    eye = np.eye(sig.size)

    def jac(u: np.ndarray, *_: object) -> np.ndarray:
        """Forward differences, scipy's '2-point' step (√ε·max(1, |u|)), every column of the
        independent forward model in one batched call (the residual is linear in the data)."""
        h = np.sqrt(np.finfo(float).eps) * np.maximum(1.0, np.abs(u))
        th = theta0 + np.vstack([u, u + h[:, None] * eye]) * sig
        F = (_forward(th, cand, lay, P) / sd).reshape(th.shape[0], -1)
        return np.vstack([((F[1:] - F[0]) / h[:, None]).T, eye[10:]])

    est = []
    for i in range(150):
        rng = np.random.default_rng([7, i])
        Hs, _ = pl.simulated_frf(cand, lay, PROPS, errors, errors.n_lines, rng)
        data = Hs.real.mean(axis=0)

        def resid(u: np.ndarray, data: np.ndarray = data) -> np.ndarray:
            th = theta0 + u * sig
            r = ((_forward(th, cand, lay, P) - data) / sd).ravel()
            return np.concatenate([r, u[10:]])  # priors of the nuisances, in σ units

        fit = least_squares(resid, np.zeros(sig.size), jac=jac, method="lm", x_scale=1.0)
        est.append(x0 + fit.x[:10] * model.x_scale)
    est = np.array(est)
    sd_mc = est.std(axis=0, ddof=1)
    sd_pred = np.sqrt(np.diag(cov))
    # 150 samples: the standard deviation's own 1σ is ~6 %
    np.testing.assert_allclose(sd_mc, sd_pred, rtol=0.2)
    bias = np.abs(est.mean(axis=0) - x0) / sd_pred
    assert bias.max() < 4 / np.sqrt(150) * 1.5


@pytest.mark.slow
def test_exchange_finds_the_best_layout_of_a_small_candidate_set() -> None:
    """Brute force over every layout of 3 of 6 triaxes and 4 of 7 inputs."""
    pos = np.array([[0.2, 0.2, 0.2], [-0.2, 0.1, 0.2], [0.05, -0.2, -0.1], [0.02, 0.03, 0.0],
                    [-0.2, -0.2, -0.2], [0.2, -0.05, -0.2]])  # fmt: skip
    setup = _setup(pos, _box_inputs(7, seed=3))
    model = _model(setup)
    best = min(
        (pl.criterion(model, pl.Layout(t, j)), t, j)
        for t in itertools.combinations(range(6), 3)
        for j in itertools.combinations(range(7), 4)
    )
    chosen = pl.exchange_select(model, 3, 4)
    assert pl.criterion(model, chosen) <= best[0] * (1 + 1e-9)
    assert (chosen.triaxes, chosen.inputs) == (best[1], best[2])


def test_far_triaxes_are_chosen_over_near_ones() -> None:
    """Eight triaxes at the corners of a 0.4 m cube and the same eight at a tenth of that: the
    lever arms of the far ones see the rotations ten times better; four of 16 are all far."""
    setup = _setup(np.r_[0.2 * CORNERS, 0.02 * CORNERS], _box_inputs(12))
    model = _model(setup)
    lay = pl.exchange_select(model, 4, 8)
    assert all(t < 8 for t in lay.triaxes)
    near = pl.Layout(tuple(t + 8 for t in lay.triaxes), lay.inputs)
    b_far = pl.predicted_bounds(model, pl.layout_covariance(model, lay))
    b_near = pl.predicted_bounds(model, pl.layout_covariance(model, near))
    assert b_far.principal_pct < b_near.principal_pct / 2
    rand = [pl.criterion(model, lay2) for lay2 in pl.random_layouts(16, 12, 4, 8, 50, seed=0)]
    assert pl.criterion(model, lay) <= min(rand)


def test_predicted_bounds_of_a_known_covariance() -> None:
    """Mass bound = 1.96 σ; the largest of three independent equal CG errors: its 95 % quantile
    solves (2Φ(q/σ) − 1)³ = 0.95, q = 2.388 σ."""
    setup = _setup(0.2 * CORNERS[:4], _box_inputs(6))
    model = _model(setup)
    jt = pl.target_jacobian(model)
    # a covariance of x whose target covariance is diagonal: build it in target space
    ct = np.diag([0.01**2, 1e-6, 1e-6, 1e-6, 1e-9, 1e-9, 1e-9])
    cov = np.linalg.pinv(jt) @ ct @ np.linalg.pinv(jt).T
    b = pl.predicted_bounds(model, cov)
    assert b.mass_pct == pytest.approx(100 * 1.96 * 0.01 / PROPS.mass_kg, rel=1e-3)
    assert b.cg_mm == pytest.approx(2.388 * 1.0, rel=0.02)


def test_properties_and_layout_errors_are_refused() -> None:
    setup = _setup(0.2 * CORNERS[:4], _box_inputs(6))
    model = _model(setup)
    with pytest.raises(Exception, match="--triaxes 5"):
        pl.exchange_select(model, 5, 3)
    with pytest.raises(Exception, match="--inputs 0"):
        pl.exchange_select(model, 2, 0)
    with pytest.raises(Exception, match="positive noise"):
        pl.build_model(model.candidates, PROPS, replace(model.errors, noise=0.0))
    assert isinstance(PROPS, RigidBodyProperties)
