"""The stages of the output-error solve (:func:`dimacq.pipeline.output_error.solver.solve_output_error`): the band's data and noise, the stated geometry and its priors, the fitter, the geometry test, the residual terms, the posterior and the noise report; the equations are in this package's modules."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from dimacq.errors import SolverError
from dimacq.model.frf import FrfData
from dimacq.model.setup import PARAMETERS, TestSetup
from dimacq.pipeline._batched import cross3
from dimacq.pipeline._special import chi2_ppf
from dimacq.pipeline.dim import DimResult, cell_reactions
from dimacq.pipeline.output_error.checks import (
    adequacy_test,
    geometry_needed,
    input_robust_factors,
)
from dimacq.pipeline.output_error.fit import gauge_constraint, lm, weighted_direct_cost
from dimacq.pipeline.output_error.model import (
    EYE3,
    Problem,
    gauge_property_jacobian,
    mass_matrix,
    reduced_statistics,
)
from dimacq.pipeline.output_error.noise import (
    REACTION_SNR_LOW,
    estimate_noise,
    line_weights,
    reaction_noise_cov,
    smooth_reactions,
    third_difference_power,
)
from dimacq.pipeline.output_error.report import (
    OutputErrorOptions,
    residual_size,
    rf_mode_label,
)

#: the logger of the module before the split into a package: the messages keep its name


FloatArray = NDArray[np.float64]
ComplexArray = NDArray[np.complex128]


# ------------------------------------------------------------------------------------------
# The stages of the solve
# ------------------------------------------------------------------------------------------
@dataclass
class BandData:
    """The band's data relative to P, their noise and the load cells' reactions.

    ``H`` (L, C, J) the kept accelerances, ``R`` (L, 6K, J) each load cell's reactions at P
    (smoothed, :func:`.noise.smooth_reactions`), ``sigma`` (C, J) the FRF noise,
    ``cov_R`` (J, 6K, 6K) the reactions' noise left after the smoothing, ``R_at_p`` (L, 6, J)
    the stated cells' sum at P, ``reaction_snr`` (L, J) ``Σ_k |R_ℓkj|² / tr Σ_Rj``.
    """

    H: ComplexArray
    R: ComplexArray
    sigma: FloatArray
    cov_R: FloatArray
    R_at_p: ComplexArray
    reaction_snr: FloatArray
    h_mean_power: FloatArray
    cell_nodes: tuple[int, ...]
    h_power: FloatArray | None
    d3_power: FloatArray | None


def band_data(
    frf: FrfData, setup: TestSetup, out_idx: NDArray[np.intp], in_idx: NDArray[np.intp]
) -> BandData:
    """The data of the fit: the kept channels and inputs, their noise and the reactions at P."""
    p = setup.reference_point
    H = frf.H[:, out_idx][:, :, in_idx]  # (L, C, J)
    # each load cell's reactions at P (L, 6K, J), N and N·m per N: the fit may turn and move
    # each cell within its stated uncertainty (model.py, Problem.cell_maps)
    cell_nodes, R = cell_reactions(frf, setup, p)
    R = R[:, :, in_idx]
    L_lines = H.shape[0]
    # |H|², its band mean and |Δ³H|² once: the noise, its floor, the line weights and the report
    h_power = np.abs(H) ** 2
    h_mean_power = np.mean(h_power, axis=0)  # (C, J)
    d3_power = third_difference_power(H) if L_lines >= 8 else None
    sigma = estimate_noise(H, d3_power=d3_power)
    floor = 1e-6 * np.sqrt(h_mean_power)
    sigma = np.maximum(sigma, np.maximum(floor, 1e-300))
    cov_R = (
        reaction_noise_cov(R)
        if R.shape[0] >= 8
        else np.zeros((len(in_idx), R.shape[1], R.shape[1]))
    )
    # the reactions' power against their own noise, per line and input:
    # S/N_ℓj = Σ_k |R_ℓkj|² / tr Σ_Rj (the share of lines at noise level is reported)
    with np.errstate(divide="ignore", invalid="ignore"):
        reaction_snr = np.sum(np.abs(R) ** 2, axis=1) / np.einsum("jii->j", cov_R)[None]
    R, n_rb = smooth_reactions(R, frf.frequencies_hz, cov_R)
    cov_R = cov_R * n_rb[:, None, None]  # noise left in Σ_ω Re(R̂ R̂ᴴ) after the projection
    R_at_p = R.reshape(L_lines, len(cell_nodes), 6, len(in_idx)).sum(axis=1)
    return BandData(
        H, R, sigma, cov_R, R_at_p, reaction_snr, h_mean_power, cell_nodes, h_power, d3_power
    )


@dataclass
class StatedGeometry:
    """The stated geometry relative to P and its priors, in the fit's item order.

    Sensors (``r0``, ``d0`` per kept channel; ``nodes`` and ``node_of`` their triax nodes),
    inputs (``rin0``, ``din0`` and ``eb`` the two unit vectors normal to each line of action),
    load cells (``cell_r0``, ``cell_rot0``), and ``sig_g`` the prior standard deviation of every
    geometry item: 6 per node, 4 per input, 9 per load cell, 1 per channel gain.
    """

    r0: FloatArray
    d0: FloatArray
    nodes: NDArray[np.int64]
    node_of: NDArray[np.intp]
    rin0: FloatArray
    din0: FloatArray
    eb: FloatArray
    cell_r0: FloatArray
    cell_rot0: FloatArray
    sig_g: FloatArray


def stated_geometry(
    frf: FrfData,
    setup: TestSetup,
    geo: Any,
    active: NDArray[np.bool_],
    in_idx: NDArray[np.intp],
    cell_nodes: tuple[int, ...],
    refine_load_cells: bool,
) -> StatedGeometry:
    """The geometry as stated by the setup, relative to P, with its priors."""
    p = setup.reference_point
    r0 = geo.positions_m[active] - p
    d0 = geo.directions[active]
    nodes, node_of = np.unique(geo.nodes[active], return_inverse=True)
    ex = {(e.node, e.direction): e for e in setup.excitations}
    rin0, din0 = [], []
    for j in in_idx:
        ch = frf.inputs[j]
        e = ex.get((ch.node, ch.direction)) or ex.get((ch.node, -ch.direction))
        assert e is not None and e.direction_gcs is not None  # assemble checked
        s = 1.0 if e.direction == ch.direction else -1.0
        rin0.append(np.asarray(e.position_m) - p)
        din0.append(s * np.asarray(e.direction_gcs))
    rin0_a, din0_a = np.asarray(rin0, float), np.asarray(din0, float)
    cells = {lc.node: lc for lc in setup.load_cells}
    cell_r0 = np.array([np.asarray(cells[n].position_m, float) - p for n in cell_nodes]).reshape(
        -1, 3
    )
    cell_rot0 = np.array([cells[n].rotation_matrix for n in cell_nodes]).reshape(-1, 3, 3)
    eb = np.empty((len(in_idx), 2, 3))
    for k, dv in enumerate(din0_a):
        a = EYE3[int(np.argmin(np.abs(dv)))]
        e1 = cross3(dv, a)
        e1 /= np.linalg.norm(e1)
        eb[k] = (e1, cross3(dv, e1))
    gu = setup.geometry_uncertainty
    nn, J = nodes.size, len(in_idx)
    sig_g = np.concatenate(
        [
            np.tile([np.deg2rad(gu.sensor_orientation_deg)] * 3 + [gu.sensor_position_m] * 3, nn),
            np.tile([np.deg2rad(gu.line_of_action_deg)] * 2 + [gu.input_position_m] * 2, J),
            # each load cell: a small rotation (3), an offset of its point (3) and the gains of
            # its three moment outputs against its calibration (3; report.py, refine_load_cells)
            np.tile(
                [np.deg2rad(gu.load_cell_orientation_deg)] * 3
                + [gu.load_cell_position_m] * 3
                + [setup.transducer_uncertainty.loadcell_matrix_rel] * 3,
                len(cell_nodes),
            )
            * float(refine_load_cells),
            # each accelerometer axis's sensitivity against its certificate (relative)
            np.full(int(active.sum()), setup.transducer_uncertainty.accel_sensitivity_rel),
        ]
    )
    return StatedGeometry(r0, d0, nodes, node_of, rin0_a, din0_a, eb, cell_r0, cell_rot0, sig_g)


class Fitter:
    """The fits of one solve: the data, the stated geometry and the start shared.

    ``sigma`` (the noise model, rescaled by the variance factor) and ``cand`` (the geometry
    items a fit may refine) are read at each fit. The reduced statistics depend on the data, the
    noise scale and the basis only, not on the free geometry: fits that share them (the first
    fit, the gains-only fit of the geometry test, the refits) reuse them.
    """

    def __init__(
        self,
        data: BandData,
        g: StatedGeometry,
        opt: OutputErrorOptions,
        free_x: NDArray[np.intp],
        x_fixed: FloatArray,
        x_start: FloatArray,
        cand: NDArray[np.intp],
        basis: ComplexArray,
        lw0: FloatArray | None,
    ) -> None:
        self.data, self.g, self.opt = data, g, opt
        self.free_x, self.x_fixed, self.x_start = free_x, x_fixed, x_start
        self.cand, self.basis, self.lw0 = cand, basis, lw0
        self.sigma = data.sigma
        self._memo: dict[bool, tuple[tuple[object, ...], tuple[FloatArray, FloatArray, float]]] = {}

    def line_w(self, use_basis: bool = False) -> FloatArray | None:
        """The line weights; with residual terms the projection is per channel over all lines."""
        return None if use_basis else self.lw0

    def build(self, use_basis: bool, free_g: NDArray[np.intp]) -> tuple[Problem, float]:
        d, g = self.data, self.g
        args = (d.H, d.R, self.sigma, d.cov_R, self.basis if use_basis else None,
                self.line_w(use_basis))  # fmt: skip
        memo = self._memo.get(use_basis)
        if memo is not None and all(a is b for a, b in zip(memo[0], args, strict=True)):
            Ly, Lh, const = memo[1]
        else:
            Ly, Lh, const = reduced_statistics(*args)
            self._memo[use_basis] = (args, (Ly, Lh, const))
        return (
            Problem(
                g.r0, g.d0, g.node_of, g.nodes, g.rin0, g.din0, g.eb, 1.0 / self.sigma, Ly, Lh,
                self.free_x, self.x_fixed, free_g, g.sig_g, cell_r0=g.cell_r0,
                cell_rot0=g.cell_rot0,
            ),
            const,
        )  # fmt: skip

    def fit(
        self, use_basis: bool, cands: NDArray[np.intp] | None = None
    ) -> tuple[Problem, FloatArray, FloatArray, float, int, list[int]]:
        """Refuse the unidentified items, fix the gauge, and fit (Levenberg–Marquardt)."""
        opt, free_x, x_start = self.opt, self.free_x, self.x_start
        cand_ = self.cand if cands is None else cands
        prob, const = self.build(use_basis, cand_)
        theta0 = np.concatenate([x_start[free_x], np.zeros(cand_.size)])
        refused: list[int] = []
        if self.cand.size:
            _, J0 = prob.residual(theta0)
            assert J0 is not None
            post = np.linalg.pinv(J0.T @ J0)
            ratio = np.sqrt(np.clip(np.diag(post)[free_x.size :], 0, None))
            ok = ratio <= opt.refuse_ratio
            refused = [int(i) for i in cand_[~ok]]
            prob.free_g = cand_[ok]
            theta0 = np.concatenate([x_start[free_x], np.zeros(prob.free_g.size)])
            if opt.fix_gauge and prob.free_g.size:
                # the data rows of J0 in the columns kept: the Jacobian at theta0 of the items
                # kept, without computing it again (its data rows are the same numbers)
                cols = np.concatenate([np.arange(free_x.size), free_x.size + np.nonzero(ok)[0]])
                gauge_constraint(
                    prob,
                    theta0,
                    opt.refuse_ratio,
                    fix_all=not opt.gauge_from_reactions,
                    data_jacobian=J0[: prob.Lh.size][:, cols],
                )
        theta, Jac, cost, it = lm(prob, theta0, opt.max_iterations)
        return prob, theta, Jac, cost + const, it, refused

    def direct_cost(
        self, prob: Problem, theta: FloatArray, use_basis: bool = False, lw: bool = True
    ) -> float:
        """The fit's cost on the data, recomputed directly (not from the reduced statistics)."""
        d = self.data
        weights = self.line_w(use_basis) if lw else None
        basis = self.basis if use_basis else None
        return float(weighted_direct_cost(prob, theta, d.H, d.R, self.sigma, basis, weights))


