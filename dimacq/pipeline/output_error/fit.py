"""Fitting the output-error model: the gauge constraint, Levenberg–Marquardt, the residual on
every line.

Holds :func:`gauge_constraint` (the gauge modes the data do not identify, fixed by an inner
constraint), :func:`lm` (Levenberg–Marquardt with column equilibration on the residual of
:meth:`.model.Problem.residual`), and the direct residual ``w (H − Ĥ)/σ`` on every line
(:func:`line_residual`) with its cost ``Σ w²|H − Ĥ|²/σ²`` (:func:`weighted_direct_cost`), which χ² and
the tests of :mod:`.checks` use.

Gauge
-----
A common similarity of the whole instrumentation (translation, rotation about P and scale of all
sensors, inputs and load cells together, with the body's properties moved with it:
:func:`gauge_property_jacobian`) and a common accelerometer gain leave every FRF unchanged
(``ψᵀ M⁻¹ φ`` is invariant under ``ψ → Sψ``, ``φ → Sφ``, ``M → SMS``; a cell's reactions at P
move with its pose; under the scale its own moments would need its moment gains moved too, which
the scale mode leaves out: model.py, ``gauge_basis``). When the cells are not
refined (``OutputErrorOptions.refine_load_cells`` off) their stated poses break the symmetry,
and the reactions alone see it. The priors fix
what the data do not (inner constraint, :func:`gauge_constraint`): the scale and the common gain
always (the reactions could pin the scale only if modelled to a few 0.1 %), and by default the
translations and rotations too (the reactions tie the frame only to the load cells' stated
positions, themselves measured geometry: ``OutputErrorOptions.gauge_from_reactions``). Frame, scale and gain are then those of the stated
(digitized, registered) geometry and certificates, and their prior variance — the Cramér–Rao
bound of any estimator from these FRFs and priors — is in the intervals
(``tests/scripts/accuracy_diagnose.py`` prints it). Its scale share is
``σ_s = (Σ_i |r_i,⊥|² / σ_p²)^(-1/2)`` over the sensor and input positions (about P; inputs: the
components normal to the line), which sets the principal moments' floor at ``2 σ_s`` whatever the
data; the translation's, ``σ_p / √N`` per axis, the CG's.
"""

from __future__ import annotations

import logging

import numpy as np
from numpy.typing import NDArray

from dimacq.pipeline._batched import cross3
from dimacq.pipeline._special import eigh_generalized, null_space
from dimacq.pipeline.output_error.model import Problem, mass_matrix

#: the logger of the module before the split into a package: the messages keep its name
log = logging.getLogger("dimacq.pipeline.output_error")

FloatArray = NDArray[np.float64]
ComplexArray = NDArray[np.complex128]


