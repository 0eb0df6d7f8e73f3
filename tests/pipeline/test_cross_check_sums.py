"""The mass-line fit's summed normal equations (its geometry Monte Carlo) against the per-input
ones summed, formed the other way (Kronecker blocks per input, then the sum)."""

from __future__ import annotations

import numpy as np

from dimacq.pipeline import cross_check as cc


def test_summed_normal_equations_are_the_sum_of_the_per_input_ones() -> None:
    rng = np.random.default_rng(0)
    L, n, J, S = 40, 18, 12, 7
    H = rng.normal(size=(L, n, J)) + 1j * rng.normal(size=(L, n, J))
    R = rng.normal(size=(L, 6, J)) + 1j * rng.normal(size=(L, 6, J))
    sums = cc.data_band_sums(H, R)
    psi, phi = rng.normal(size=(S, n, 6)), rng.normal(size=(S, J, 6))
    w = rng.uniform(size=(J, n))
    N, b = cc.normal_equations(sums, psi, phi, w)
    Ns, bs = cc.normal_equations(sums, psi, phi, w, summed=True)
    assert N.shape == (S, J, 21, 21) and Ns.shape == (S, 21, 21) and bs.shape == (S, 21)
    np.testing.assert_allclose(Ns, N.sum(axis=1), rtol=1e-13, atol=1e-12 * np.abs(Ns).max())
    np.testing.assert_allclose(bs, b.sum(axis=1), rtol=1e-13, atol=1e-12 * np.abs(bs).max())
    np.testing.assert_allclose(Ns, np.swapaxes(Ns, 1, 2), atol=1e-12 * np.abs(Ns).max())
