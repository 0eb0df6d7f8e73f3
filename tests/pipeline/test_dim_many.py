"""Many joint solves from the inputs' band sums against one ``solve_joint`` per weighting."""

from __future__ import annotations

import numpy as np
import pytest

from dimacq.pipeline import dim
from dimacq.pipeline.dim import input_band_sums, solve_joint_many
from dimacq.simulators.lab.forward import calibration_mass, x38_like

BAND = (20.0, 100.0)


def _noisy_system(fm, seed: int) -> dim.DimSystem:  # type: ignore[no-untyped-def]
    rng = np.random.default_rng(seed)
    frf = fm.frf(BAND)
    frf = frf.replace(H=frf.H * (1 + 0.01 * rng.standard_normal(frf.H.shape)))
    return dim.assemble(frf, fm.setup)


@pytest.mark.parametrize(
    "known", [{}, {"m": 18.0}, {"m": 18.0, "cx": 0.03}, {"cz": -0.08, "Ixy": 0.0}]
)
def test_leave_one_out_and_resampled_weights_match_solve_joint(known: dict[str, float]) -> None:
    system = _noisy_system(calibration_mass(0), 5)
    n_in = system.K.shape[2]
    rng = np.random.default_rng(1)
    W = np.vstack(
        [
            1.0 - np.eye(n_in),  # the jackknife
            np.bincount(rng.integers(0, n_in, n_in), minlength=n_in)[None],  # a bootstrap
            rng.uniform(0.2, 2.0, (2, n_in)),
        ]
    )
    got, solved = solve_joint_many(system, W, known=known)
    assert solved.all()
    want = np.array([dim.solve_joint(system, known=known, input_weights=w) for w in W])
    # the same sums in another order: rounding, far below the jackknife spread (~1e-3)
    np.testing.assert_allclose(got, want, rtol=1e-11, atol=1e-14)
    assert np.ptp(got[:n_in, -1]) > 1e-6 * abs(got[0, -1])  # the weightings differ


def test_load_cell_reactions_enter_the_band_sums() -> None:
    """X-38 on load cells: F carries the reactions; its leave-one-outs as solve_joint's."""
    system = _noisy_system(x38_like(0), 3)
    n_in = system.K.shape[2]
    got, solved = solve_joint_many(system, 1.0 - np.eye(n_in)[:4].reshape(4, n_in))
    assert solved.all()
    want = [dim.solve_joint(system, input_weights=w) for w in 1.0 - np.eye(n_in)[:4]]
    np.testing.assert_allclose(got, want, rtol=1e-10, atol=1e-12)
    G, C = input_band_sums(system)
    # an independent look: G_j, C_j are input j's Gram matrices summed over lines
    k0, f0 = system.K[:, :, 0], system.F[:, :, 0]
    np.testing.assert_allclose(G[0].reshape(6, 6), np.real(k0.conj().T @ k0), rtol=1e-13)
    np.testing.assert_allclose(
        C[0].reshape(6, 6), np.real(k0.conj().T @ f0), rtol=1e-12, atol=1e-15
    )


def test_a_rank_deficient_weighting_is_a_nan_row_not_an_error() -> None:
    system = _noisy_system(calibration_mass(0), 2)
    n_in = system.K.shape[2]
    W = np.vstack([np.ones(n_in), np.zeros(n_in)])
    got, solved = solve_joint_many(system, W)
    assert solved.tolist() == [True, False]
    assert np.isfinite(got[0]).all() and np.isnan(got[1]).all()
    np.testing.assert_allclose(got[0], dim.solve_joint(system), rtol=1e-11)