@dataclass
class Fit:
    """One fit's state as the stages hand it on."""

    prob: Problem
    theta: FloatArray
    Jac: FloatArray
    it: int
    refused: list[int]


def geometry_test_step(fitter: Fitter, fit: Fit) -> tuple[dict[str, Any], FloatArray | None, str]:
    """Do the data need the geometry moved? If not, the stated-geometry estimate (the gains
    refined) is reported: ``(geometry_test, stated_theta or None, note)``."""
    opt, nx = fitter.opt, fitter.free_x.size
    prob, theta = fit.prob, fit.theta
    n_geo = prob.gain_base  # geometry items (sensors, inputs, load cells) before the gains
    if not (opt.geometry_test and fitter.cand.size and np.any(prob.free_g < n_geo)):
        return {"tested": False}, None, ""
    d = fitter.data
    geometry_test, prob_g, theta_g = geometry_needed(
        prob, theta, fitter.fit, fitter.cand, n_geo, d.H, d.R, fitter.sigma, fitter.line_w()
    )
    if geometry_test["needed"]:
        return geometry_test, None, ""
    # the stated geometry explains the data as well as the refined one: report the estimate with
    # the geometry as stated (the channels' gains refined); its intervals are the refined fit's
    # posterior widened by the difference of the two (covariance_step)
    stated_theta = theta.copy()
    stated_theta[:nx] = theta_g[:nx]
    where = {int(k): i for i, k in enumerate(prob_g.free_g)}
    for i, k in enumerate(prob.free_g):
        stated_theta[nx + i] = (
            0.0 if k < n_geo or int(k) not in where else theta_g[nx + where[int(k)]]
        )
    note = (
        "stated value kept: the data do not need the geometry moved (likelihood ratio "
        f"{geometry_test['statistic']:.3g} ≤ {geometry_test['critical_value']:.3g}, "
        f"{geometry_test['dof']} dof); the refined fit's posterior and its difference "
        "to the stated-geometry estimate are in the intervals"
    )
    return geometry_test, stated_theta, note


