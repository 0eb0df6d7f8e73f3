"""Analysis service: band → response selection → orientation repair → input selection → solve →
uncertainty → figures, with every decision recorded in the report.

Used by every ``dimacq solve`` and by the REST API (``POST /api/solutions``). The defaults are the
best method: automatic band, response and input selection, 95 % intervals with every source of
uncertainty (inputs, sensors, lines, the stated geometry uncertainty), and one verdict
(``ok`` / ``warn`` / ``fail`` with its reasons). Options turn each off. Pure orchestration over
:mod:`dimacq.pipeline` (no devices, no threads); the only I/O is writing figures when asked.
Steps 1–4 and the second band suggestion are in :mod:`dimacq.services.solve.selection_steps`.

Order of the steps and why
--------------------------
1. Band: given (``band_hz`` overrides), automatic (default,
   :func:`~dimacq.pipeline.selection.band.suggest_band`), or the whole span (``auto_band=False``).
   An automatic band is suggested again after the selections (step 5) on the selected data, and
   the solve uses that second suggestion.
2. Perimeter response selection on the band (gross channel errors first, so that they do not
   corrupt the orientation fit of their node).
3. Orientation repair of the kept channels (only when asked; the setup given to the solver then
   carries the corrected directions and the report says so).
4. Jackknife excitation selection on the assembled system of the kept channels.
5. Joint DIM solve, uncertainty from the input jackknife, a delete-one-sensor-node jackknife,
   the line spread and the stated geometry uncertainty (Monte Carlo through the joint solve).
6. Verdict (:func:`verdict`): ``fail`` when the answer cannot be trusted (no qualifying band, a
   non-physical estimate, a residual above its limit, a DOF not excited, a registration above its
   limit), ``warn`` when it stands with a caveat, else ``ok``; every check with its reason.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from dimacq.errors import SetupError
from dimacq.model.frf import FrfData
from dimacq.model.setup import PARAMETERS, TestSetup
from dimacq.pipeline.chain_calibration import ChainCalibration, chain_calibration
from dimacq.pipeline.dim import DimResult, DimSystem, assemble, solve_system
from dimacq.pipeline.selection._common import match_pairs, response_geometry
from dimacq.pipeline.selection.band import MAX_RIGID_BODY_ERROR, BandSuggestion
from dimacq.pipeline.selection.inputs import ExcitationCheck, JackknifeSelection, excitation_check
from dimacq.pipeline.selection.orientation import OrientationRepair
from dimacq.pipeline.selection.responses import ResponseSelection
from dimacq.pipeline.uncertainty import (
    GeometrySpread,
    Uncertainty,
)
from dimacq.services.solve.cross_check import CrossCheck, cross_check
from dimacq.services.solve.estimation import output_error_step
from dimacq.services.solve.modal_correction import (
    ModalCorrection,
    RigidBodyScreen,
    analyse_with_modal,
)
from dimacq.services.solve.selection_steps import (
    first_band,
    repaired_orientation,
    second_suggestion,
    selected_inputs,
    selected_responses,
)
from dimacq.services.solve.uncertainty_steps import geometry_step, uncertainty_step
from dimacq.services.solve.verdict import (
    CI95_LIMIT_MASS,
    CI95_LIMIT_PRINCIPAL,
    PRECISION_FAIL_FACTOR,
    RESIDUAL_FAIL,
    RESIDUAL_WARN,
    VerdictReason,
    band_quality,
    rigid_body_checks,
    verdict,
)

__all__ = [
    "CI95_LIMIT_MASS",
    "CI95_LIMIT_PRINCIPAL",
    "PRECISION_FAIL_FACTOR",
    "RESIDUAL_FAIL",
    "RESIDUAL_WARN",
    "AnalysisOptions",
    "AnalysisReport",
    "VerdictReason",
    "analyse",
    "verdict",
]


log = logging.getLogger(__name__)


@dataclass(frozen=True)
class AnalysisOptions:
    """What :func:`analyse` should do.

    Attributes
    ----------
    select_responses : bool
        Automatic perimeter response selection (default on).
    select_inputs : bool
        Jackknife excitation selection (default on).
    repair_orientation : bool
        Estimate one small rotation per sensor node and apply it to the setup.
    auto_band : bool
        Choose the band automatically (default on; ``band_hz`` overrides it).
    plots_dir : Path, optional
        Write the figures (PNG and SVG) there.
    band_hz : (lo, hi), optional
        Analysis band given by the user (overrides ``auto_band``); with ``auto_band`` off and no
        band, the whole span.
    geometry_samples : int
        Monte Carlo samples of the geometry propagation (0 turns it off; the intervals then leave
        out the geometry uncertainty and the verdict says so).
    known : dict, optional
        Known properties (``m``, ``cx``.., ``Ixx``..); default ``setup.known``.
    length_unit : {"m", "cm", "mm"}, optional
        Default ``setup.length_unit``.
    force_in, force_out : list of (node, direction)
        Channels or inputs the user keeps / drops whatever the selection says. A pair applies to
        the response channel and to the input it names (either sign of the direction).
    uncertainty_method : {"jackknife", "bootstrap"}
    method : {"joint", "mean"}
        Headline answer of the solve (intervals are those of the joint solve).
    unbiased : bool
        Output-error (maximum-likelihood) estimate with the FRF noise estimated from the data
        (:mod:`dimacq.pipeline.output_error`): no errors-in-variables bias. Default on; without
        ``refine_geometry`` it is used only where the stated geometry explains the data
        (reduced χ² ≤ 3), else the equation-error result stays, with the reason.
    refine_geometry : bool
        Estimate sensor rotations/offsets, input lines of action and channel gains with the
        properties (priors from ``setup.geometry_uncertainty`` and
        ``setup.transducer_uncertainty``; the gauge modes the data do not identify fixed, their
        prior variance in the intervals). Default on (README, Accuracy: never worse than the
        selection alone on the realistic cases); implies the output-error estimate.
    residual_flexibility : bool
        Fit residual terms of elastic modes above the band (and test whether they were needed).
    ci95_limit_mass, ci95_limit_principal : float
        Largest useful relative half-width of the 95 % interval of the mass and of the principal
        moments (default 0.02 and 0.05); wider gives a ``warn`` verdict (``precision``),
        :data:`PRECISION_FAIL_FACTOR` times wider a ``fail``.
    reference_mass : (mass_kg, u_kg), optional
        The data were measured on a reference body of this weighed mass (standard uncertainty
        ``u_kg``): the report carries the chain calibration ``γ`` it gives
        (:mod:`dimacq.pipeline.chain_calibration`); the hammer certificate term is left out of
        that solve's intervals (it is what is being calibrated).
    chain : ChainCalibration, optional
        A chain calibration to apply: the FRFs are multiplied by ``chain.factor`` and the hammer
        certificate's uncertainty is replaced by ``chain.u_rel``.
    cross_check : bool
        Run the second, independent estimator (the mass-line fit,
        :mod:`dimacq.services.solve.cross_check`) on the DIM's data and compare (default on).
    modal_correction : {"auto", "on", "off"}
        Take the elastic modes identified from the FRFs out of them and solve on the corrected
        FRFs (:mod:`dimacq.services.solve.modal_correction`): ``auto`` (default) only when the plain
        analysis shows elastic contamination, and says so.
    """

    select_responses: bool = True
    select_inputs: bool = True
    repair_orientation: bool = False
    auto_band: bool = True
    plots_dir: Path | None = None
    band_hz: tuple[float, float] | None = None
    known: Mapping[str, float] | None = None
    length_unit: str | None = None
    force_in: Sequence[tuple[int, int]] = ()
    force_out: Sequence[tuple[int, int]] = ()
    uncertainty_method: str = "jackknife"
    geometry_samples: int = 400
    method: str = "joint"
    unbiased: bool = True
    refine_geometry: bool = True
    residual_flexibility: bool = False
    ci95_limit_mass: float = CI95_LIMIT_MASS
    ci95_limit_principal: float = CI95_LIMIT_PRINCIPAL
    reference_mass: tuple[float, float] | None = None
    chain: ChainCalibration | None = None
    cross_check: bool = True
    modal_correction: str = "auto"


@dataclass(frozen=True, eq=False)
class AnalysisReport:
    """The solution with the evidence of every selection step.

    Attributes
    ----------
    result : DimResult
    excluded_responses, excluded_inputs : list of {"node": N, "direction": D}
        D as in UFF (±1..±6), as the FRF records name them.
    uncertainty : Uncertainty
    orientation_corrections : list of dict
        Per sensor node: ``node``, ``angle_deg``, ``rotation_vector_deg``, errors, ``applied``
        (empty when the repair was not asked for).
    band_selection : dict
        ``band_hz``, ``reason``, ``automatic``.
    plots : list of Path
    excitation : ExcitationCheck
        Eq. 16 check of the inputs used.
    response_selection, input_selection, band_suggestion, orientation : optional details
    setup_used : TestSetup
        The setup given to the solver (with repaired directions if applied).
    verdict : {"ok", "warn", "fail"}
    verdict_reasons : list of VerdictReason
        Every check, whatever its outcome (the failing and warning ones first).
    geometry : GeometrySpread, optional
    chain_calibration : dict, optional
        ``{"role": "measured" | "applied", **ChainCalibration.to_json()}``: the chain factor this
        solve measured on a reference mass, or the one it applied.
    cross_check : CrossCheck, optional
        The mass-line estimate on the same data and its agreement with the DIM.
    """

    result: DimResult
    excluded_responses: list[dict[str, int]]
    excluded_inputs: list[dict[str, int]]
    uncertainty: Uncertainty
    orientation_corrections: list[dict[str, Any]]
    band_selection: dict[str, Any]
    excitation: ExcitationCheck
    setup_used: TestSetup
    plots: list[Path] = field(default_factory=list)
    response_selection: ResponseSelection | None = None
    input_selection: JackknifeSelection | None = None
    band_suggestion: BandSuggestion | None = None
    orientation: OrientationRepair | None = None
    verdict: str = "ok"
    verdict_reasons: list[VerdictReason] = field(default_factory=list)
    geometry: GeometrySpread | None = None
    chain_calibration: dict[str, Any] | None = None
    cross_check: CrossCheck | None = None
    modal_correction: ModalCorrection | None = None
    weights_used: np.ndarray | None = None
    inputs_kept: np.ndarray | None = None

    def to_json(self) -> dict[str, Any]:
        """``result.to_json()`` plus ``excluded_responses``, ``excluded_inputs``, ``uncertainty``,
        ``orientation_corrections``, ``band_selection`` and the selection details."""
        out = self.result.to_json()
        out.update(
            {
                "excluded_responses": list(self.excluded_responses),
                "excluded_inputs": list(self.excluded_inputs),
                "uncertainty": self.uncertainty.to_json(),
                "orientation_corrections": list(self.orientation_corrections),
                "band_selection": dict(self.band_selection),
                "excitation_check": self.excitation.to_json(),
                "plots": [str(p) for p in self.plots],
                "verdict": self.verdict,
                "verdict_reasons": [r.to_json() for r in self.verdict_reasons],
                "geometry_uncertainty": self.setup_used.geometry_uncertainty.model_dump(),
                "transducer_uncertainty": self.setup_used.transducer_uncertainty.model_dump(),
            }
        )
        if self.geometry is not None:
            out["uncertainty"]["geometry_check"] = {
                "n_samples": self.geometry.n_samples,
                "se_monte_carlo": dict(zip(PARAMETERS, self.geometry.se.tolist(), strict=True)),
                "se_linearised": dict(
                    zip(PARAMETERS, self.geometry.se_linear.tolist(), strict=True)
                ),
            }
        if self.chain_calibration is not None:
            out["chain_calibration"] = dict(self.chain_calibration)
        if self.cross_check is not None:
            out["cross_check"] = self.cross_check.to_json()
        if self.modal_correction is not None:
            out["modal_correction"] = self.modal_correction.to_json()
        if self.response_selection is not None:
            out["response_selection"] = self.response_selection.to_json()
        if self.input_selection is not None:
            out["input_selection"] = self.input_selection.to_json()
        return out


def analyse(
    frf: FrfData, setup: TestSetup, options: AnalysisOptions | None = None
) -> AnalysisReport:
    """Run selection → solve → uncertainty → figures (module docstring), on the FRFs as
    measured or, when they show elastic contamination (``options.modal_correction``), on the
    FRFs with the elastic modes taken out (:mod:`dimacq.services.solve.modal_correction`).

    Raises
    ------
    SetupError, DataError
        Bad setup, options or data (messages name the item and the fix).
    SolverError
        The kept data cannot be solved (rank < 6 ...).
    """
    opt = options or AnalysisOptions()
    return analyse_with_modal(frf, setup, opt, _Plain, lambda f, st: _with_chain(f, st, opt))


@dataclass(frozen=True, eq=False)
class _Stage:
    """The analysis up to the equation-error answer and its intervals (steps 1–5 of the module
    docstring before the output-error estimate): what the remaining steps read.

    ``frf`` and ``setup`` carry the chain calibration when one is applied; ``data`` is ``frf`` on
    the band; ``weights`` (per accelerometer channel) and ``keep_in`` (per input) are the
    selections; ``result`` and ``unc`` the equation-error solve and its intervals.
    """

    frf: FrfData
    setup: TestSetup
    opt: AnalysisOptions
    known: dict[str, float]
    auto: bool
    data: FrfData
    setup_used: TestSetup
    weights: np.ndarray
    keep_in: np.ndarray
    band_sel: dict[str, Any]
    suggestion: BandSuggestion | None
    rsel: ResponseSelection | None
    jsel: JackknifeSelection | None
    repair: OrientationRepair | None
    excluded_resp: list[dict[str, int]]
    excluded_in: list[dict[str, int]]
    system_used: DimSystem
    result: DimResult
    unc: Uncertainty
    geo: GeometrySpread | None


class _Plain:
    """The analysis of one FRF set as given, in two stages.

    Made, it holds the selections, the band and the equation-error solve with its intervals
    (:func:`_stage`); :meth:`screen` gives the rigid-body checks the modal correction's ``auto``
    mode reads of it (they do not depend on the output-error estimate); :meth:`report` runs the
    output-error estimate, the cross-check and the verdict on first asking (the same report as
    one run straight through) and writes the figures when the options ask for them.
    """

    def __init__(self, frf: FrfData, setup: TestSetup, opt: AnalysisOptions) -> None:
        self.stage = _stage(frf, setup, opt)
        self._report: AnalysisReport | None = None

    def screen(self) -> RigidBodyScreen:
        """The band suggestion, the verdict's band and residual checks, the band and the
        exclusions of the equation-error stage."""
        st = self.stage
        pre = _stage_report(st, st.result, st.unc, None)
        checks = rigid_body_checks(pre, st.data, st.suggestion if st.auto else None)
        return RigidBodyScreen(
            band_suggestion=st.suggestion,
            verdict_reasons=checks,
            band_hz=tuple(st.result.band_hz),
            excluded_responses=st.excluded_resp,
            excluded_inputs=st.excluded_in,
        )

    def report(self, figures: bool = True) -> AnalysisReport:
        """The full report (figures written when ``figures`` and the options give a folder)."""
        if self._report is None:
            self._report = _finished(self.stage)
        st = self.stage
        if not figures or st.opt.plots_dir is None:
            return self._report
        return _with_figures(
            self._report, st.frf, st.setup_used, Path(st.opt.plots_dir), st.weights, st.keep_in
        )


def _stage(frf: FrfData, setup: TestSetup, opt: AnalysisOptions) -> _Stage:
    """Steps 1–5 of the module docstring up to the equation-error solve and its intervals."""
    frf, setup = _with_chain(frf, setup, opt)
    known = dict(setup.known.as_dict() if opt.known is None else opt.known)
    force_in, force_out = _forced_pairs(opt)
    geo_all = response_geometry(frf, setup)
    w0 = (~match_pairs(force_out, geo_all.channels)).astype(float)  # type: ignore[arg-type]
    in_out = match_pairs(force_out, frf.inputs)  # type: ignore[arg-type]
    in_in = match_pairs(force_in, frf.inputs)  # type: ignore[arg-type]

    # 1. band ------------------------------------------------------------------------------
    auto = opt.auto_band and opt.band_hz is None
    band, band_sel, suggestion = first_band(frf, setup, opt, known, w0, in_out)
    data = frf.band(*band)
    # 2. responses -------------------------------------------------------------------------
    rsel, weights, excluded_resp = selected_responses(
        data, setup, opt, force_in, force_out, w0, geo_all
    )
    # 3. orientation -----------------------------------------------------------------------
    setup_used, repair = repaired_orientation(data, setup, opt, weights)
    # 4. inputs ----------------------------------------------------------------------------
    system = assemble(data, setup_used, length_unit=opt.length_unit, response_weights=weights)
    jsel, keep_in, excluded_in = selected_inputs(system, frf, opt, known, in_in, in_out)
    keep_idx = np.nonzero(keep_in)[0]
    if auto and (rsel is not None or jsel is not None or repair is not None):
        # the first suggestion saw every channel and input; suggest again on the selected data
        unchanged = setup_used is setup and (
            np.array_equal(weights, w0) and np.array_equal(keep_in, ~in_out)
        )
        suggestion = second_suggestion(
            frf, setup_used, known, suggestion, unchanged, weights, keep_in
        )
        if suggestion.band_hz != band:
            band = suggestion.band_hz
            data = frf.band(*band)
            system = assemble(
                data, setup_used, length_unit=opt.length_unit, response_weights=weights
            )
        band_sel = {**suggestion.to_json(), "passes": 2}
    system_used: DimSystem = system.select_inputs(keep_idx)

    # 5. solve + uncertainty ---------------------------------------------------------------
    result = solve_system(
        system_used, known=known, method="mean" if opt.method == "mean" else "joint"
    )
    geo: GeometrySpread | None = None
    if opt.geometry_samples > 0:
        geo = geometry_step(data, setup_used, system_used, weights, keep_idx, known, opt)
    unc = uncertainty_step(
        data, setup_used, system_used, result, known, opt, geo_all.nodes, weights, keep_idx, geo
    )
    return _Stage(
        frf=frf,
        setup=setup,
        opt=opt,
        known=known,
        auto=auto,
        data=data,
        setup_used=setup_used,
        weights=weights,
        keep_in=keep_in,
        band_sel=band_sel,
        suggestion=suggestion,
        rsel=rsel,
        jsel=jsel,
        repair=repair,
        excluded_resp=excluded_resp,
        excluded_in=excluded_in,
        system_used=system_used,
        result=result,
        unc=unc,
        geo=geo,
    )


def _finished(st: _Stage) -> AnalysisReport:
    """Step 5's output-error estimate, the cross-check and the verdict (step 6) of a stage;
    no figures."""
    result, unc = st.result, st.unc
    keep_idx = np.nonzero(st.keep_in)[0]
    if _output_error_tried(st.opt, st.auto, st.data, st.setup_used, st.weights, keep_idx, st.known):
        result, unc = output_error_step(
            st.data,
            st.setup_used,
            result,
            unc,
            st.weights,
            st.keep_in,
            st.known,
            st.opt,
            st.system_used.hull_points_m,
        )
    result = _with_extras(result, st.rsel, st.jsel, st.repair)
    cc = _cross_checked(st.data, st.setup_used, result, unc, st.weights, st.keep_in, st.opt)
    report = _stage_report(st, result, unc, cc)
    return _judged(report, st.data, st.suggestion if st.auto else None, st.opt)


def _stage_report(
    st: _Stage, result: DimResult, unc: Uncertainty, cc: CrossCheck | None
) -> AnalysisReport:
    """The report of a stage with this answer, its intervals and cross-check (no verdict)."""
    return AnalysisReport(
        result=result,
        excluded_responses=st.excluded_resp,
        excluded_inputs=st.excluded_in,
        uncertainty=unc,
        orientation_corrections=st.repair.to_json() if st.repair is not None else [],
        band_selection=st.band_sel,
        excitation=excitation_check(_phi_m(st.system_used)),
        setup_used=st.setup_used,
        response_selection=st.rsel,
        input_selection=st.jsel,
        band_suggestion=st.suggestion,
        orientation=st.repair,
        geometry=st.geo,
        cross_check=cc,
        weights_used=np.asarray(st.weights, float),
        inputs_kept=np.asarray(st.keep_in, bool),
    )


def _forced_pairs(opt: AnalysisOptions) -> tuple[list[tuple[int, ...]], list[tuple[int, ...]]]:
    """The (node, direction) pairs forced in and forced out; a pair may not be both."""
    force_in = [tuple(map(int, p)) for p in opt.force_in]
    force_out = [tuple(map(int, p)) for p in opt.force_out]
    if set(force_in) & set(force_out):
        raise SetupError(
            f"{sorted(set(force_in) & set(force_out))[0]} is both forced in and forced out; choose one"
        )
    return force_in, force_out


def _output_error_tried(
    opt: AnalysisOptions,
    auto: bool,
    data: FrfData,
    setup_used: TestSetup,
    weights: np.ndarray,
    keep_idx: np.ndarray,
    known: dict[str, float],
) -> bool:
    """Whether the output-error estimate is tried: asked for, on the joint solve, and, on a
    band given by hand, only when the data are a rigid body there.

    A band given by hand that the verdict will fail (the band check is made on it) gains nothing
    from the output-error fit, whose gross-error search then tries every item in turn (minutes).
    """
    refine = opt.method == "joint" and (
        opt.unbiased or opt.refine_geometry or opt.residual_flexibility
    )
    if refine and not auto:
        e_max, _ = band_quality(data, setup_used, weights > 0, keep_idx.tolist(), known)
        if e_max > MAX_RIGID_BODY_ERROR:
            refine = False
            log.warning(
                "output-error estimate not tried: worst rigid-body error %.3g in the band "
                "(limit %g); the band check fails and the equation-error estimate is reported",
                e_max,
                MAX_RIGID_BODY_ERROR,
            )
    return bool(refine)


def _cross_checked(
    data: FrfData,
    setup_used: TestSetup,
    result: DimResult,
    unc: Any,
    weights: np.ndarray,
    keep_in: np.ndarray,
    opt: AnalysisOptions,
) -> CrossCheck | None:
    """The independent cross-check of the answer when asked (at most 200 geometry samples)."""
    if not opt.cross_check:
        return None
    return cross_check(
        data,
        setup_used,
        result,
        unc,
        weights,
        keep_in,
        geometry_samples=min(opt.geometry_samples, 200),
    )


def _judged(
    report: AnalysisReport,
    data: FrfData,
    suggestion: BandSuggestion | None,
    opt: AnalysisOptions,
) -> AnalysisReport:
    """The report with its verdict and its chain calibration (applied or measured)."""
    v, reasons = verdict(
        report,
        data,
        suggestion,
        ci95_limits=(opt.ci95_limit_mass, opt.ci95_limit_principal),
    )
    report = replace(report, verdict=v, verdict_reasons=reasons)
    if opt.chain is not None:
        report = replace(report, chain_calibration={"role": "applied", **opt.chain.to_json()})
    elif opt.reference_mass is not None:
        report = _measure_chain(report, opt.reference_mass)
    return report


def _with_figures(
    report: AnalysisReport,
    frf: FrfData,
    setup_used: TestSetup,
    plots_dir: Path,
    weights: np.ndarray,
    keep_in: np.ndarray,
) -> AnalysisReport:
    """The report with its figures written to ``plots_dir`` (their paths in ``plots``)."""
    from dimacq.plotting import write_report_figures

    paths = write_report_figures(report, frf, setup_used, plots_dir, weights, keep_in)
    return AnalysisReport(**{**report.__dict__, "plots": paths})


def _with_chain(frf: FrfData, setup: TestSetup, opt: AnalysisOptions) -> tuple[FrfData, TestSetup]:
    """Apply a chain calibration (FRFs × γ, hammer uncertainty := u(γ)), or leave the hammer
    term out of a reference-mass solve (:mod:`dimacq.pipeline.chain_calibration`)."""
    if opt.chain is not None and opt.reference_mass is not None:
        raise SetupError(
            "a reference-mass solve measures the chain factor; do not also apply one "
            "(give either reference_mass or chain_calibration)"
        )
    tu = setup.transducer_uncertainty
    if opt.chain is not None:
        frf = frf.scaled(opt.chain.factor)
        tu = tu.model_copy(update={"force_sensitivity_rel": opt.chain.u_rel, "source": "chain"})
    elif opt.reference_mass is not None:
        tu = tu.model_copy(update={"force_sensitivity_rel": 0.0})
    else:
        return frf, setup
    return frf, setup.model_copy(update={"transducer_uncertainty": tu})


def _measure_chain(report: AnalysisReport, reference_mass: tuple[float, float]) -> AnalysisReport:
    """The chain factor of a reference-mass solve; refused (a ``fail`` reason, no factor) when
    the solve itself is not trusted."""
    if report.verdict == "fail":
        reason = VerdictReason(
            "chain_calibration",
            "fail",
            "no chain calibration from this solve: its verdict is fail (see the other reasons)",
        )
        return replace(report, verdict_reasons=[reason, *report.verdict_reasons])
    m = report.uncertainty.parameters["m"]
    cal = chain_calibration(
        float(report.result.mass_kg),
        float(m.standard_error),
        float(reference_mass[0]),
        float(reference_mass[1]),
    )
    return replace(report, chain_calibration={"role": "measured", **cal.to_json()})


def _phi_m(system: DimSystem) -> np.ndarray:
    phi = system.phi.copy()
    phi[3:] *= system.unit_m
    return phi


def _with_extras(
    result: DimResult,
    rsel: ResponseSelection | None,
    jsel: JackknifeSelection | None,
    repair: OrientationRepair | None,
) -> DimResult:
    extras = dict(result.extras)
    extras["selection_applied"] = {
        "responses": rsel is not None,
        "inputs": jsel is not None,
        "orientation_repair": repair is not None and repair.applied,
    }
    return replace(result, extras=extras)
