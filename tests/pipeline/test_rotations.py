"""Rotation matrices and the hull test of :mod:`dimacq.pipeline.rotations` against scipy's."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import ConvexHull
from scipy.spatial.transform import Rotation

from dimacq.pipeline.rotations import apply_rotvec, inside_hull, rotvec_to_matrix


@pytest.mark.parametrize("size", [0.0, 1e-6, 5e-4, 1e-3, 2e-3, 0.1, 3.0])
def test_rotation_matrices_are_scipys_bit_for_bit(size: float) -> None:
    rng = np.random.default_rng(int(size * 1e6))
    v = rng.normal(size=(200, 3)) * size  # both sides of the series' 1e-3 switch
    x = rng.normal(size=(200, 3))
    rot = Rotation.from_rotvec(v)
    np.testing.assert_array_equal(rotvec_to_matrix(v), rot.as_matrix())
    np.testing.assert_array_equal(
        rotvec_to_matrix(v.reshape(20, 10, 3)).reshape(200, 3, 3), rot.as_matrix()
    )
    np.testing.assert_array_equal(apply_rotvec(v, x), rot.apply(x))
    np.testing.assert_array_equal(apply_rotvec(v, x[0]), rot.apply(x[0]))
    np.testing.assert_array_equal(apply_rotvec(v[0], x), Rotation.from_rotvec(v[0]).apply(x))


def test_hull_membership_is_qhulls() -> None:
    rng = np.random.default_rng(1)
    box = np.array([[a, b, c] for a in (0, 1) for b in (0, 2) for c in (0, 0.5)], float)
    box = np.vstack([box, [[0.5, 1, 0], [0, 1, 0.25]]])  # points inside facets: coplanar triples
    n_out = 0
    for t in range(200):
        pts = box if t % 2 else rng.normal(size=(rng.integers(4, 30), 3)) * rng.uniform(0.1, 3, 3)
        x = rng.uniform(-0.2, 1.2, 3) * [1, 2, 0.5] if t % 2 else rng.normal(size=3)
        hull = ConvexHull(np.unique(pts, axis=0))
        tol = 1e-9 * float(np.ptp(pts, axis=0).max())
        want = bool(np.all(hull.equations[:, :3] @ x + hull.equations[:, 3] <= tol))
        assert inside_hull(x, pts, tol) is want
        n_out += not want
    assert 20 < n_out < 180  # both answers were tried


def test_flat_or_too_few_points_give_no_answer() -> None:
    square = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0], [0.5, 0.5, 0]], float)
    assert inside_hull(np.zeros(3), square, 1e-9) is None
    assert inside_hull(np.zeros(3), square[:3], 1e-9) is None