def residual_flexibility_step(
    fitter: Fitter, fit: Fit, n_data: int, n_rf: int
) -> tuple[Fit, dict[str, Any], FloatArray | None]:
    """Fit with and without residual terms and keep them when the Hausman test needs them.

    Under a rigid structure both fits are consistent and the one without residual terms is
    efficient, so ``d = x_b − x_a`` has covariance ``V_b − V_a``; a large
    ``dᵀ (V_b − V_a)⁺ d`` says the residual terms change the properties beyond noise. Returns the
    fit kept, the report, and the model-form difference ``d`` when the terms are kept.
    """
    rf_mode = fitter.opt.residual_flexibility
    rf_info: dict[str, Any] = {"fitted": False, "mode": rf_mode_label(rf_mode)}
    if rf_mode is False:
        return fit, rf_info, None
    prob_b, theta_b, Jac_b, _cost_b, it_b, refused_b = fitter.fit(True)
    ca = fitter.direct_cost(fit.prob, fit.theta)
    cb = fitter.direct_cost(prob_b, theta_b, use_basis=True, lw=False)
    nx_ = fitter.free_x.size
    # one noise scale for both (the wider model's χ², consistent under either hypothesis)
    s2 = max(1.0, 2 * cb / max(n_data - n_rf - theta_b.size, 1))
    va = np.linalg.pinv(fit.Jac.T @ fit.Jac)[:nx_, :nx_] * s2
    vb = np.linalg.pinv(Jac_b.T @ Jac_b)[:nx_, :nx_] * s2
    dx = theta_b[:nx_] - fit.theta[:nx_]
    lam_d, vec_d = np.linalg.eigh(vb - va)
    ok_d = lam_d > max(float(lam_d.max()), 0.0) * 1e-9
    if ok_d.any():
        hz = float(np.sum((vec_d[:, ok_d].T @ dx) ** 2 / lam_d[ok_d]))
        crit = chi2_ppf(0.999, int(ok_d.sum()))
    else:  # no precision lost to the residual terms: nothing to test against
        hz, crit = 0.0, float("inf")
    needed = bool(hz > crit)
    rf_info.update(
        {
            "test": "Hausman (properties with and without residual terms), p = 0.001",
            "statistic": hz,
            "critical_value": crit,
            "chi2_reduced_without": 2 * ca / max(n_data - fit.theta.size, 1),
            "chi2_reduced_with": 2 * cb / max(n_data - n_rf - theta_b.size, 1),
            "extra_parameters": int(n_rf),
            "needed": needed,
        }
    )
    model_form: FloatArray | None = None
    if rf_mode is True or needed:
        fit = Fit(prob_b, theta_b, Jac_b, it_b, refused_b)
        rf_info["fitted"] = True
        # which model is right the data cannot say beyond the test: the two fits' difference is
        # kept in the intervals as a model-form term (rank one, along dx). Without it the
        # residual terms on a rigid X-38 (realistic geometry, 2.5–50 Hz) moved the mass −0.13 %
        # and the CG 5 mm with intervals that missed the truth, verdict ok
        model_form = dx
        rf_info["model_form_difference"] = [float(v) for v in dx]
    if rf_info["fitted"]:
        d = fitter.data
        rf_info.update(residual_size(fit.prob, fit.theta, d.H, d.R, fitter.sigma, fitter.basis))
    return fit, rf_info, model_form


