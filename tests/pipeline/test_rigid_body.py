"""Rigid-body condensation and force summation against independent kinematics."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from dimacq.errors import SetupError
from dimacq.pipeline.rigid_body import (
    condense,
    filtered_responses,
    force_vectors,
    load_cell_transform,
    response_matrix,
    skew,
)


def test_condensation_recovers_an_exact_rigid_motion() -> None:
    rng = np.random.default_rng(0)
    pos = rng.uniform(-1, 1, (8, 3))
    dirs = np.concatenate(
        [Rotation.random(random_state=i).as_matrix().T for i in range(8)]
    )  # 24 rows
    pos24 = np.repeat(pos, 3, axis=0)
    p = np.array([0.2, -0.1, 0.3])
    u_p, theta = np.array([1.0, -2.0, 0.5]), np.array([0.3, 0.1, -0.2])
    # Independent kinematics: the displacement of each point, then its projection.
    q = np.einsum("ij,ij->i", dirs, u_p + np.cross(theta, pos24 - p))
    c = condense(response_matrix(pos24, dirs, p))
    assert np.allclose(c.transform @ q, np.r_[u_p, theta], atol=1e-13)
    assert c.rank == 6


def test_collinear_response_set_is_refused_with_the_fix() -> None:
    pos = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0]] * 3)
    dirs = np.repeat(np.eye(3), 3, axis=0)
    with pytest.raises(SetupError, match="rank 5 < 6"):
        condense(response_matrix(pos, dirs, np.zeros(3)))


def test_force_and_load_cell_moments_are_cross_products() -> None:
    r = np.array([[0.5, 0.2, -0.1]])
    d = np.array([[0.0, 0.6, 0.8]])
    p = np.array([0.1, 0.1, 0.1])
    phi = force_vectors(r, d, p)[:, 0]
    assert np.allclose(phi[3:], np.cross(r[0] - p, d[0]))
    R = Rotation.from_euler("zyx", [30, 10, -20], degrees=True).as_matrix()
    f_l, m_l = np.array([1.0, 2.0, 3.0]), np.array([0.1, -0.2, 0.3])
    rc = np.array([0.0, 0.0, -0.5])
    T = load_cell_transform(rc, R, p, sign=-1.0)
    out = T @ np.r_[f_l, m_l]
    assert np.allclose(out[:3], -(R @ f_l))
    assert np.allclose(out[3:], -(R @ m_l + np.cross(rc - p, R @ f_l)))
    assert np.allclose(
        skew(np.array([1.0, 2.0, 3.0])) @ np.array([4.0, 5.0, 6.0]), np.cross([1, 2, 3], [4, 5, 6])
    )


def test_filtered_responses_equal_rigid_data_and_flag_a_bad_channel() -> None:
    rng = np.random.default_rng(2)
    pos = np.repeat(rng.uniform(-1, 1, (6, 3)), 3, axis=0)
    dirs = np.tile(np.eye(3), (6, 1))
    psi = response_matrix(pos, dirs, np.zeros(3))
    k = rng.normal(size=(4, 6, 2)) + 1j * rng.normal(size=(4, 6, 2))
    q = np.einsum("ck,lkj->lcj", psi, k)
    assert np.allclose(filtered_responses(psi, q), q)
    bad = q.copy()
    bad[:, 5] *= 1.5
    err = np.abs(bad - filtered_responses(psi, bad)).mean(axis=(0, 2))
    assert int(np.argmax(err)) == 5
    w = np.ones(18)
    w[5] = 0.0
    assert np.allclose(
        filtered_responses(psi, bad, w)[:, np.arange(18) != 5], q[:, np.arange(18) != 5]
    )
