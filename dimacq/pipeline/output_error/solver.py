"""The output-error solve: :func:`solve_output_error` composes the model, the noise, the fit, the
checks and the report of this package (:mod:`dimacq.pipeline.output_error`; the equations are in
its modules' docstrings).

The flow: the noise and the reactions' compensation (:mod:`.noise`), the equation-error start
(:func:`dimacq.pipeline.dim.solve_system`), the fit with the refusal of unidentified items, the
a posteriori variance factor and the gross-error rule (:mod:`.fit`), the geometry test and the
residual-flexibility (Hausman) test (:mod:`.checks`), the covariance (noise, input-robust
factors, model-form terms, the fixed gauge modes' prior variance, registration) and the report
(:mod:`.report`). Each is a named step here: :func:`band_data`, :func:`stated_geometry`,
:func:`make_fitter` (:class:`Fitter`), :func:`_gross_error_step`, :func:`geometry_test_step`,
:func:`residual_flexibility_step`, :func:`covariance_step`, :func:`properties_posterior` and
:func:`noise_report`.

Identifiability
---------------
A geometry parameter whose posterior standard deviation (at the start, all others marginalised) is
above ``refuse_ratio`` of its prior is not identified by the data: it is left at the stated value
(not estimated) and reported with that reason. The posterior covariance of the properties is the
inverse of the Gauss–Newton information (data and priors) at the solution (Laplace approximation).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Mapping
from dataclasses import replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from dimacq.errors import SetupError, SolverError
from dimacq.model.frf import FrfData
from dimacq.model.setup import TestSetup
from dimacq.pipeline.dim import DimResult, assemble, solve_system
from dimacq.pipeline.output_error.report import (
    OutputErrorOptions,
    OutputErrorResult,
    corrections,
    refined_setup,
)
from dimacq.pipeline.output_error.stages import (
    Fit,
    Fitter,
    band_data,
    covariance_step,
    gauge_text,
    geometry_test_step,
    make_fitter,
    noise_report,
    properties_posterior,
    residual_flexibility_step,
    stated_geometry,
)
from dimacq.pipeline.selection._common import response_geometry

#: the logger of the module before the split into a package: the messages keep its name
log = logging.getLogger("dimacq.pipeline.output_error")

FloatArray = NDArray[np.float64]
ComplexArray = NDArray[np.complex128]


def _gross_error_step(
    fitter: Fitter,
    fit: Fit,
    frf: FrfData,
    setup: TestSetup,
    call: dict[str, Any],
    geo: Any,
    in_idx: NDArray[np.intp],
    depth: int,
) -> tuple[Fit, float, str, OutputErrorResult | None]:
    """The a posteriori variance factor, then the gross-error rule.

    Returns the fit, the variance factor, the refusal note (empty when the refinement stands)
    and, when an item was left out (or the cells held) and the solve repeated with success, that
    solve's result, which the caller returns.
    """
    opt, g = fitter.opt, fitter.g
    n_data = 2 * fitter.data.H.shape[0] * fitter.data.H.shape[1] * len(in_idx)
    nn = g.nodes.size
    variance_factor = 1.0
    # a posteriori variance factor: misfit the noise does not explain (elastic modes, errors the
    # model lacks) must not be absorbed by the geometry at the noise's weight
    for _ in range(2):
        c2 = 2 * fitter.direct_cost(fit.prob, fit.theta) / max(n_data - fit.theta.size, 1)
        if c2 <= 1.5:
            break
        fitter.sigma = fitter.sigma * np.sqrt(c2)
        variance_factor *= c2
        prob, theta, Jac, _, it, refused = fitter.fit(False)
        fit = Fit(prob, theta, Jac, it, refused)
    nx = fitter.free_x.size
    z = float(np.max(np.abs(fit.theta[nx:]), initial=0.0))
    zfull = np.zeros(g.sig_g.size)
    zfull[fit.prob.free_g] = np.abs(fit.theta[nx:])
    worst = int(np.argmax(zfull))
    # a load cell cannot be left out of the balance (its reactions are forces on the body): one
    # far off is held at its stated pose and calibration instead (all cells), the refinement of
    # the rest solved again; noisy reactions at the band's top moved a bracket's cell 23 mm on
    # the shared sample (bracket_noisy_ascii), where the cells held exact give the old answer
    cell_worst = fit.prob.cell_base <= worst < fit.prob.gain_base
    if z > opt.max_correction_sigma and depth < opt.max_gross_items:
        if cell_worst:
            item = "load cells (held at their stated pose and calibration)"
            log.warning(
                "geometry refinement: load cell corrections up to %.1f σ of their stated "
                "uncertainty; the cells are held at their stated pose and calibration and the "
                "geometry solved again",
                z,
            )
            again = {**call, "options": replace(opt, refine_load_cells=False)}
            failed = "holding the load cells fails (%s); refinement refused instead"
            unsaved = "holding the load cells does not save the refinement"
        else:
            # one item far outside its stated uncertainty: a gross error the selection missed
            # (a bad impact, a mis-mounted sensor). Leave out the worst item and solve again.
            w2 = call["response_weights"].copy()
            k2 = np.asarray(call["input_keep"], bool).copy()
            if worst >= fit.prob.gain_base:  # a channel's gain: leave its sensor node out
                worst = 6 * int(g.node_of[worst - fit.prob.gain_base])
            if worst < 6 * nn:
                node = int(g.nodes[worst // 6])
                w2[geo.nodes == node] = 0.0
                item = f"sensor node {node}"
            else:
                jj = int(in_idx[(worst - 6 * nn) // 4])
                k2[jj] = False
                item = f"input {frf.inputs[jj].name}"
            log.warning(
                "geometry refinement: %s needs a correction of %.1f σ of its stated uncertainty; "
                "left out as a gross error and solved again",
                item,
                z,
            )
            again = {**call, "response_weights": w2, "input_keep": k2}
            failed = f"leaving out {item} fails (%s); refinement refused instead"
            # the refinement ends refused further down: the corrections that named this item are
            # not trusted either; keep every item and refuse here
            unsaved = f"leaving out {item} does not save the refinement; all items kept"
        try:
            sub = solve_output_error(frf, setup, **again, _depth=depth + 1)
        except (SolverError, SetupError) as err:
            log.warning(failed, err)
        else:
            if sub.refine_geometry:
                gross = {"item": item, "correction_sigma": z}
                return (
                    fit,
                    variance_factor,
                    "",
                    replace(sub, gross_errors=[gross, *sub.gross_errors]),
                )
            log.warning(unsaved)
    note = ""
    if z > opt.max_correction_sigma:
        note = (
            f"geometry refinement refused: corrections up to {z:.1f} σ of the stated "
            "uncertainty; the data disagree with the rigid-body model, not only with the "
            "stated geometry (check the band and the selection); stated geometry used"
        )
        log.warning(note)
        refused_all = [int(i) for i in fitter.cand]
        fitter.cand = np.zeros(0, np.intp)
        prob, theta, Jac, _cost, it, _ = fitter.fit(False)
        fit = Fit(prob, theta, Jac, it, refused_all)
    return fit, variance_factor, note, None


# ------------------------------------------------------------------------------------------
# Entry point
# ------------------------------------------------------------------------------------------
def solve_output_error(
    frf: FrfData,
    setup: TestSetup,
    *,
    response_weights: NDArray[np.floating] | None = None,
    input_keep: NDArray[np.bool_] | None = None,
    known: Mapping[str, float] | None = None,
    options: OutputErrorOptions | None = None,
    initial: DimResult | None = None,
    _depth: int = 0,
) -> OutputErrorResult:
    """Output-error DIM over the band of ``frf`` (:mod:`dimacq.pipeline.output_error`).

    An item (sensor node or input) whose refined correction exceeds ``max_correction_sigma`` of
    its stated uncertainty is a gross error: it is left out and the solve repeated (at most
    ``max_gross_items`` times; ``gross_errors`` of the result lists them); beyond that the
    refinement is refused and the stated geometry used. A load cell cannot be left out: when the
    worst item is a cell's, the cells are held at their stated pose and calibration
    (``refine_load_cells`` off) and the solve repeated.

    Parameters
    ----------
    frf : FrfData
        FRFs of the analysis band (accelerances and load-cell reactions).
    setup : TestSetup
        The stated geometry and its ``geometry_uncertainty`` (priors).
    response_weights : ndarray, shape (n_acceleration_outputs,), optional
        0 drops a channel (selection); any positive value keeps it (the noise sets the weight).
    input_keep : ndarray of bool, shape (n_inputs,), optional
    known : dict, optional
        Known properties (``m`` kg, ``cx..cz`` GCS m, ``Ixx..Izz`` about P kg·m²).
    options : OutputErrorOptions
    initial : DimResult, optional
        Equation-error solution on the same data to start from (solved here if absent).

    Raises
    ------
    SolverError
        The start is not a physical mass matrix, or the fit does not converge to one.
    """
    t0 = time.perf_counter()
    opt = options or OutputErrorOptions()
    known = dict(known or {})
    geo = response_geometry(frf, setup)
    n_acc = geo.output_index.size
    wts = np.ones(n_acc) if response_weights is None else np.asarray(response_weights, float)
    if wts.shape != (n_acc,):
        raise SetupError(f"response_weights must hold {n_acc} values, one per accelerometer")
    keep_in = np.ones(len(frf.inputs), bool) if input_keep is None else np.asarray(input_keep)
    active = wts > 0
    in_idx = np.nonzero(keep_in)[0]
    p = setup.reference_point
    system = assemble(frf, setup, length_unit="m", response_weights=wts).select_inputs(in_idx)
    if initial is None:
        initial = solve_system(system, known=known, check_plausibility=False)
    data = band_data(frf, setup, geo.output_index[active], in_idx)
    g = stated_geometry(frf, setup, geo, active, in_idx, data.cell_nodes, opt.refine_load_cells)
    J = len(in_idx)
    fitter = make_fitter(frf, setup, data, g, opt, initial, known)
    free_x = fitter.free_x
    n_data = 2 * data.H.shape[0] * data.H.shape[1] * J
    n_rf = 2 * data.H.shape[1] * J
    prob0, theta0, jac0, _cost0, it0, refused0 = fitter.fit(False)
    fit = Fit(prob0, theta0, jac0, it0, refused0)
    variance_factor, refinement_note = 1.0, ""
    if fitter.cand.size:
        call = {"response_weights": wts, "input_keep": keep_in, "known": known, "options": opt}
        fit, variance_factor, refinement_note, sub = _gross_error_step(
            fitter, fit, frf, setup, call, geo, in_idx, _depth
        )
        if sub is not None:
            return sub
    geometry_test, stated_theta, keep_note = geometry_test_step(fitter, fit)
    fit, rf_info, model_form = residual_flexibility_step(fitter, fit, n_data, n_rf)
    fitted_b = bool(rf_info["fitted"])
    dof = max(n_data - (fit.theta.size + (n_rf if fitted_b else 0)), 1)
    # complex residuals: E|e/σ|² = 1 per 2 real data
    chi2 = 2.0 * fitter.direct_cost(fit.prob, fit.theta, use_basis=fitted_b) / dof
    theta, cov_theta, cov_noise_theta, robust, adequacy, _N = covariance_step(
        fitter, fit, chi2, model_form, stated_theta, geometry_test, fitted_b
    )
    prob = fit.prob
    params, cov, cov_noise, gauge_info = properties_posterior(
        prob, theta, cov_theta, cov_noise_theta, free_x, setup
    )
    nx = free_x.size
    gvec = prob.full_g(theta)
    se_g = np.zeros(g.sig_g.size)
    se_g[prob.free_g] = np.sqrt(np.clip(np.diag(cov_theta)[nx:], 0, None)) * g.sig_g[prob.free_g]
    sens, inps, cell_corr = corrections(
        gvec, se_g, g.sig_g, prob, fit.refused, frf.inputs, in_idx, opt.refine_geometry,
        refinement_note or keep_note, data.cell_nodes,
    )  # fmt: skip
    new_setup = refined_setup(setup, geo, active, prob, gvec, frf.inputs, in_idx, p,
                               data.cell_nodes)  # fmt: skip
    return OutputErrorResult(
        parameters=params,
        covariance=cov,
        covariance_noise=cov_noise,
        chi2_reduced=float(chi2),
        iterations=int(fit.it),
        elapsed_s=time.perf_counter() - t0,
        sensor_corrections=sens,
        input_corrections=inps,
        load_cell_corrections=cell_corr,
        residual_flexibility=rf_info,
        noise=noise_report(fitter, setup, chi2, variance_factor, robust, refinement_note),
        gauge=gauge_text(gauge_info["fixed_modes"]),
        setup=new_setup,
        refine_geometry=opt.refine_geometry and not refinement_note,
        n_inputs=J,
        response_weights=wts,
        input_keep=np.asarray(keep_in, bool),
        extras={"gauge": gauge_info, "adequacy": adequacy, "geometry_test": geometry_test},
    )