def covariance_step(
    fitter: Fitter,
    fit: Fit,
    chi2: float,
    model_form: FloatArray | None,
    stated_theta: FloatArray | None,
    geometry_test: dict[str, Any],
    use_basis: bool,
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray, dict[str, Any], FloatArray]:
    """The posterior of the fit: noise (scaled by χ²), input-robust factors, model-form terms.

    Returns ``(theta, cov_theta, cov_noise_theta, robust, adequacy, N)``: ``theta`` is the
    stated-geometry estimate when the geometry test kept it, its covariance widened by the
    difference to the refined fit; otherwise the refined one, checked for adequacy against the
    stated geometry taken as exact.
    """
    prob, theta, Jac = fit.prob, fit.theta, fit.Jac
    nx0 = fitter.free_x.size
    N = Jac.T @ Jac
    N_inv: FloatArray = np.asarray(np.linalg.pinv(N), float)
    cov_theta = N_inv * max(1.0, chi2)
    robust = input_robust_factors(prob, theta, Jac, cov_theta, nx0, N_inv)
    cov_theta[:nx0] *= robust[:, None]
    cov_theta[:, :nx0] *= robust[None, :]
    if model_form is not None:
        cov_theta[:nx0, :nx0] += np.outer(model_form, model_form)
    adequacy: dict[str, Any] = {"tested": False, "reason": "geometry not refined"}
    if stated_theta is not None:
        # the stated-geometry estimate, with the refined posterior widened by the difference
        # (rank one): both are consistent with the data (the geometry test), the truth lies
        # within the refined posterior, and the reported centre is the stated one
        dx_k = theta[:nx0] - stated_theta[:nx0]
        cov_theta[:nx0, :nx0] += np.outer(dx_k, dx_k)
        geometry_test["difference"] = [float(v) for v in -dx_k]
        theta = stated_theta
        adequacy = {"tested": False, "reason": "geometry kept as stated (geometry_test)"}
    elif prob.free_g.size and np.any(prob.free_g < prob.gain_base):
        # the same data and noise scale with the stated geometry taken as exact
        prob_s, _ = fitter.build(use_basis, np.zeros(0, np.intp))
        x0 = np.asarray(fitter.x_start[fitter.free_x], float)
        theta_s, _, _, _ = lm(prob_s, x0, fitter.opt.max_iterations)
        adequacy = adequacy_test(prob, theta, Jac, theta_s, max(1.0, chi2))
        if adequacy["tested"] and not adequacy["passed"]:
            # a refined answer never silently replaces a stated one that disagrees with it: the
            # difference stays in the intervals (rank one, as for the residual terms)
            dx_s = np.asarray(adequacy["difference"], float)
            cov_theta[:nx0, :nx0] += np.outer(dx_s, dx_s)
            adequacy["model_form_added"] = True
    cov_noise_theta: FloatArray = np.asarray(np.linalg.pinv(N[:nx0, :nx0]), float) * max(1.0, chi2)
    return theta, cov_theta, cov_noise_theta, robust, adequacy, N


