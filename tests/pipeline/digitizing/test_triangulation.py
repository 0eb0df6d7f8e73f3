"""Triangulation: exact on noise-free counts, equal to scipy least squares, echoes rejected,
the must-show accuracy figures on the virtual lab."""

import numpy as np
import pytest
from scipy.optimize import least_squares

from dimacq.errors import DataError, SetupError
from dimacq.pipeline.digitizing.triangulation import (
    DigitizerGeometry,
    Reject,
    combine_shots,
    triangulate,
    trilaterate,
)
from dimacq.simulators.lab.sonic import SonicEnvironment, SonicLab, SonicProbe, default_array

PLANAR = default_array().microphones_m
SOLID = np.vstack([PLANAR, [[0.0, 0.0, 0.4]]])


def exact_counts(geom, emitters, temp_c, n_bar=4):
    """Fractional counts whose decoded times are exact: n = (tau0 + d/c) f - 1/2."""
    c = 331.3 * np.sqrt(1 + temp_c / 273.15)
    d = np.linalg.norm(emitters[:, :, None, :] - geom.microphones_m[None, None], axis=-1)
    counts = (geom.delay_s + d / c) * geom.clock_hz - 0.5
    bar = np.full(
        (len(emitters), n_bar), (geom.delay_s + geom.bar_length_m / c) * geom.clock_hz - 0.5
    )
    return counts, bar


