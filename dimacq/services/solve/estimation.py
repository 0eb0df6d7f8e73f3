"""The estimator step of the analysis: output-error DIM with geometry self-calibration.

:func:`output_error_step` runs :func:`dimacq.pipeline.output_error.solve_output_error` on the data
the selection kept, starting from the equation-error solution, and — when it is usable — makes its
estimate the headline and its posterior the 95 % intervals (``uncertainty.<p>.ci95``). It is not
used (the equation-error result stays, with the reason in ``output_error``) when the fit fails or
when, with the stated geometry taken as exact, the misfit is far above the noise: the fit would
then shrink its predictions (mass biased high). That misfit is measured against the FRFs' own
noise, also when a refinement asked for was refused: the fit left on the stated geometry then
carries the refined fit's a posteriori variance factor, and its reduced χ² near 1 would hide a
misfit of 10⁴–10⁵ (an acquired chain check through the USB-1808X: 49.54 kg for a 48.38 kg block,
used, where the equation-error gives 48.38 kg). Items the refinement finds far outside their
stated uncertainty (gross errors the selection missed) are left out by the fit and listed in
``output_error.gross_errors`` and ``excluded_by_refinement``.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from dataclasses import replace
from typing import Any

import numpy as np

from dimacq.errors import SetupError, SolverError
from dimacq.model.frf import FrfData
from dimacq.model.setup import PARAMETERS, TestSetup
from dimacq.pipeline._special import t_ppf
from dimacq.pipeline.dim import DimResult
from dimacq.pipeline.output_error import (
    OutputErrorOptions,
    OutputErrorResult,
    solve_output_error,
)
from dimacq.pipeline.uncertainty import Uncertainty

__all__ = ["OE_MAX_CHI2_UNREFINED", "output_error_step"]

log = logging.getLogger(__name__)

#: Reduced χ² above which an output-error fit on the unrefined stated geometry is not used.
OE_MAX_CHI2_UNREFINED = 3.0


def output_error_step(
    data: FrfData,
    setup: TestSetup,
    result: DimResult,
    unc: Uncertainty,
    weights: np.ndarray,
    keep_in: np.ndarray,
    known: Mapping[str, float],
    opt: Any,
    hull: np.ndarray,
) -> tuple[DimResult, Uncertainty]:
    """The output-error estimate and its intervals, or the inputs unchanged with the reason.

    ``opt`` is the :class:`~dimacq.services.solve.analysis.AnalysisOptions` (``refine_geometry``,
    ``residual_flexibility``).
    """
    try:
        oe = solve_output_error(
            data,
            setup,
            response_weights=weights,
            input_keep=keep_in,
            known=known,
            initial=result,
            options=OutputErrorOptions(
                refine_geometry=opt.refine_geometry,
                residual_flexibility=opt.residual_flexibility,
            ),
        )
    except (SolverError, SetupError) as err:
        log.warning("output-error estimate not used (%s); equation-error result kept", err)
        return _note(result, "output_error", {"used": False, "reason": str(err)}), unc
    # against the measured noise: a refinement that was asked for and refused leaves a fit on
    # the stated geometry whose noise was scaled up by the refined fit's a posteriori variance
    # factor (its χ² near 1 says nothing of the stated geometry); that fit is as biased as one
    # never refined, and is judged the same way
    chi2_stated = float(oe.noise.get("chi2_reduced_stated_noise", oe.chi2_reduced))
    if not oe.refine_geometry and chi2_stated > OE_MAX_CHI2_UNREFINED:
        refused = oe.noise.get("refinement_refused")
        reason = (
            f"reduced χ² {chi2_stated:.3g} with the stated geometry against the measured noise "
            f"(limit {OE_MAX_CHI2_UNREFINED:g}): the geometry, not the noise, dominates the "
            "misfit; "
            + (
                f"the refinement that would absorb it was refused ({refused})"
                if refused
                else "refine the geometry (--refine-geometry)"
            )
        )
        log.warning("output-error estimate not used: %s", reason)
        note: dict[str, Any] = {"used": False, "reason": reason}
        if refused:
            note["refinement_refused"] = refused  # the verdict's estimator:refinement warn
        return _note(result, "output_error", note), unc
    result, unc = _apply_output_error(result, oe, unc, hull, setup)
    if oe.gross_errors:
        assert oe.input_keep is not None and oe.response_weights is not None
        chans = [c for c in result.responses]
        gone_in = [data.inputs[j] for j in np.nonzero(np.asarray(keep_in) & ~oe.input_keep)[0]]
        result = _note(
            result,
            "excluded_by_refinement",
            {
                "inputs": [c.as_dict() for c in gone_in],
                "response_nodes": sorted(
                    {int(c.node) for c in chans}
                    - {int(n) for n in _kept_nodes(data, setup, oe.response_weights)}
                ),
            },
        )
    return result, unc


def _kept_nodes(data: FrfData, setup: TestSetup, w: np.ndarray) -> set[int]:
    from dimacq.pipeline.selection._common import response_geometry

    geo = response_geometry(data, setup)
    return {int(n) for n in geo.nodes[np.asarray(w) > 0]}


def _note(result: DimResult, key: str, value: Any) -> DimResult:
    return replace(result, extras={**result.extras, key: value})


def _principal_from_covariance(
    p: np.ndarray, cov: np.ndarray, ref: np.ndarray, tq: float, se_noise: np.ndarray
) -> tuple[Any, ...]:
    """Principal moments about the CG with standard errors ``sqrt(diag(J C Jᵀ))``, ``J`` the
    Jacobian of :func:`~dimacq.pipeline.uncertainty.principal_of_parameters` (central
    differences); the noise share from the noise-only covariance's diagonal the same way."""
    from dimacq.pipeline.uncertainty import ParameterUncertainty, principal_of_parameters

    w0 = principal_of_parameters(p, ref)
    h = 1e-6 * np.maximum(np.abs(p), 1e-3)
    Jp = np.empty((3, 10))
    for i in range(10):
        e = np.zeros(10)
        e[i] = h[i]
        Jp[:, i] = (principal_of_parameters(p + e, ref) - principal_of_parameters(p - e, ref)) / (
            2 * h[i]
        )
    se = np.sqrt(np.clip(np.diag(Jp @ cov @ Jp.T), 0.0, None))
    se_n = np.minimum(np.sqrt(np.clip((Jp**2) @ se_noise**2, 0.0, None)), se)
    return tuple(
        ParameterUncertainty(
            float(w0[k]),
            float(se[k]),
            (float(w0[k] - tq * se[k]), float(w0[k] + tq * se[k])),
            se_inputs=float(se_n[k]),
            se_lines=0.0,
            se_responses=0.0,
            se_geometry=float(np.sqrt(max(se[k] ** 2 - se_n[k] ** 2, 0.0))),
        )
        for k in range(3)
    )


