"""The scipy-free distribution functions and eigen helpers of ``dimacq solve`` against scipy."""

from __future__ import annotations

import math

import numpy as np
import pytest
import scipy.linalg
from scipy import special

from dimacq.pipeline._special import (
    chi2_ppf,
    chi2_sf,
    eigh_generalized,
    null_space,
    t_ppf,
)

#: degrees of freedom a solve meets: inputs − 1, 11 for the structure χ², lines of a band
DOFS = [*range(1, 40), 55, 100, 237, 1000, 2047, 5000]


@pytest.mark.parametrize("dof", DOFS)
def test_chi2_quantile_and_survival_match_scipy(dof: int) -> None:
    for q in (0.001, 0.05, 0.5, 0.95, 0.99, 0.999):
        x = chi2_ppf(q, dof)
        assert x == pytest.approx(2.0 * special.gammaincinv(dof / 2, q), rel=1e-12)
        # and it inverts the survival function written independently of it (the fraction)
        assert chi2_sf(x, dof) == pytest.approx(1.0 - q, rel=1e-11)
    for x in np.geomspace(1e-3, 1e4, 25):
        ref = float(special.chdtrc(dof, x))
        assert chi2_sf(float(x), dof) == pytest.approx(ref, rel=1e-12, abs=1e-300)
    assert chi2_sf(math.inf, dof) == 0.0


@pytest.mark.parametrize("df", DOFS)
def test_t_quantile_matches_scipy(df: int) -> None:
    # large ν: log Γ(a + ½) − log Γ(a) of numbers ~1e4 keeps ~1e-12 of the prefactor's digits
    rel = 1e-12 if df < 1000 else 1e-11
    for p in (0.001, 0.05, 0.3, 0.9, 0.975, 0.999):
        assert t_ppf(p, df) == pytest.approx(float(special.stdtrit(df, p)), rel=rel)


def test_t_quantile_closed_forms_near_the_median() -> None:
    """ν = 1 (Cauchy: tan π(p − ½)) and ν = 2 ((2p − 1)/√(2p(1 − p))), where a tail formula loses
    its digits."""
    for p in (0.5000001, 0.51, 0.6, 0.975):
        assert t_ppf(p, 1) == pytest.approx(math.tan(math.pi * (p - 0.5)), rel=1e-13)
        assert t_ppf(p, 2) == pytest.approx((2 * p - 1) / math.sqrt(2 * p * (1 - p)), rel=1e-13)
    with pytest.raises(ValueError, match="strictly between 0 and 1"):
        t_ppf(1.0, 3)
    with pytest.raises(ValueError, match="strictly between 0 and 1"):
        chi2_ppf(0.0, 3)


def test_generalized_eigenproblem_and_null_space_match_scipy() -> None:
    rng = np.random.default_rng(27)
    for n in (1, 2, 5, 9):
        m = rng.standard_normal((n, n))
        a = m + m.T
        r = rng.standard_normal((n, n))
        b = r @ r.T + n * np.eye(n)
        lam, x = eigh_generalized(a, b)
        ref = scipy.linalg.eigh(a, b, eigvals_only=True)
        np.testing.assert_allclose(lam, ref, rtol=1e-12, atol=1e-12 * np.max(np.abs(ref)))
        np.testing.assert_allclose(a @ x, b @ x * lam, atol=1e-11 * np.max(np.abs(a)))
        np.testing.assert_allclose(x.T @ b @ x, np.eye(n), atol=1e-12)
    a = rng.standard_normal((3, 7))
    a[2] = a[0] + a[1]  # rank 2: a 5-dimensional null space
    z = null_space(a)
    assert z.shape == scipy.linalg.null_space(a).shape == (7, 5)
    np.testing.assert_allclose(a @ z, 0.0, atol=1e-13)
    np.testing.assert_allclose(z.T @ z, np.eye(5), atol=1e-13)
