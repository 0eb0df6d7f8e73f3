"""The mass-line estimate against closed forms: the forward model's exact FRFs, the rigid-body mass
matrix, and its own noise propagation against a Monte Carlo over noise draws."""

from __future__ import annotations

import numpy as np
import pytest

from dimacq.errors import SolverError
from dimacq.model.properties import (
    RigidBodyProperties,
    inertia_to_vector,
    principal_moments,
)
from dimacq.pipeline.cross_check import (
    QUANTITIES,
    mass_line_fit,
    mass_line_from_frf,
    quantities_from_parameters,
    read_mass_matrix,
)
from dimacq.simulators.lab.forward import ForwardModel, calibration_mass, cube, x38_like


def _truth(fm: ForwardModel, p: np.ndarray) -> np.ndarray:
    t = fm.properties
    c = t.cg_m
    return np.concatenate(
        [
            [t.mass_kg],
            c,
            inertia_to_vector(t.inertia_about(p)),
            inertia_to_vector(t.inertia_cg_kgm2),
            principal_moments(t.inertia_cg_kgm2)[0],
        ]
    )


CASES = {
    "calibration-mass-bungee": (lambda: calibration_mass(0), np.linspace(20.0, 100.0, 41)),
    "calibration-mass-free": (lambda: calibration_mass(1, support="free"), np.linspace(20, 60, 21)),
    "x38-like": (lambda: x38_like(0), np.linspace(8.0, 20.0, 13)),
    "cube-2": (lambda: cube(1.0), np.linspace(20.0, 60.0, 21)),
}


@pytest.mark.parametrize("name", list(CASES))
def test_noise_free_forward_model_gives_the_truth(name: str) -> None:
    make, freqs = CASES[name]
    fm = make()
    fit = mass_line_from_frf(fm.frf(freqs), fm.setup, geometry=False)
    truth = _truth(fm, np.asarray(fm.setup.reference_point_m, float))
    scale = np.abs(truth).copy()
    scale[1:4] = float(np.ptp(fm.setup.response_positions, axis=0).max())  # CG against the size
    scale[4:] = np.max(truth[16:19])  # inertia against the largest principal moment
    err = np.abs(fit.values - truth) / scale
    assert err.max() < 1e-9, dict(zip(QUANTITIES, err.tolist(), strict=True))
    assert fit.structure_rel < 1e-9
    assert fit.residual_rel < 1e-9


def test_reading_a_rigid_mass_matrix_is_exact_and_structure_free() -> None:
    props = RigidBodyProperties(
        7.5,
        np.array([0.11, -0.04, 0.23]),
        np.array([[0.9, -0.02, 0.05], [-0.02, 1.3, 0.01], [0.05, 0.01, 0.7]]),
    )
    p = np.array([0.3, 0.2, -0.1])
    q, structure = read_mass_matrix(props.mass_matrix(p))
    assert q[0] == pytest.approx(7.5, rel=1e-14)
    assert np.allclose(q[1:4] + p, props.cg_m, atol=1e-14)
    assert np.allclose(q[4:10], inertia_to_vector(props.inertia_about(p)), atol=1e-13)
    assert np.allclose(q[10:16], inertia_to_vector(props.inertia_cg_kgm2), atol=1e-13)
    assert np.allclose(structure, 0.0, atol=1e-13)
    # the same numbers from the DIM's parameter vector
    x = props.parameter_vector(p)
    x[1:4] = props.cg_m
    qq = quantities_from_parameters(x, p)
    assert np.allclose(qq[4:], np.concatenate([q[4:10], q[10:16], q[16:19]]), atol=1e-13)
    # a non-rigid part shows: anisotropic translational mass
    M = props.mass_matrix(p)
    M[0, 0] *= 1.01
    _, structure = read_mass_matrix(M)
    assert abs(structure[0]) > 0.05


def test_noise_propagation_matches_a_monte_carlo_over_noise_draws() -> None:
    fm = calibration_mass(0, support="free")
    frf = fm.frf(np.linspace(20.0, 100.0, 41))
    rng = np.random.default_rng(5)
    rms = np.sqrt(np.mean(np.abs(frf.H) ** 2, axis=0, keepdims=True))
    vals, ses = [], []
    for _ in range(40):
        e = rng.standard_normal(frf.H.shape) + 1j * rng.standard_normal(frf.H.shape)
        fit = mass_line_from_frf(
            frf.replace(H=frf.H + 0.02 * rms * e / np.sqrt(2)), fm.setup, geometry=False
        )
        vals.append(fit.values)
        ses.append(np.maximum(fit.se_noise, fit.se_inputs))
    spread = np.std(vals, axis=0, ddof=1)
    se = np.median(ses, axis=0)
    idx = [QUANTITIES.index(k) for k in ("m", "cx", "cy", "cz", "I1", "I2", "I3")]
    ratio = se[idx] / spread[idx]
    # 40 draws: the spread itself is known to ±25 % (2σ); the stated error must not be smaller
    assert np.all(ratio > 0.7), ratio
    assert np.all(ratio < 2.0), ratio
    truth = _truth(fm, np.asarray(fm.setup.reference_point_m, float))
    bias = np.abs(np.mean(vals, axis=0) - truth)[idx] / (spread[idx] / np.sqrt(40))
    assert np.all(bias < 4.0), bias


def test_geometry_spread_and_its_difference_from_the_dim() -> None:
    fm = calibration_mass(0)
    frf = fm.frf(np.linspace(20.0, 100.0, 41))
    fit = mass_line_from_frf(frf, fm.setup, dim_companion=True, n_samples=100)
    assert fit.geometry_samples == 100
    assert fit.se_geometry_difference is not None
    m = QUANTITIES.index("m")
    # the hammer sensitivity (0.5 %) scales both estimators alike: in the spread, not the difference
    assert fit.se_geometry[m] / fit.values[m] > 0.004
    assert fit.se_geometry_difference[m] < fit.se_geometry[m]


def test_cube_with_six_inputs_has_no_jackknife_but_a_solution() -> None:
    fm = cube(1.0)
    fit = mass_line_from_frf(fm.frf(np.linspace(20.0, 60.0, 5)), fm.setup, geometry=False)
    assert fit.values[0] == pytest.approx(fm.properties.mass_kg, rel=1e-9)
    assert fit.jackknife.shape[0] == 0  # every leave-one-out loses a DOF


def test_too_few_channels_is_refused() -> None:
    fm = calibration_mass(0, support="free")
    frf = fm.frf(np.linspace(20.0, 60.0, 5))
    acc = frf.output_index("acceleration")
    w = np.zeros(acc.size)
    w[:5] = 1.0
    with pytest.raises(SolverError, match="at least 6"):
        mass_line_from_frf(frf, fm.setup, response_weights=w, geometry=False)
    with pytest.raises(SolverError, match=r"singular|positive"):
        H = frf.H[:, acc]
        mass_line_fit(
            H,
            None,
            np.zeros((acc.size, 3)),
            np.tile([1.0, 0.0, 0.0], (acc.size, 1)),
            np.zeros((len(frf.inputs), 3)),
            np.tile([1.0, 0.0, 0.0], (len(frf.inputs), 1)),
            np.zeros(3),
        )