def gauge_covariance(prob: Problem, x: FloatArray) -> tuple[FloatArray | None, dict[str, Any]]:
    """The fixed gauge modes' prior variance mapped to the properties (fit.py, "Gauge")."""
    if not (prob.gauge_rows.shape[0] and prob.gauge_modes.size):
        return None, {"fixed_modes": 0}
    Gw = prob.gauge_basis()[prob.free_g] / prob.sigma_g[prob.free_g][:, None]
    Gw = Gw[:, prob.gauge_live]
    V = prob.gauge_modes
    cov_a = np.linalg.inv(V.T @ Gw.T @ Gw @ V)
    Jg = gauge_property_jacobian(x)[:, prob.gauge_live] @ V  # (10, k)
    names = ["tx", "ty", "tz", "rx", "ry", "rz", "scale", "gain"]
    return Jg @ cov_a @ Jg.T, {
        "fixed_modes": int(V.shape[1]),
        "modes_live": [n for n, ok in zip(names, prob.gauge_live, strict=True) if ok],
        "data_to_prior_information": [float(v) for v in prob.gauge_information_ratio],
        "common_gain_fixed": bool(prob.gauge_live[7]),
    }


def gauge_text(fixed_modes: int) -> str:
    """How the report states the gauge (the frame the FRFs cannot see)."""
    if fixed_modes:
        return (
            f"inner constraint: {fixed_modes} modes of the similarity of all "
            "sensors, inputs and load cells and of the common accelerometer gain, which the FRFs "
            "do not identify (data information below the prior's), carry no correction in the "
            "prior's metric: frame, scale and gain of the stated geometry and certificates; "
            "their prior variance is in the intervals"
        )
    return (
        "frame of the stated geometry: the common rigid motion of all sensors and inputs, "
        "which the FRFs cannot see, is held by the priors at a precision-weighted mean "
        "correction of zero; its uncertainty is in the CG interval"
    )


