"""The simulated lab's truth: model FRFs and the support-side bench.

Independent answers: the forward model's own frequency-domain solve (ForwardModel.frf) for the
state-space FRFs; Newton–Euler on the calibration mass for the bench gauges; the true article's
properties for DIM through the simulated devices (the devices themselves:
``tests/cli/test_acquire_cli.py``, ``tests/services/test_inertial_calibration.py``).
"""

from __future__ import annotations

import numpy as np
import pytest
from _acq_support import no_leaks

from dimacq.cli.simulated_lab import model_frf, scenario_model
from dimacq.errors import SetupError
from dimacq.pipeline.rigid_body import load_cell_transform
from dimacq.simulators.lab.forward import calibration_mass
from dimacq.simulators.lab.timedomain import Hammer, LabNoise, VirtualLab
from dimacq.simulators.loadcell.bench import SupportSideBench

__all__ = ["no_leaks"]


@pytest.mark.parametrize("name", ["calibration-mass", "calibration-mass-ground", "x38-flexible"])
def test_model_frf_equals_forward_model(name):
    m = scenario_model(name, 3)
    f = np.linspace(0.5, 900.0, 57)
    np.testing.assert_allclose(model_frf(m, f), m.frf(f).H, rtol=1e-8, atol=1e-12)


@pytest.mark.parametrize("name", ["calibration-mass", "x38-flexible"])
def test_model_frf_with_exponential_window_is_laplace_shift(name):
    """``model_frf(..., τ)`` is ``H(iω + 1/τ)``: checked against the second-order form
    ``(K + sC + s²M)⁻¹`` of :meth:`ForwardModel.transfer` at ``s = i2πf + 1/τ`` (the state-space
    form ``model_frf`` uses is independent of it), over the suspension modes, where the shift
    changes the FRF by orders of magnitude, and above them."""
    m = scenario_model(name, 1)
    tau = 0.05
    fn = m.natural_frequencies_hz()
    f = np.unique(np.concatenate([fn[fn > 0.1], [0.7, 3.0, 37.0, 300.0]]))
    s = 2j * np.pi * f + 1.0 / tau
    h0, h1 = model_frf(m, f), model_frf(m, f, exponential_tau_s=tau)
    ref = m.transfer(s)
    np.testing.assert_allclose(h1, ref, rtol=1e-8, atol=1e-10 * np.abs(ref).max())
    # and not the unshifted FRF: at the resonances the window damps the peaks by far
    at_res = np.isin(f, fn)
    assert np.median(np.abs(h0[at_res]) / np.maximum(np.abs(h1[at_res]), 1e-300)) > 3
    # a free body's accelerance is the same at every s (mass line): the shift leaves it
    free = calibration_mass(1, support="free")
    np.testing.assert_allclose(
        model_frf(free, f, exponential_tau_s=tau), model_frf(free, f), rtol=1e-9, atol=1e-12
    )


def test_unknown_scenario_is_refused():
    with pytest.raises(SetupError, match="scenario 'nope' is unknown"):
        scenario_model("nope")


def test_bench_gauges_carry_every_force_on_the_mass():
    """Newton–Euler: the bench's gauges read S (sT_c)⁻¹ M_rb a_O at every sample."""
    model = calibration_mass(2, support="bungee")
    lab = VirtualLab(model, hammer=Hammer(peak_n=100.0), noise=LabNoise(), seed=2)
    bench = SupportSideBench(lab, 501)
    bench.excite(5, 100)
    bench.excite(17, 700)
    n_acc = len(model.setup.responses)
    g_ch = np.array([lab.channel_index(f"LC501 g{k + 1:02d}") for k in range(12)])
    y = bench.read(np.concatenate([np.arange(n_acc), g_ch]), 0, 1400)
    # rigid-body acceleration of O from the 24 accelerometer axes (least squares)
    setup = model.setup
    pos, d = setup.response_positions, setup.response_directions
    psi = np.concatenate([d, np.cross(pos, d)], axis=1)
    a_o = np.linalg.lstsq(psi, y[:n_acc], rcond=None)[0]
    (s,) = model.supports
    T = load_cell_transform(s.position_m, s.rotation, np.zeros(3), 1.0)
    expect = lab.gauge_matrix(501) @ np.linalg.solve(
        T, model.properties.mass_matrix(np.zeros(3)) @ a_o
    )
    np.testing.assert_allclose(y[n_acc:], expect, atol=1e-9 * np.abs(expect).max() + 1e-12)
    assert np.abs(y[n_acc:]).max() > 1e-2  # the hammer load is really there
    # without the bench the gauges see only the bungee: far smaller
    lab2 = VirtualLab(model, hammer=Hammer(peak_n=100.0), noise=LabNoise(), seed=2)
    lab2.excite(5, 100)
    lab2.excite(17, 700)
    assert np.abs(lab2.read(g_ch, 0, 1400)).max() < 0.05 * np.abs(y[n_acc:]).max()


def test_bench_refuses_hammer_noise():
    lab = VirtualLab(calibration_mass(0), noise=LabNoise(force_noise_n=0.1))
    with pytest.raises(ValueError, match="force_noise_n=0"):
        SupportSideBench(lab, 501)
