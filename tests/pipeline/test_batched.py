"""The batched products of ``dimacq.pipeline._batched`` against numpy's own functions."""

from __future__ import annotations

import numpy as np
import pytest

from dimacq.pipeline._batched import cross3, real_apply


@pytest.mark.parametrize(
    ("shape_a", "shape_b"),
    [((3,), (3,)), ((5, 3), (5, 3)), ((4, 1, 3), (1, 6, 3)), ((3, 3), (7, 1, 3)), ((3,), (8, 3))],
)
def test_cross3_is_numpy_cross_to_the_bit(
    shape_a: tuple[int, ...], shape_b: tuple[int, ...]
) -> None:
    rng = np.random.default_rng(3)
    a, b = rng.standard_normal(shape_a), rng.standard_normal(shape_b)
    assert np.array_equal(cross3(a, b), np.cross(a, b))
    # the right-hand rule on the basis vectors (an answer not taken from numpy)
    e = np.eye(3)
    np.testing.assert_array_equal(cross3(e[0], e[1]), e[2])
    np.testing.assert_array_equal(cross3(e[2], e[1]), -e[0])


def test_real_apply_is_the_einsum() -> None:
    rng = np.random.default_rng(4)
    B = rng.standard_normal((6, 5))
    F = rng.standard_normal((7, 5, 4)) + 1j * rng.standard_normal((7, 5, 4))
    np.testing.assert_allclose(real_apply(B, F), np.einsum("ck,lkj->lcj", B, F), rtol=1e-13)