def poses(rng, n, probe):
    tips = rng.uniform([-0.6, -0.6, 0.5], [0.6, 0.6, 1.8], (n, 3))
    u = np.array([0, 0, 1.0]) + rng.uniform(-0.5, 0.5, (n, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    e1 = tips - probe.tip_length_m * u
    return tips, np.stack([e1, e1 - probe.emitter_spacing_m * u], axis=1)


@pytest.mark.parametrize("mics", [PLANAR, SOLID], ids=["planar", "solid"])
@pytest.mark.parametrize("temp", [-5.0, 20.0, 35.0])
def test_exact_on_noise_free_counts(mics, temp):
    geom = DigitizerGeometry(microphones_m=mics)
    tips, em = poses(np.random.default_rng(0), 200, SonicProbe())
    counts, bar = exact_counts(geom, em, temp)
    sol = triangulate(counts, bar, geom)
    assert sol.accepted.all()
    np.testing.assert_allclose(sol.tip_m, tips, atol=1e-9)
    np.testing.assert_allclose(sol.speed_m_s, 331.3 * np.sqrt(1 + temp / 273.15), rtol=1e-12)


def test_planar_side_follows_configuration():
    geom = DigitizerGeometry(microphones_m=PLANAR, facing=np.array([0, 0, -1.0]))
    tips, em = poses(np.random.default_rng(1), 20, SonicProbe())
    tips[:, 2] *= -1
    em[..., 2] *= -1
    counts, bar = exact_counts(geom, em, 20.0)
    np.testing.assert_allclose(triangulate(counts, bar, geom).tip_m, tips, atol=1e-9)


def test_gauss_newton_equals_scipy_least_squares():
    rng = np.random.default_rng(2)
    p_true = rng.uniform([-0.5, -0.5, 0.6], [0.5, 0.5, 1.5], (30, 3))
    d = np.linalg.norm(p_true[:, None] - PLANAR[None], axis=-1) + rng.normal(0, 2e-3, (30, 4))
    p, res = trilaterate(d, PLANAR)
    for k in range(30):
        ref = least_squares(
            lambda x, dk=d[k]: np.linalg.norm(x - PLANAR, axis=1) - dk, p_true[k], xtol=1e-15
        )
        np.testing.assert_allclose(p[k], ref.x, atol=1e-8)
        np.testing.assert_allclose(res[k], ref.fun, atol=1e-8)


def test_echo_on_one_path_rejected():
    geom = DigitizerGeometry(microphones_m=PLANAR)
    _, em = poses(np.random.default_rng(3), 50, SonicProbe())
    counts, bar = exact_counts(geom, em, 20.0)
    counts[:, 1, 2] += 0.06 / 343.2 * 1e7  # 6 cm late on emitter 2, microphone 3
    bar[:10, 1] += 0.1 / 343.2 * 1e7
    sol = triangulate(counts, bar, geom, status=np.r_[np.zeros(49), 1])
    assert not sol.accepted.any()
    assert (sol.reject[10:49] & Reject.RESIDUAL).all()
    assert (sol.reject[:10] & Reject.BAR).all()
    assert sol.reject[49] & Reject.STATUS


def test_combine_shots_drops_outliers():
    tips = (
        np.array([[0, 0, 1.0]] * 4 + [[0, 0, 1.01]])
        + np.array([[1e-4, 0, 0]]) * np.arange(5)[:, None]
    )
    est = combine_shots(tips, [True] * 5, outlier_m=1e-3)
    assert est.n_used == 4 and est.n_accepted == 5
    np.testing.assert_allclose(est.position_m, [1.5e-4, 0, 1.0])
    np.testing.assert_allclose(est.spread_m, [np.std([0, 1e-4, 2e-4, 3e-4], ddof=1), 0, 0])
    with pytest.raises(DataError, match="no accepted shot among 2"):
        combine_shots(tips[:2], [False, False])


def test_bad_inputs():
    geom = DigitizerGeometry(microphones_m=PLANAR)
    with pytest.raises(DataError, match="'counts' shape"):
        triangulate(np.zeros((3, 4)), np.zeros((3, 2)), geom)
    with pytest.raises(DataError, match="has 5 microphones"):
        triangulate(np.zeros((3, 2, 5)), np.zeros((3, 2)), geom)
    with pytest.raises(SetupError, match="'microphones_m' has shape"):
        DigitizerGeometry(microphones_m=np.zeros((2, 3)))


# ---------------------------------------------------------------------------- must show


def lab_shots(lab, rng, tips, axes, per_point):
    counts, bars, echo = [], [], []
    for tip, ax in zip(tips, axes, strict=True):
        lab.place_probe(tip, ax)
        for _ in range(per_point):
            s = lab.shot(rng)
            counts.append(s.counts)
            bars.append(s.bar_counts)
            echo.append(s.echo)
    return np.array(counts), np.array(bars), np.array(echo)


def test_must_show_tip_accuracy_echoes_and_temperature_step():
    """20 degC, ~0.1 mm timing noise, 2 % echo shots, 1000 shots over the volume."""
    rng = np.random.default_rng(11)
    lab = SonicLab(array=default_array())
    lab.environment = SonicEnvironment(temperature_c=20.0, echo_probability=0.02)
    geom = DigitizerGeometry(microphones_m=lab.array.microphones_m)
    tips = rng.uniform([-0.6, -0.6, 0.5], [0.6, 0.6, 1.8], (200, 3))
    axes = np.array([0, 0, 1.0]) + rng.uniform(-0.5, 0.5, (200, 3))
    counts, bars, echo = lab_shots(lab, rng, tips, axes, 5)
    sol = triangulate(counts, bars, geom)
    assert echo.sum() >= 10
    assert not (sol.accepted & echo).any(), "an echo-corrupted shot was accepted"
    assert sol.accepted[~echo].all()
    pts = np.array(
        [
            combine_shots(sol.tip_m[i * 5 : i * 5 + 5], sol.accepted[i * 5 : i * 5 + 5]).position_m
            for i in range(200)
        ]
    )
    rms20 = np.sqrt(np.mean(np.sum((pts - tips) ** 2, axis=1)))
    assert rms20 <= 0.5e-3

    lab.environment.temperature_c = 30.0
    lab.environment.echo_probability = 0.0
    counts30, bars30, _ = lab_shots(lab, rng, tips, axes, 5)
    sol30 = triangulate(counts30, bars30, geom)
    pts30 = np.array([sol30.tip_m[i * 5 : i * 5 + 5].mean(axis=0) for i in range(200)])
    rms30 = np.sqrt(np.mean(np.sum((pts30 - tips) ** 2, axis=1)))
    assert np.sqrt(max(rms30**2 - rms20**2, 0.0)) < 0.2e-3
    # without the bar (speed frozen at 20 degC) the same shots would be centimetres off
    frozen = triangulate(counts30, bars[: len(counts30)], geom)
    assert np.sqrt(np.mean(np.sum((frozen.tip_m - np.repeat(tips, 5, 0)) ** 2, axis=1))) > 10e-3