def _apply_output_error(
    result: DimResult,
    oe: OutputErrorResult,
    unc: Uncertainty,
    hull: np.ndarray,
    setup: TestSetup,
) -> tuple[DimResult, Uncertainty]:
    """Headline = the output-error estimate, with its own 95 % intervals.

    The posterior covariance of the output-error fit carries the noise of every line, channel and
    input and — with the geometry refined — the stated geometry uncertainty (the priors, gauge
    included) and the registration residual. Without refinement the geometry share propagated by
    Monte Carlo (``se_geometry`` of ``unc``) is added in quadrature. ``se_inputs`` holds the noise
    share (every line, channel and input; geometry held), ``se_geometry`` the rest. Student t with
    N − 1 inputs, as for the jackknife.
    """
    from dimacq.model.properties import RigidBodyProperties, vector_to_inertia
    from dimacq.pipeline.dim import plausibility
    from dimacq.pipeline.uncertainty import ParameterUncertainty

    p = oe.parameters
    props = RigidBodyProperties.from_about_point(
        float(p[0]), p[1:4], vector_to_inertia(p[4:]), result.reference_point_m
    )
    se_post = oe.standard_errors
    se_noise = np.minimum(np.sqrt(np.clip(np.diag(oe.covariance_noise), 0.0, None)), se_post)
    se_geo = np.array([unc.parameters[k].se_geometry for k in PARAMETERS])
    comps: tuple[str, ...]
    if oe.refine_geometry:
        # the geometry is in the posterior already; the transducer calibration is not: a force
        # (hammer) sensitivity error η scales every FRF, hence m and I, by 1/(1+η) exactly (the
        # CG not at all); the accelerometer axes' independent errors act through their mean
        # over the n_ch channels kept (σ_a/√n_ch) the same way
        tu = setup.transducer_uncertainty
        # (the common gain is in the posterior already when the fit fixed it as a gauge mode)
        gain_in_post = bool(oe.extras.get("gauge", {}).get("common_gain_fixed"))
        rel = np.hypot(
            tu.force_sensitivity_rel,
            0.0
            if gain_in_post
            else tu.accel_sensitivity_rel / np.sqrt(max(len(result.responses), 1)),
        )
        se_geo = np.zeros(10)
        se_geo[[0, *range(4, 10)]] = rel * np.abs(oe.parameters[[0, *range(4, 10)]])
        comps = ("inputs", "responses", "geometry", "lines")
    else:  # stated geometry: its Monte Carlo share and the sensor jackknife, as the jackknife had
        comps = tuple(unc.components)
        se_geo = np.hypot(se_geo, [unc.parameters[k].se_responses for k in PARAMETERS])
    se = np.sqrt(se_post**2 + se_geo**2)
    for k in result.known:
        se[PARAMETERS.index(k)] = 0.0
    tq = t_ppf(0.975, max(oe.n_inputs - 1, 1))  # stats.t.ppf to ~1e-14, without scipy
    # the principal moments from the same covariance (first order): the posterior, plus the
    # transducer share as the common scale of m and I it is (refined) or the Monte Carlo and
    # sensor-jackknife shares (unrefined, diagonal as they were added above)
    cov = np.array(oe.covariance, float)
    if oe.refine_geometry:
        v = p.copy()
        v[1:4] = 0.0
        cov = cov + np.outer(se_geo, se_geo) * np.outer(np.sign(v), np.sign(v))
    else:
        cov = cov + np.diag(se_geo**2)
    for k in result.known:
        i = PARAMETERS.index(k)
        cov[i, :] = cov[:, i] = 0.0
    principal = _principal_from_covariance(p, cov, result.reference_point_m, tq, se_noise)
    params = {
        name: ParameterUncertainty(
            float(p[i]),
            float(se[i]),
            (float(p[i] - tq * se[i]), float(p[i] + tq * se[i])),
            se_inputs=float(se_noise[i]),
            se_lines=0.0,
            se_responses=0.0,
            se_geometry=float(np.sqrt(max(se[i] ** 2 - se_noise[i] ** 2, 0.0))),
        )
        for i, name in enumerate(PARAMETERS)
    }
    unc_oe = replace(
        unc,
        parameters=params,
        principal=principal,
        method="output-error posterior"
        + (" (geometry refined)" if oe.refine_geometry else " + geometry Monte Carlo"),
        components=comps,
    )
    out = replace(
        result,
        properties=props,
        parameters=p.copy(),
        extras={
            **result.extras,
            "output_error": {"used": True, **oe.to_json()},
            "equation_error_parameters": {
                k: float(v) for k, v in zip(PARAMETERS, result.parameters, strict=True)
            },
        },
    )
    out = replace(out, diagnostics=plausibility(props, hull, out))
    return out, unc_oe
