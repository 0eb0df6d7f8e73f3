"""Registration of the array in the GCS: exact recovery, per-node residuals, refusals."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from dimacq.errors import SetupError
from dimacq.pipeline.digitizing.registration import planarity, register, three_point_frame

RNG = np.random.default_rng(4)
NODES = RNG.uniform(-1, 1, (7, 3))
ROT = Rotation.from_euler("xyz", [10, -25, 70], degrees=True)
OFF = np.array([1.0, -2.0, 0.5])


@pytest.mark.parametrize("method", ["rigid", "similarity", "affine"])
def test_exact_rigid_map(method):
    xg = ROT.apply(NODES) + OFF
    reg = register(NODES, xg, method=method)
    np.testing.assert_allclose(reg.matrix, ROT.as_matrix(), atol=1e-12)
    np.testing.assert_allclose(reg.offset_m, OFF, atol=1e-12)
    assert reg.rms_m < 1e-12 and reg.scale == pytest.approx(1.0)
    np.testing.assert_allclose(reg.inverse(reg.apply(NODES)), NODES, atol=1e-12)


def test_similarity_recovers_scale_and_affine_a_shear():
    reg = register(NODES, 1.01 * ROT.apply(NODES) + OFF, method="similarity")
    assert reg.scale == pytest.approx(1.01, abs=1e-12)
    shear = np.array([[1, 0.1, 0], [0, 1, 0], [0, 0.05, 0.98]])
    reg = register(NODES, NODES @ shear.T + OFF, method="affine")
    np.testing.assert_allclose(reg.matrix, shear, atol=1e-12)


def test_residual_points_at_the_bad_node():
    xg = ROT.apply(NODES) + OFF
    xg[3] += [0.0, 0.004, 0.0]
    reg = register(NODES, xg)
    assert np.argmax(reg.residual_norm_m) == 3
    assert reg.residuals_m.shape == (7, 3)
    # rigid least squares: the residuals of a rigid fit are orthogonal to translation
    np.testing.assert_allclose(reg.residuals_m.sum(axis=0), 0, atol=1e-12)


def test_refusals():
    with pytest.raises(SetupError, match="3 reference nodes; give at least 4"):
        register(NODES[:3], NODES[:3])
    flat = NODES.copy()
    flat[:, 2] = 0.3
    assert planarity(flat) < 1e-12
    with pytest.raises(SetupError, match="coplanar"):
        register(flat, flat)
    with pytest.raises(SetupError, match="same nodes"):
        register(NODES, NODES[:5])
    with pytest.raises(SetupError, match="method 'kabsch'"):
        register(NODES, NODES, method="kabsch")


def test_three_point_frame():
    # known frame: GCS axes rotated by ROT and shifted, in the DACS
    r = ROT.as_matrix()
    p0 = np.array([0.2, 0.3, 1.0])
    px = p0 + 0.7 * r[:, 0]
    pxz = p0 + 0.4 * r[:, 0] + 0.5 * r[:, 2]
    reg = three_point_frame(p0, px, pxz)
    np.testing.assert_allclose(reg.apply(p0), 0, atol=1e-12)
    np.testing.assert_allclose(reg.apply(px), [0.7, 0, 0], atol=1e-12)
    np.testing.assert_allclose(reg.apply(pxz), [0.4, 0, 0.5], atol=1e-12)
    assert np.linalg.det(reg.matrix) == pytest.approx(1.0)
    with pytest.raises(SetupError, match="collinear"):
        three_point_frame(p0, px, p0 + 2 * (px - p0))
