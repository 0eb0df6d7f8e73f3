"""The inertial bench's accelerometer gains and the matrix's uncertainty, against independent
answers: the gains applied to a synthetic rigid body (known), the first-order propagation
against re-fitting the matrix with perturbed channels, and the amplification the module's
docstring states on the thesis mass (certificate scatter costs more than its mean)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from dimacq.errors import DataError
from dimacq.model.properties import THESIS_CALIBRATION_MASS
from dimacq.pipeline.inertial_bench import (
    jackknife_matrix_variance,
    matrix_gain_variance,
    rigid_body_gains,
)
from dimacq.pipeline.loadcell_calibration import inertial_calibration
from dimacq.pipeline.rigid_body import condense, load_cell_transform, response_matrix

CELL_POS = np.array([0.05, 0.0, 0.05])
CELL_ROT = Rotation.from_euler("z", 45, degrees=True).as_matrix()


def mass_matrix():
    return THESIS_CALIBRATION_MASS.mass_matrix(np.zeros(3))


def array(seed=0):
    """Eight triaxes at the corners of a 0.26 × 0.27 × 0.22 m box, each turned at random."""
    rng = np.random.default_rng(seed)
    corners = np.array(
        [[x, y, z] for x in (-0.08, 0.18) for y in (-0.13, 0.14) for z in (-0.19, 0.03)]
    )
    pos, dirs = [], []
    for c in corners:
        R = Rotation.from_rotvec(rng.normal(0, 0.3, 3)).as_matrix()
        for k in range(3):
            pos.append(c)
            dirs.append(R[:, k])
    return response_matrix(np.array(pos), np.array(dirs), np.zeros(3))


def rigid_frf(psi, n_lines=40, n_inputs=12, seed=1):
    """Accelerances of a rigid body (n_lines, n_ch, n_inputs) and the motion of P."""
    rng = np.random.default_rng(seed)
    a = rng.standard_normal((n_lines, 6, n_inputs)) + 1j * rng.standard_normal(
        (n_lines, 6, n_inputs)
    )
    return np.einsum("cb,lbi->lci", psi, a), a


def test_gains_of_a_rigid_body_are_recovered_up_to_the_certificates_mean() -> None:
    psi = array()
    H, _ = rigid_frf(psi)
    rng = np.random.default_rng(5)
    eps = 0.005 * rng.standard_normal(psi.shape[0])  # certificates read (1 + ε) × the truth
    g = rigid_body_gains(H * (1 + eps)[None, :, None], psi, 0.005)
    assert g.identified and g.separation < 1e-12 and g.residual_rel < 1e-6
    # true = gain × measured: gain = 1/(1 + ε), normalised to the certificates' log-mean
    want = np.exp(-np.log1p(eps) + np.mean(np.log1p(eps)))
    np.testing.assert_allclose(g.gains, want, rtol=1e-10)
    # the common scale is what the data cannot see: σ/√n, 0.1 % for 24 axes at 0.5 %
    assert g.scale_std == pytest.approx(0.005 / np.sqrt(24))
    np.testing.assert_allclose(g.relative_std, g.scale_std, rtol=1e-6)


def test_gains_not_identified_keep_the_certificates_and_their_scatter() -> None:
    psi = array()
    H, _ = rigid_frf(psi, n_lines=1, n_inputs=1)
    # one real motion: 18 equations off the rigid body for 23 gain ratios
    g = rigid_body_gains(H.real + 0j, psi, 0.005)
    assert not g.identified
    np.testing.assert_array_equal(g.gains, np.ones(24))
    np.testing.assert_allclose(g.covariance, 0.005**2 * np.eye(24))


def test_bad_shapes_and_non_finite_data_are_refused() -> None:
    psi = array()
    H, _ = rigid_frf(psi)
    with pytest.raises(DataError, match="n_ch"):
        rigid_body_gains(H[:, :20], psi, 0.005)
    H[0, 0, 0] = np.nan
    with pytest.raises(DataError, match="NaN"):
        rigid_body_gains(H, psi, 0.005)


def _fit(psi, a, H_meas, S, Tq):
    M = mass_matrix()
    T = load_cell_transform(CELL_POS, CELL_ROT, np.zeros(3), 1.0)
    F_L = np.einsum("ab,lbi->lai", np.linalg.solve(T, M), a)
    gauges = np.einsum("gb,lbi->lgi", S, F_L)
    a_meas = np.einsum("kc,lci->lki", Tq, H_meas)
    return inertial_calibration(gauges, a_meas, M, CELL_POS, CELL_ROT, np.zeros(3)).matrix


def test_matrix_variance_matches_refits_with_perturbed_channels() -> None:
    """First-order δC = Σ δ_i J_i against re-fitting C with each channel's gain off by δ_i:
    the variance of the re-fits over random δ (Monte Carlo) matches matrix_gain_variance."""
    psi = array()
    H, a = rigid_frf(psi, n_lines=4, n_inputs=6)
    S = np.random.default_rng(3).standard_normal((12, 6)) * np.array([1e-3] * 3 + [1e-2] * 3)
    Tq = condense(psi).transform
    C0 = _fit(psi, a, H, S, Tq)
    np.testing.assert_allclose(C0, np.linalg.pinv(S), rtol=1e-8, atol=1e-8)
    sig = 0.005
    rng = np.random.default_rng(11)
    errs = np.array(
        [
            _fit(psi, a, H * (1 + sig * rng.standard_normal(24))[None, :, None], S, Tq) - C0
            for _ in range(200)
        ]
    )
    M = mass_matrix()
    T = load_cell_transform(CELL_POS, CELL_ROT, np.zeros(3), 1.0)
    var = matrix_gain_variance(C0, sig**2 * np.eye(24), Tq, psi, M, T)
    mc = np.sum(errs**2, axis=(1, 2)).mean()
    assert np.sum(var) == pytest.approx(mc, rel=0.2)
    # a common scale s moves C by s exactly (T_q Ψ = E)
    var_scale = matrix_gain_variance(C0, sig**2 * np.ones((24, 24)), Tq, psi, M, T)
    np.testing.assert_allclose(var_scale, (sig * C0) ** 2, rtol=1e-8)
    # and the scatter costs far more than its mean would: the amplification of the module
    # docstring (the cell's force is the small difference of the mass's rotational terms)
    rel_scatter = np.sqrt(np.sum(var)) / np.linalg.norm(C0)
    assert rel_scatter > 3 * sig / np.sqrt(24)


def test_jackknife_over_inputs_matches_repeated_benches() -> None:
    """The fit's jackknife variance against the spread of C over repeated noisy benches (the
    same motions, fresh gauge noise each time): the same size, on the safe side (the jackknife
    variance is biased up, Efron–Stein; 1.5–3× with 12 inputs), never below; with fewer
    than 4 inputs there is nothing to leave out."""
    psi = array()
    _, a = rigid_frf(psi, n_lines=6, n_inputs=12)
    S = np.random.default_rng(3).standard_normal((12, 6)) * np.array([1e-3] * 3 + [1e-2] * 3)
    M = mass_matrix()
    T = load_cell_transform(CELL_POS, CELL_ROT, np.zeros(3), 1.0)
    g0 = np.einsum("gb,lbi->lgi", S, np.einsum("ab,lbi->lai", np.linalg.solve(T, M), a))
    rng = np.random.default_rng(8)
    sigma = 0.02 * np.abs(g0).mean()

    def noisy():
        n = rng.standard_normal(g0.shape) + 1j * rng.standard_normal(g0.shape)
        return g0 + sigma * n

    args = (M, CELL_POS, CELL_ROT, np.zeros(3))
    Cs = np.array([inertial_calibration(noisy(), a, *args).matrix for _ in range(60)])
    mc = np.sum(Cs.var(axis=0))
    jk = np.mean([np.sum(jackknife_matrix_variance(noisy(), a, *args)) for _ in range(6)])
    assert mc < jk < 4 * mc
    # the Gram-matrix shortcut is the re-fit with each input left out
    g = noisy()
    Cs = np.array(
        [
            inertial_calibration(np.delete(g, j, 2), np.delete(a, j, 2), *args).matrix
            for j in range(12)
        ]
    )
    naive = 11 / 12 * np.sum((Cs - Cs.mean(axis=0)) ** 2, axis=0)
    np.testing.assert_allclose(jackknife_matrix_variance(g, a, *args), naive, rtol=1e-6)
    assert jackknife_matrix_variance(g0[:, :, :3], a[:, :, :3], *args) is None


def test_a_wrong_geometry_is_not_a_rigid_body() -> None:
    """Triaxes turned as the setup does not say (another scenario seed's array): the measured
    motions are no rigid motion of the stated array, whatever the gains; the residual says so
    (the service refuses above 5 %, MAX_RIGID_RESIDUAL) — the matrix fit's own residual would
    not: C maps any linear combination."""
    from dimacq.services.calibration.inertial_calibration import MAX_RIGID_RESIDUAL

    psi_true = array(seed=0)
    H, _ = rigid_frf(psi_true)
    g = rigid_body_gains(H, array(seed=1), 0.005)
    assert g.residual_rel > 2 * MAX_RIGID_RESIDUAL
    assert rigid_body_gains(H, psi_true, 0.005).residual_rel < 1e-6
