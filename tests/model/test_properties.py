"""Rigid-body properties against a body of point masses (an independent closed form)."""

from __future__ import annotations

import numpy as np

from dimacq.model.properties import RigidBodyProperties, principal_moments


def _point_masses(seed: int = 3) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    return rng.uniform(0.5, 2.0, 12), rng.uniform(-0.4, 0.6, (12, 3))


def _tensor_about(m: np.ndarray, r: np.ndarray, p: np.ndarray) -> np.ndarray:
    d = r - p
    return sum(mi * (di @ di * np.eye(3) - np.outer(di, di)) for mi, di in zip(m, d, strict=True))


def test_parallel_axis_matches_point_masses() -> None:
    m, r = _point_masses()
    cg = (m[:, None] * r).sum(0) / m.sum()
    props = RigidBodyProperties(float(m.sum()), cg, _tensor_about(m, r, cg))
    p = np.array([0.3, -0.2, 1.0])
    assert np.allclose(props.inertia_about(p), _tensor_about(m, r, p), rtol=1e-13, atol=1e-14)
    back = RigidBodyProperties.from_about_point(props.mass_kg, cg, _tensor_about(m, r, p), p)
    assert np.allclose(back.inertia_cg_kgm2, props.inertia_cg_kgm2, atol=1e-14)


def test_mass_matrix_gives_momentum_of_point_masses() -> None:
    # Kinetic energy ½ vᵀ M v of a rigid motion [u̇_P; ω] equals Σ ½ m_i |u̇_P + ω × (r_i − P)|².
    m, r = _point_masses(7)
    cg = (m[:, None] * r).sum(0) / m.sum()
    props = RigidBodyProperties(float(m.sum()), cg, _tensor_about(m, r, cg))
    p = np.array([0.1, 0.0, -0.3])
    v = np.array([0.3, -1.0, 0.2, 0.7, -0.4, 1.1])
    vel = v[:3] + np.cross(v[3:], r - p)
    assert np.isclose(
        0.5 * v @ props.mass_matrix(p) @ v, 0.5 * np.sum(m * np.sum(vel**2, axis=1)), rtol=1e-13
    )


def test_principal_axes_are_right_handed_and_diagonalise() -> None:
    m, r = _point_masses(11)
    t = _tensor_about(m, r, (m[:, None] * r).sum(0) / m.sum())
    w, v = principal_moments(t)
    assert np.isclose(np.linalg.det(v), 1.0)
    assert np.allclose(v.T @ t @ v, np.diag(w), atol=1e-13)
    assert np.all(np.diff(w) >= 0)


def test_json_round_trip() -> None:
    m, r = _point_masses(5)
    cg = (m[:, None] * r).sum(0) / m.sum()
    props = RigidBodyProperties(float(m.sum()), cg, _tensor_about(m, r, cg))
    back = RigidBodyProperties.from_json(props.to_json(np.array([1.0, 2.0, 3.0])))
    assert np.isclose(back.mass_kg, props.mass_kg)
    assert np.allclose(back.inertia_cg_kgm2, props.inertia_cg_kgm2, atol=1e-14)
