"""Rotation matrices of :mod:`dimacq.pipeline.rotations` against Rodrigues' formula, and the CG
hull test of :mod:`dimacq.pipeline.dim.checks` against a box whose inside is known."""

from __future__ import annotations

import numpy as np
import pytest

from dimacq.pipeline.dim.checks import inside_hull
from dimacq.pipeline.rigid_body import skew
from dimacq.pipeline.rotations import apply_rotvec, rotvec_to_matrix


def _rodrigues(v: np.ndarray) -> np.ndarray:
    """``I + sin θ [u]× + (1 − cos θ) [u]×²`` for one rotation vector ``v = θ u``."""
    theta = float(np.linalg.norm(v))
    if theta == 0.0:
        return np.eye(3)
    k = skew(v / theta)
    return np.eye(3) + np.sin(theta) * k + (1.0 - np.cos(theta)) * (k @ k)


@pytest.mark.parametrize("size", [0.0, 1e-6, 5e-4, 2e-3, 0.1, 3.0])
def test_rotation_matrices_are_rodrigues(size: float) -> None:
    rng = np.random.default_rng(int(size * 1e6))
    v = rng.normal(size=(20, 3)) * size
    x = rng.normal(size=(20, 3))
    want = np.stack([_rodrigues(r) for r in v])
    np.testing.assert_allclose(rotvec_to_matrix(v), want, rtol=0, atol=1e-14)
    np.testing.assert_allclose(
        rotvec_to_matrix(v.reshape(4, 5, 3)).reshape(20, 3, 3), want, rtol=0, atol=1e-14
    )
    np.testing.assert_allclose(apply_rotvec(v, x), np.einsum("nij,nj->ni", want, x), atol=1e-14)
    np.testing.assert_allclose(apply_rotvec(v[0], x), x @ want[0].T, atol=1e-14)


def test_hull_membership_of_a_box() -> None:
    rng = np.random.default_rng(1)
    lengths = np.array([1.0, 2.0, 0.5])
    box = np.array([[a, b, c] for a in (0, 1) for b in (0, 2) for c in (0, 0.5)], float)
    box = np.vstack([box, [[0.5, 1, 0], [0, 1, 0.25]]])  # points inside facets: coplanar triples
    n_out = 0
    for _ in range(200):
        x = rng.uniform(-0.2, 1.2, 3) * lengths
        want = bool(np.all((x >= 0) & (x <= lengths)))
        assert inside_hull(x, box, 1e-9 * 2.0) is want
        n_out += not want
    assert 20 < n_out < 180  # both answers were tried


def test_flat_or_too_few_points_give_no_answer() -> None:
    square = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0], [0.5, 0.5, 0]], float)
    assert inside_hull(np.zeros(3), square, 1e-9) is None
    assert inside_hull(np.zeros(3), square[:3], 1e-9) is None