def gauge_constraint(
    prob: Problem,
    theta0: FloatArray,
    refuse_ratio: float,
    fix_all: bool = False,
    data_jacobian: FloatArray | None = None,
) -> None:
    """Fix the gauge modes the data do not identify (sets ``prob.gauge_rows``).

    ``data_jacobian``: the data rows of the Jacobian at ``theta0`` when the caller has them
    (:meth:`Problem.residual`'s, whose data rows do not depend on the constraint rows).

    The similarity of the whole instrumentation (the load cells included when they are refined)
    and the common accelerometer gain (:meth:`Problem.gauge_basis`, ``G``) change no FRF when the
    properties move with them; only load cells held at their stated poses and calibration can tie
    them. The fixed scale holds the product of the sensors' and
    the inputs' scales (what the principal moments follow) only if nothing in the model ties
    their ratio to an exact length: with the cells held exact, the reactions did, and a 0.3 %
    error in them moved the principal moments 0.5 % (on acquired sets). In the
    whitened corrections ``θ_g = δg/σ_g`` a gauge motion is ``G_θ c`` with
    ``G_θ = diag(1/σ_g) G``; the prior's information on ``c`` is ``P = G_θᵀG_θ`` and the data's,
    properties marginalised, ``D = G_θᵀ (J_gᵀJ_g − J_gᵀJ_x (J_xᵀJ_x)⁻¹ J_xᵀJ_g) G_θ``.

    - The **scale** and the **common gain** are always fixed: the common gain is an exact
      symmetry even with reactions, and the scale acts on the reactions only as the factor
      ``1/(1+s)`` on their moments about P, so pinning it to the prior's precision (a few
      0.1 %) needs the reactions modelled to that relative accuracy — finer than the reaction
      model (smooth basis, errors-in-variables compensation) and the load cells' own
      calibration and stated positions, which the model takes as exact. Measured
      (``tests/scripts/accuracy_diagnose.py``): let free, the true geometry with 1 % FRF noise
      came out 0.25 % off in scale (principal moments +0.5 %) on a bungee-hung mass.
    - The translations and rotations, in the part of the space ``P``-orthogonal to those two,
      are the modes of ``D v = λ P v``; those the data do not identify by the rule used for
      each item (posterior σ ``1/√(1+λ)`` of the prior's above ``refuse_ratio``) are fixed too
      (all of them with ``fix_all``).

    A fixed mode satisfies ``(G_θ v)ᵀ θ_g = 0``: the corrections have no component along it in
    the prior's metric (the inner constraint of bundle adjustment), and frame, scale and common
    gain are those of the stated geometry and certificates. The fixed modes are ``P``-orthogonal
    to the free ones, so their prior variance ``(VᵀPV)⁻¹`` is their marginal variance; it is
    added to the properties' covariance afterwards (:func:`gauge_property_jacobian`), so the
    intervals keep it — the Cramér–Rao bound of any estimator from these FRFs and priors along
    those modes.
    """
    G = prob.gauge_basis()[prob.free_g] / prob.sigma_g[prob.free_g][:, None]
    live = np.linalg.norm(G, axis=0) > 0
    G = G[:, live]
    prob.gauge_rows = np.zeros((0, prob.free_g.size))
    prob.gauge_modes = np.zeros((int(live.sum()), 0))
    prob.gauge_live = live
    if not G.shape[1]:
        return
    if data_jacobian is None:
        _, J0 = prob.residual(theta0)
        assert J0 is not None
        data_jacobian = J0[: J0.shape[0] - prob.free_g.size]
    nx = prob.free_x.size
    Jd = data_jacobian
    Jx, Jg = Jd[:, :nx], Jd[:, nx:]
    Nxx, Nxg, Ngg = Jx.T @ Jx, Jx.T @ Jg, Jg.T @ Jg
    Dg = Ngg - Nxg.T @ np.linalg.pinv(Nxx) @ Nxg
    # Gauge coordinates c that move nothing (columns of G dependent once items are fixed or
    # left out) carry no prior and no data: work in the row space of G, c = W y, where
    # P_y = Wᵀ GᵀG W is positive definite.
    _, sv, Wt = np.linalg.svd(G, full_matrices=False)
    W = Wt[sv > sv[0] * 1e-9].T
    D = W.T @ (G.T @ Dg @ G) @ W
    P = W.T @ (G.T @ G) @ W
    D, P = 0.5 * (D + D.T), 0.5 * (P + P.T)
    lam_all = eigh_generalized(D, P)[0]
    # always fixed: the scale and common-gain axes (columns 6, 7 of the full basis), in y
    live_idx = np.nonzero(live)[0]
    A = W[np.isin(live_idx, (6, 7)) | fix_all].T  # (r, n_always)
    if A.shape[1]:
        ua, sa, _ = np.linalg.svd(A, full_matrices=False)
        A = ua[:, sa > sa[0] * 1e-9]
    # the rest, P-orthogonal to A: B spans {y : Aᵀ P y = 0}
    B = null_space((P @ A).T) if A.shape[1] else np.eye(W.shape[1])
    fixed_y = A
    if B.shape[1]:
        lam, U = eigh_generalized(B.T @ D @ B, B.T @ P @ B)
        sel = 1.0 / np.sqrt(1.0 + np.clip(lam, 0.0, None)) > refuse_ratio
        fixed_y = np.concatenate([A, B @ U[:, sel]], axis=1)
    fixed = W @ fixed_y
    prob.gauge_information_ratio = lam_all
    if not fixed.shape[1]:
        return
    rows = (G @ fixed).T
    rows /= np.linalg.norm(rows, axis=1, keepdims=True)
    prob.gauge_rows = rows
    prob.gauge_modes = fixed