def noise_report(
    fitter: Fitter,
    setup: TestSetup,
    chi2: float,
    variance_factor: float,
    robust: FloatArray,
    refinement_note: str,
) -> dict[str, Any]:
    """The noise model as the report states it."""
    d = fitter.data
    sig_rel = fitter.sigma / np.sqrt(d.h_mean_power)
    snr = d.reaction_snr
    noise: dict[str, Any] = {
        "method": "line-to-line scatter (third difference), per channel and input",
        "relative_median": float(np.median(sig_rel)),
        "relative_max": float(np.max(sig_rel)),
        "reaction_bias_compensated": bool(np.any(d.cov_R)),
        # load cells present: the share of lines × inputs whose reactions' power is within
        # REACTION_SNR_LOW of their noise (weighed by that noise in the fit, bias compensated,
        # not trusted as exact forces), and the median power / noise
        "reaction_lines_at_noise": (
            float(np.mean(~(snr > REACTION_SNR_LOW))) if setup.load_cells and snr.size else None
        ),
        "reaction_snr_median": (
            float(np.median(snr[np.isfinite(snr)]))
            if setup.load_cells and np.any(np.isfinite(snr))
            else None
        ),
        "chi2_reduced": float(chi2),
        "variance_factor": float(variance_factor),
        "chi2_reduced_stated_noise": float(chi2 * variance_factor),
        "input_robust_factor_max": float(robust.max(initial=1.0)),
    }
    if refinement_note:
        noise["refinement_refused"] = refinement_note
    return noise


