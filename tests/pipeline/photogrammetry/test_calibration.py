"""Board-calibration numerics against closed forms and a second method: the corners' cover, the
board's tilt, the image difference of two cameras, the intrinsics' covariance (Schur complement
against the full normal matrix), and the refusals."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from dimacq.pipeline.photogrammetry.calibration import (
    LIMIT_EDGE_STD_PX,
    LIMIT_F_REL_STD,
    MIN_PHOTOS,
    Coverage,
    board_tilt_deg,
    coverage,
    edge_std_px,
    image_difference_px,
    intrinsic_covariance,
    more_photos,
    refusals,
)
from dimacq.pipeline.photogrammetry.camera import Intrinsics


def test_coverage_cells_and_reach() -> None:
    # one point in the top-left cell and one at the image's bottom-right corner
    c = coverage([np.array([[10.0, 10.0]]), np.array([[1599.0, 1199.0]])], 1600, 1200)
    assert c.cells == pytest.approx(2 / 16)
    assert "top right" in c.empty and len(c.empty) == 14
    assert "top left" not in c.empty and "bottom right" not in c.empty
    assert c.reach == pytest.approx(np.hypot(799, 599) / 1000.0)
    full = np.stack(np.meshgrid(np.linspace(0, 1599, 9), np.linspace(0, 1199, 9)), -1)
    assert coverage([full.reshape(-1, 2)], 1600, 1200).cells == 1.0


def test_tilt_is_the_angle_between_normal_and_axis() -> None:
    assert board_tilt_deg([0.0, 0.0, 1.3]) == pytest.approx(0.0, abs=1e-9)  # roll only
    rv = Rotation.from_euler("zx", [40.0, 33.0], degrees=True).as_rotvec()
    assert board_tilt_deg(rv) == pytest.approx(33.0)
    assert board_tilt_deg([np.pi, 0.0, 0.0]) == pytest.approx(0.0, abs=1e-6)  # the back face


def test_image_difference() -> None:
    a = Intrinsics(1450.0, 1450.0, 800.0, 600.0, k1=-0.1, k2=0.05, width=1600, height=1200)
    assert image_difference_px(a, a) < 1e-6
    # a shifted principal point moves every pixel by the shift
    b = Intrinsics(1450.0, 1450.0, 802.0, 600.0, k1=-0.1, k2=0.05, width=1600, height=1200)
    assert image_difference_px(a, b) == pytest.approx(2.0, rel=1e-6)
    # a 1 % focal length without distortion: largest at the corner farthest from (cx, cy)
    c0 = Intrinsics(1000.0, 1000.0, 800.0, 600.0, width=1600, height=1200)
    c1 = Intrinsics(1010.0, 1010.0, 800.0, 600.0, width=1600, height=1200)
    assert image_difference_px(c0, c1) == pytest.approx(0.01 * np.hypot(800, 600), rel=1e-6)


def test_edge_std_closed_forms() -> None:
    cam = Intrinsics(1000.0, 1000.0, 700.0, 600.0, width=1600, height=1200)
    # the principal point alone: every pixel moves with it
    cov = np.zeros((9, 9))
    cov[2, 2] = 0.3**2
    assert edge_std_px(cam, cov) == pytest.approx(0.3, rel=1e-6)
    # fx alone, no distortion: u = fx x + cx moves by σ_fx |x|, largest at the far edge
    cov = np.zeros((9, 9))
    cov[0, 0] = 2.0**2
    assert edge_std_px(cam, cov) == pytest.approx(2.0 * (1599 - 700) / 1000, rel=1e-6)
    # k1 alone: (u, v) = (cx, cy) + f (x, y)(1 + k1 r²) moves by f r³ σ_k1, largest at the
    # corner farthest from the principal point, the top right (1599, 0)
    cov = np.zeros((9, 9))
    cov[4, 4] = 0.01**2
    x, y = (1599 - 700) / 1000, (0 - 600) / 1000
    want = 1000 * np.hypot(x, y) * (x * x + y * y) * 0.01
    assert edge_std_px(cam, cov) == pytest.approx(want, rel=1e-6)


def test_schur_covariance_matches_the_full_normal_matrix() -> None:
    rng = np.random.default_rng(1)
    p, n = 9, 5
    a_blocks = [rng.normal(size=(40, p)) for _ in range(n)]
    b_blocks = [rng.normal(size=(40, 6)) for _ in range(n)]
    r = rng.normal(scale=0.3, size=40 * n)
    got = intrinsic_covariance(a_blocks, b_blocks, r)
    # the whole Jacobian [A | blockdiag(B)], its normal matrix inverted, the intrinsics' block
    j = np.zeros((40 * n, p + 6 * n))
    for i in range(n):
        j[40 * i : 40 * (i + 1), :p] = a_blocks[i]
        j[40 * i : 40 * (i + 1), p + 6 * i : p + 6 * (i + 1)] = b_blocks[i]
    s2 = float(r @ r) / (40 * n - p - 6 * n)
    want = s2 * np.linalg.inv(j.T @ j)[:p, :p]
    np.testing.assert_allclose(got, want, rtol=1e-8, atol=1e-14)


def test_refusals_name_the_fix() -> None:
    good = Coverage(1.0, (), 0.9)
    assert refusals(15, 0.001, 0.2, good, [30.0] * 15) == []
    few = refusals(4, None, None, good, [])
    assert len(few) == 1 and f"fewer than {MIN_PHOTOS}" in few[0] and "take 11 more" in few[0]
    flat = refusals(15, 0.02, 0.1, good, [2.0] * 15)
    assert len(flat) == 1 and "0 of 15 photos" in flat[0] and "tilting the board 20–45°" in flat[0]
    # square-on photos refused however small the focal length's σ (a sharp, fine sensor)
    sharp = refusals(15, 0.2 * LIMIT_F_REL_STD, 0.1, good, [2.0] * 13 + [20.0, 30.0])
    assert len(sharp) == 1 and "2 of 15 photos" in sharp[0] and "at least 3 needed" in sharp[0]
    assert "take 8 more photos" in sharp[0]
    assert refusals(15, 0.2 * LIMIT_F_REL_STD, 0.1, good, [2.0] * 12 + [15.0] * 3) == []
    # most photos tilted: σ ∝ 1/√n asks for n (σ/limit)² − n more
    tilted = refusals(10, 2 * LIMIT_F_REL_STD, 0.1, good, [30.0] * 10)
    assert f"take {more_photos(10, 2.0)} more" in tilted[0] and more_photos(10, 2.0) == 30
    corner = refusals(15, 0.001, 0.1, Coverage(0.5, ("top left", "top right"), 0.6), [30.0] * 15)
    assert "nothing in: top left, top right" in corner[0] and "near each corner" in corner[0]
    # the cells covered but the image's corners placed loosely: refused on that alone
    loose = refusals(15, 0.001, 0.1, good, [30.0] * 15, 1.5 * LIMIT_EDGE_STD_PX)
    assert len(loose) == 1 and "image's corners to ±1.50 px (1σ; limit 1.0 px)" in loose[0]
    assert refusals(15, 0.001, 0.1, good, [30.0] * 15, 0.5 * LIMIT_EDGE_STD_PX) == []
    rms = refusals(15, 0.001, 1.7, good, [30.0] * 15)
    assert "reprojection RMS 1.70 px" in rms[0] and "board file" in rms[0]