def lm(
    prob: Problem, theta0: FloatArray, max_iter: int
) -> tuple[FloatArray, FloatArray, float, int]:
    """Levenberg–Marquardt with column equilibration; returns θ, Jacobian, cost, iterations."""
    theta = theta0.copy()
    res, Jac = prob.residual(theta)
    assert Jac is not None
    cost = float(res @ res)
    lam = 1e-6
    it = 0
    while it < max_iter:
        it += 1
        N = Jac.T @ Jac
        g = Jac.T @ res
        dsc = np.sqrt(np.diag(N))
        dsc = np.where(dsc > 0, dsc, 1.0)
        Ns = N / np.outer(dsc, dsc)
        improved = False
        for _ in range(12):
            try:
                step = -np.linalg.solve(Ns + lam * np.eye(Ns.shape[0]), g / dsc) / dsc
            except np.linalg.LinAlgError:
                lam *= 10
                continue
            t_new = theta + step
            try:
                r_new, _ = prob.residual(t_new, jacobian=False)
            except np.linalg.LinAlgError:
                lam *= 10
                continue
            c_new = float(r_new @ r_new)
            if np.isfinite(c_new) and c_new <= cost:
                improved = True
                break
            lam *= 10
        if not improved:
            break
        # predicted decrease −gᵀδ (Newton decrement, cost units of χ²/2): below 1e-2 the step is
        # about a tenth of the posterior standard deviations: further iterations change nothing
        dec = float(-(g @ step))
        rel = (cost - c_new) / max(cost, 1e-300)
        log.debug("LM %d: cost %.6g → %.6g, decrement %.3g, λ %.1g", it, cost, c_new, dec, lam)
        theta = t_new
        cost = c_new
        lam = max(lam / 10, 1e-9)
        res, Jac = prob.residual(theta)
        assert Jac is not None
        if dec < 1e-2 or rel < 1e-12 or float(np.max(np.abs(step * dsc))) < 1e-8:
            break
    return theta, Jac, cost, it


def line_residual(
    prob: Problem,
    theta: FloatArray,
    H: ComplexArray,
    R: ComplexArray,
    sigma: FloatArray,
    lw: FloatArray | None = None,
) -> ComplexArray:
    """``w (H − Ĥ)/σ`` on every line, channel and input (L, C, J), read-only.

    The last one is kept on ``prob`` (with references to the arrays it came from, so that their
    identities stay theirs): asked again for the same θ, free items and arrays, it is returned
    as it is instead of computed anew."""
    key = (theta.tobytes(), prob.free_g.tobytes(), id(H), id(R), id(sigma), id(lw))
    memo = prob.line_residual_memo
    if memo is not None and memo[0] == key:
        return memo[2]
    x = prob.full_x(theta)
    gfull = prob.full_g(theta)
    r, d, rin, din = prob.geometry(gfull)
    A = np.linalg.inv(mass_matrix(x)[0])
    psi = np.concatenate([d, cross3(r, d)], axis=1)
    psi = psi * (1.0 + gfull[gfull.size - psi.shape[0] :])[:, None]
    phi = np.concatenate([din, cross3(rin, din)], axis=1)
    mot = A @ (phi.T[None] + prob.reactions_at_p(gfull, R))  # (L, 6, J)
    # Ψ (real) times the motions as one real product on their (re, im) view, and 1/σ as a
    # product: numpy's complex matmul and division give these numbers (up to the sign of a zero)
    pred = (psi @ mot.view(np.float64)).view(np.complex128)
    e = (H - pred) * (1.0 / sigma)[None]
    if lw is not None:
        e = e * lw[:, None, :]
    e.flags.writeable = False
    prob.line_residual_memo = (key, (H, R, sigma, lw), e)
    return e


def weighted_direct_cost(
    prob: Problem,
    theta: FloatArray,
    H: ComplexArray,
    R: ComplexArray,
    sigma: FloatArray,
    basis: ComplexArray | None,
    lw: FloatArray | None = None,
) -> float:
    """``Σ w²|H − Ĥ|²/σ²`` over every line, channel and input (residual terms projected out when
    ``basis`` is given; ``w`` the line weights, 1 when absent): the data cost without the bias
    compensation, for χ² and the test."""
    e = line_residual(prob, theta, H, R, sigma, lw)
    if basis is not None:
        Bs = np.concatenate([basis.real, basis.imag], axis=0)  # (2L, nb)
        es = np.concatenate([e.real, e.imag], axis=0).reshape(2 * e.shape[0], -1)
        Q, _ = np.linalg.qr(Bs)
        es = es - Q @ (Q.T @ es)
        return float(np.sum(es**2))
    memo = prob.line_residual_memo
    if memo is not None and memo[2] is e and len(memo) > 3:
        return float(memo[3])  # this residual's sum, already formed
    cost = float(np.sum(np.abs(e) ** 2))
    if memo is not None and memo[2] is e:
        prob.line_residual_memo = (*memo[:3], cost)
    return cost
