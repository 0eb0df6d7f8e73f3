"""The statistical tests on an output-error fit and its robust covariance.

Holds the test that the data need the geometry moved at all (:func:`geometry_needed`: the
likelihood ratio ``Λ = 2 (C_gains − C_full)`` scaled by ``n_eff / L``, against ``χ²(k)``), the
refinement's adequacy test (:func:`adequacy_test`: Hausman, ``h = dᵀ(V_s − V_r)⁺d ~ χ²(rank)``), the
input-clustered sandwich (:func:`input_robust_factors`:
``V = N⁻¹ (Σ_j (s_j − s̄)(s_j − s̄)ᵀ · J/(J−1) + J_pᵀJ_p) N⁻¹``), the effective number of lines
of a misfit (:func:`effective_lines`: ``n_eff = L (1 − ρ)/(1 + ρ)``) and the χ² quantile they
are compared with (:func:`_chi2_ppf`). Each function's docstring derives its equation.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from dimacq.model.setup import PARAMETERS
from dimacq.pipeline._special import chi2_ppf
from dimacq.pipeline.output_error.fit import line_residual
from dimacq.pipeline.output_error.model import Problem

FloatArray = NDArray[np.float64]
ComplexArray = NDArray[np.complex128]


def _chi2_ppf(q: float, dof: int) -> float:
    """χ² quantile, ``scipy.stats.chi2.ppf(q, dof)`` (its ``2·P⁻¹(dof/2, q)``) to ~1e-13, without
    importing scipy (:mod:`dimacq.pipeline._special`)."""
    return chi2_ppf(q, dof)


#: Significance of the refinement's adequacy test (:func:`adequacy_test`) and of the test that the
#: geometry needs moving (:func:`geometry_needed`).
ADEQUACY_P = 0.001


def geometry_needed(
    prob: Problem,
    theta: FloatArray,
    fit: Any,
    cand: NDArray[np.intp],
    n_geo: int,
    H: ComplexArray,
    R: ComplexArray,
    sigma: FloatArray,
    lw: FloatArray | None,
) -> tuple[dict[str, Any], Problem, FloatArray]:
    """Do the data need the geometry moved, or do the channels' gains explain them as well?

    Nested models at the same noise scale: the refined fit (geometry and gains) against the fit
    with the channel gains alone (geometry as stated). Their likelihood ratio
    ``Λ = 2 (C_gains − C_full)`` (whitened costs, priors included: ``E|e/σ|² = 1`` per complex
    datum, hence the factor 2) is ``χ²(k)`` under the stated geometry, ``k`` the free geometry
    corrections less the gauge constraints, *if the misfit were white*. A measured test's misfit
    is not: calibration errors and unmodelled transducer dynamics are smooth along the lines, and
    a misfit correlated over the band moves the cost of every line together. So ``Λ`` is scaled
    by ``n_eff / L`` (:func:`effective_lines` of the refined fit's residual): a misfit constant
    over the band counts once per channel and input, white noise on every line. Measured on
    acquired calibration-mass sets (exact geometry): ``Λ`` 116–180 for k = 136; with the realistic
    scenario's geometry errors (2 mm, 0.5°, 1°): 2·10⁵–8·10⁵.

    Returns the test, and the gains-only problem and solution.
    """
    res_f, _ = prob.residual(theta, jacobian=False)
    prob_g, theta_g, _, _, _, _ = fit(False, cand[cand >= n_geo])
    res_g, _ = prob_g.residual(theta_g, jacobian=False)
    raw = 2.0 * (float(res_g @ res_g) - float(res_f @ res_f))
    L = H.shape[0]
    n_eff = effective_lines(line_residual(prob, theta, H, R, sigma, lw))
    lr = raw * n_eff / L
    k = max(int(np.sum(prob.free_g < n_geo)) - int(prob.gauge_rows.shape[0]), 1)
    crit = _chi2_ppf(1.0 - ADEQUACY_P, k)
    return (
        {
            "tested": True,
            "test": (
                "likelihood ratio, refined geometry against channel gains alone, scaled by the "
                f"effective lines of the misfit ({n_eff:.3g} of {L}), p = {ADEQUACY_P:g}"
            ),
            "statistic": lr,
            "statistic_white": raw,
            "effective_lines": n_eff,
            "dof": k,
            "critical_value": crit,
            "needed": bool(lr > crit),
        },
        prob_g,
        theta_g,
    )


def adequacy_test(
    prob: Problem,
    theta: FloatArray,
    Jac: FloatArray,
    theta_s: FloatArray,
    scale: float,
) -> dict[str, Any]:
    """Does the refinement move the properties only as far as the stated geometry's uncertainty
    allows? (Hausman test of the refined against the stated-geometry estimate.)

    Linearised at the refined solution, with the data rows ``J_x, J_g`` (properties, whitened
    geometry corrections) and the gauge-constrained prior ``g ~ N(0, P)``,
    ``P = I − Rᵀ(RRᵀ)⁺R`` (``R`` the gauge rows): the stated-geometry estimate
    ``x_s = N_xx⁻¹ J_xᵀ y`` has covariance ``V_s = s² N_xx⁻¹ + K P Kᵀ``, ``K = N_xx⁻¹ J_xᵀ J_g``
    (noise plus the geometry's stated uncertainty it ignores), and the refined one, efficient
    under the model, ``V_r = s² [(JᵀJ)⁻¹]_xx``. If the misfit is geometry within its priors,
    ``d = x_r − x_s`` has covariance ``V_s − V_r`` and ``h = dᵀ(V_s − V_r)⁺d ~ χ²(rank)``. A
    large ``h`` says the refinement explained a misfit that is not geometry within its stated
    uncertainty (channel calibration, a load-cell chain, a model the rigid body lacks) by moving
    the sensors: the refined answer cannot silently replace the stated one. The covariances are
    the model's (noise scaled by the reduced χ²), not the input-clustered sandwich's: the
    sandwich widens both where the misfit is correlated within the inputs and would hide exactly
    the disagreement looked for (a calibration mass standing on its cell, band just above the
    support modes: the refinement moved the mass 15 % and the sandwich's test passed at 7.7; the
    model's gave 356 against 29.6, while acquired and model-FRF rigid cases gave 2–11).

    Returns
    -------
    dict
        ``tested``, ``statistic``, ``dof``, ``critical_value`` (at :data:`ADEQUACY_P`),
        ``passed``, ``difference`` (``x_r − x_s`` of the free properties, SI relative to P).
    """
    nx = prob.free_x.size
    n_data = prob.Lh.size
    Jx, Jg = Jac[:n_data, :nx], Jac[:n_data, nx:]
    Nxx_inv = np.linalg.pinv(Jx.T @ Jx)
    K = Nxx_inv @ (Jx.T @ Jg)
    Rg = prob.gauge_rows
    P = np.eye(Jg.shape[1])
    if Rg.shape[0]:
        P -= Rg.T @ np.linalg.pinv(Rg @ Rg.T) @ Rg
    Vs = scale * Nxx_inv + K @ P @ K.T
    Vr = scale * np.linalg.pinv(Jac.T @ Jac)[:nx, :nx]
    D = Vs - Vr
    d = theta[:nx] - theta_s[:nx]
    lam, vec = np.linalg.eigh(0.5 * (D + D.T))
    ok = lam > max(float(lam.max(initial=0.0)), 0.0) * 1e-9
    if not ok.any():
        return {"tested": False, "reason": "the refinement changes nothing the data can test"}
    h = float(np.sum((vec[:, ok].T @ d) ** 2 / lam[ok]))
    dof = int(ok.sum())
    crit = _chi2_ppf(1.0 - ADEQUACY_P, dof)
    return {
        "tested": True,
        "test": f"Hausman (refined against stated geometry), p = {ADEQUACY_P:g}",
        "statistic": h,
        "dof": dof,
        "critical_value": crit,
        "passed": bool(h <= crit),
        "difference": [float(v) for v in d],
        "free_parameters": [PARAMETERS[i] for i in prob.free_x],
    }


def input_robust_factors(
    prob: Problem,
    theta: FloatArray,
    Jac: FloatArray,
    cov: FloatArray,
    nx: int,
    N_inv: FloatArray | None = None,
) -> FloatArray:
    """Per free property, ``max(1, σ_robust / σ_model)``: the input-clustered sandwich against the
    model-based posterior.

    The posterior ``N⁻¹ = (JᵀJ)⁻¹`` (× the reduced χ²) holds when the misfit is independent noise
    on every line and channel. A misfit the rigid model lacks (the stiffness-line residual of an
    elastic mode near the band, a support it does not see) is smooth along the lines and
    correlated over an input's channels, and its effect on the estimate is far larger than the
    same misfit as white noise. The inputs are independent experiments, so the cluster-robust
    (Liang–Zeger) covariance holds whatever the correlation within one input:

        V = N⁻¹ (Σ_j (s_j − s̄)(s_j − s̄)ᵀ · J/(J−1) + J_pᵀJ_p) N⁻¹,   s_j = J_jᵀ r_j

    with ``s_j`` input ``j``'s score (the gradient of its cost: rows of the data residual and
    Jacobian that belong to it, :meth:`Problem.residual`), centred (the priors' pull balances
    their sum at the MAP), and ``J_pᵀJ_p`` the priors' own (their scores have unit variance; the
    gauge constraint rows carry none). Where a property's ``V`` exceeds the model-based variance,
    its row and column of the covariance are scaled up to it (correlations kept); never down:
    with ~20 inputs the robust variance is itself known only to ±30 %.

    Returns
    -------
    ndarray, shape (nx,)
        Factors ``≥ 1`` for the rows and columns of the free properties' covariance.
    """
    J_ = prob.Lh.shape[0]
    if J_ < 3:
        return np.ones(nx)
    n_data = prob.Lh.size
    res, _ = prob.residual(theta, jacobian=False)
    Jd = Jac[:n_data].reshape(J_, -1, Jac.shape[1])
    sc = np.einsum("jrp,jr->jp", Jd, res[:n_data].reshape(J_, -1))
    sc = sc - sc.mean(axis=0)
    n_g = prob.free_g.size
    Jp = Jac[n_data : n_data + n_g]
    B = sc.T @ sc * (J_ / (J_ - 1)) + Jp.T @ Jp
    Ninv = np.linalg.pinv(Jac.T @ Jac) if N_inv is None else N_inv  # the caller's, if formed
    V = Ninv @ B @ Ninv
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.diag(V)[:nx] / np.diag(cov)[:nx]
    return np.asarray(np.sqrt(np.where(np.isfinite(ratio), np.maximum(ratio, 1.0), 1.0)), float)


def effective_lines(e: ComplexArray) -> float:
    """How many independent lines a misfit along the lines is worth (AR(1) approximation).

    With ``ρ`` the lag-one autocorrelation of the residual along the lines (real and imaginary
    parts of every channel and input, each about its mean; the median over them),
    ``n_eff = L (1 − ρ)/(1 + ρ)``, between 1 and ``L``: white noise counts every line; a misfit
    smooth over the band (a transducer's roll-off, an unmodelled trend) counts as the few
    independent lines it is. (The integrated autocorrelation time of the initial positive
    sequence gives 2–3 times more lines on acquired calibration-mass sets: the misfit there is
    not AR(1); the test below was measured with this one.)
    """
    L = e.shape[0]
    if L < 3:
        return float(L)
    x = np.concatenate([e.real, e.imag], axis=1).reshape(L, -1)
    x = x - x.mean(axis=0)
    den = np.sum(x * x, axis=0)
    ok = den > 0
    if not ok.any():
        return float(L)
    rho = np.sum(x[1:] * x[:-1], axis=0)[ok] / den[ok]
    r = float(np.clip(np.median(rho), -0.99, 0.999))
    return float(np.clip(L * (1 - r) / (1 + r), 1.0, L))