def start_point(
    initial: DimResult, known: Mapping[str, float], p: FloatArray
) -> tuple[NDArray[np.intp], FloatArray, FloatArray]:
    """The free properties, the vector with the known ones set, and the start (relative to P)."""
    x0 = initial.parameters.copy()
    x0[1:4] -= p
    free_x = np.array([i for i, k in enumerate(PARAMETERS) if k not in known], dtype=np.intp)
    x_fixed = x0.copy()
    for name, v in known.items():
        i = PARAMETERS.index(name)
        x_fixed[i] = v - p[i - 1] if 1 <= i <= 3 else v
    x_start = x_fixed.copy()
    x_start[free_x] = x0[free_x]
    if not np.all(np.linalg.eigvalsh(mass_matrix(x_start)[0]) > 0):
        raise SolverError(
            "the equation-error start is not a physical mass matrix (not positive definite); the "
            "output-error fit needs a plausible start: check the band and the data selection"
        )
    return free_x, x_fixed, x_start


def make_fitter(
    frf: FrfData,
    setup: TestSetup,
    data: BandData,
    g: StatedGeometry,
    opt: OutputErrorOptions,
    initial: DimResult,
    known: Mapping[str, float],
) -> Fitter:
    """The fitter of one solve: the items it may refine, the start, the residual terms' basis
    ``[ω̂², ω̂⁴]`` (``ω̂ = ω/ω_max``) and the line weights from the measured noise and the load
    cells' certificate (the a posteriori variance factor scales the whole noise model, not the
    lines' relative weights)."""
    nn = g.nodes.size
    cand = np.nonzero(g.sig_g > 0)[0] if opt.refine_geometry else np.zeros(0, np.intp)
    if opt.refine_geometry and not opt.refine_positions:
        cand = cand[~np.isin(cand % 6, (3, 4, 5)) | (cand >= 6 * nn)]
    free_x, x_fixed, x_start = start_point(initial, known, setup.reference_point)
    w_hi = 2 * np.pi * float(frf.frequencies_hz[-1])
    wn = 2 * np.pi * frf.frequencies_hz / w_hi
    basis = np.stack([wn**2, wn**4], axis=1).astype(complex)
    eps_r = setup.transducer_uncertainty.loadcell_matrix_rel if setup.load_cells else 0.0
    psi0 = np.concatenate([g.d0, cross3(g.r0, g.d0)], axis=1)
    phi0 = np.concatenate([g.din0, cross3(g.rin0, g.din0)], axis=1)
    A0 = np.asarray(np.linalg.inv(mass_matrix(x_start)[0]), dtype=np.float64)  # typed for mypy
    lw0 = line_weights(
        data.H, data.R_at_p, psi0, phi0, A0, eps_r, h_power=data.h_power, d3_power=data.d3_power
    )
    data.h_power = data.d3_power = None
    return Fitter(data, g, opt, free_x, x_fixed, x_start, cand, basis, lw0)


def properties_posterior(
    prob: Problem,
    theta: FloatArray,
    cov_theta: FloatArray,
    cov_noise_theta: FloatArray,
    free_x: NDArray[np.intp],
    setup: TestSetup,
) -> tuple[FloatArray, FloatArray, FloatArray, dict[str, Any]]:
    """The ten properties (GCS) with their covariance: the fit's, the fixed gauge modes' prior
    variance and the registration's; and the covariance of the noise alone.

    Raises :class:`SolverError` when the fit ended on a mass matrix that is not positive
    definite.
    """
    x = prob.full_x(theta)
    if not np.all(np.linalg.eigvalsh(mass_matrix(x)[0]) > 0):
        raise SolverError(
            "the output-error fit ended on a mass matrix that is not positive definite; the data "
            "do not support it: check the band, the selection and the stated geometry"
        )
    cov = np.zeros((10, 10))
    cov_noise = np.zeros((10, 10))
    nx = free_x.size
    cov[np.ix_(free_x, free_x)] = cov_theta[:nx, :nx]
    cov_noise[np.ix_(free_x, free_x)] = cov_noise_theta
    cov_gauge, gauge_info = gauge_covariance(prob, x)
    if cov_gauge is not None:
        cov[np.ix_(free_x, free_x)] += cov_gauge[np.ix_(free_x, free_x)]
    gu = setup.geometry_uncertainty
    if gu.registration_rms_m:
        for i in (1, 2, 3):
            if i in free_x:
                cov[i, i] += gu.registration_rms_m**2
    params = x.copy()
    params[1:4] += setup.reference_point
    return params, cov, cov_noise, gauge_info
