"""Line of action: Eq. 13 and the SVD principal direction, signed from the input node."""

import numpy as np
import pytest

from dimacq.errors import DataError, SetupError
from dimacq.pipeline.digitizing.lines_of_action import (
    angle_between_deg,
    line_of_action_svd,
    line_of_action_thesis,
)

D = np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])
BASE = np.array([0.1, 0.2, 1.0])
# rod points from 30 mm above the base outwards; the force acts along -outward (into the structure)
PTS = BASE - np.outer(0.03 + 0.0254 * np.arange(8), D)


@pytest.mark.parametrize("fn", [line_of_action_thesis, line_of_action_svd])
def test_exact_and_signed_towards_input_node(fn):
    loa = fn(PTS, BASE)
    np.testing.assert_allclose(loa.direction, D, atol=1e-12)
    assert loa.perpendicular_rms_m < 1e-12
    np.testing.assert_allclose(fn(PTS, PTS[-1] - 0.01 * D).direction, -D, atol=1e-12)


def test_svd_must_show_and_beats_eq13_on_a_small_component():
    rng = np.random.default_rng(5)
    d = np.array([0.02, 0.6, 0.8])
    d /= np.linalg.norm(d)
    pts = BASE - np.outer(0.03 + 0.0254 * np.arange(8), d)
    e_svd, e_13, pred = [], [], []
    for _ in range(400):
        noisy = pts + rng.normal(0, 0.15e-3 / np.sqrt(3), pts.shape)
        s = line_of_action_svd(noisy, BASE)
        e_svd.append(angle_between_deg(s.direction, d))
        pred.append(s.angle_std_deg)
        e_13.append(angle_between_deg(line_of_action_thesis(noisy, BASE).direction, d))
    rms_svd = np.sqrt(np.mean(np.square(e_svd)))
    assert rms_svd <= 0.2
    assert rms_svd < np.sqrt(np.mean(np.square(e_13)))
    assert 0.6 < rms_svd / np.sqrt(np.mean(np.square(pred))) < 1.4


def test_refusals():
    with pytest.raises(SetupError, match="n >= 2"):
        line_of_action_svd(PTS[:1], BASE)
    with pytest.raises(DataError, match="coincide"):
        line_of_action_thesis(np.zeros((4, 3)), BASE)
    with pytest.raises(SetupError, match="undefined"):
        line_of_action_svd(PTS, PTS.mean(axis=0))
    assert angle_between_deg([1, 0, 0], [0, 1, 0]) == pytest.approx(90.0)
