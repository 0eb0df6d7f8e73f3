"""The modal-model correction as a step of the analysis: when to use it, what it reports.

:func:`dimacq.services.solve.analysis.analyse` calls :func:`modal_fit` on the whole measured span, gives
the DIM the corrected FRFs (:func:`corrected`), and adds the fit's own uncertainty to the intervals
(:func:`with_modal_uncertainty`). The numerics are in :mod:`dimacq.pipeline.modal`.

When (``modal_correction = "auto"``, the default)
-------------------------------------------------
The plain analysis runs first (up to its equation-error answer: what the checks below read does
not depend on the output-error estimate, which is made only when the plain answer is reported).
Its result stands, unchanged, unless the rigid-body checks show elastic contamination
(:func:`contamination`):

- no band qualifies (the band suggestion found no run of lines moving as one rigid body), or the
  band or residual checks of the verdict fail or warn;
- or the band suggestion saw elastic modes above the band, and either the modal fit's elastic
  modes above the band's upper edge contribute more than :data:`TRIGGER_SIZE` of the kept
  accelerances in it (a smooth mass-line trend the per-line checks cannot see: an X-38-like hull
  with modes at 34/48/62 Hz passes them with principal moments 1.6–2.6 % off), or the peak that
  ended the band is one the fit finds a suspension mode (:func:`_suspension_peak_rejected`: the
  elastic motion riding on it confined the band below the suspension).

Then the analysis runs again on the corrected FRFs and the report says why. ``"on"`` always
corrects, ``"off"`` never.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Protocol

import numpy as np
from numpy.typing import NDArray

from dimacq.errors import DataError, SetupError
from dimacq.model.frf import FrfData
from dimacq.model.setup import PARAMETERS, TestSetup
from dimacq.pipeline.dim import DimResult, assemble, solve_system
from dimacq.pipeline.modal import (
    ModalFit,
    elastic_shapes,
    fit_modal_model,
    project_out,
    residue_draws,
)
from dimacq.pipeline.rigid_body import response_matrix
from dimacq.pipeline.selection._common import response_geometry
from dimacq.pipeline.uncertainty import ParameterUncertainty, Uncertainty, principal_of_parameters
from dimacq.services.solve.verdict import VerdictReason

__all__ = [
    "TRIGGER_SIZE",
    "ModalCorrection",
    "PlainAnalysis",
    "RigidBodyScreen",
    "analyse_with_modal",
    "contamination",
    "corrected",
    "modal_fit",
    "with_modal_uncertainty",
]

log = logging.getLogger(__name__)
FloatArray = NDArray[np.float64]
ComplexArray = NDArray[np.complex128]

#: Largest share of the kept accelerances (RMS over the band) the elastic modes may contribute
#: before ``auto`` corrects a band that passed the rigid-body checks.
TRIGGER_SIZE = 0.005
#: Shapes of the residual term of the modes above the span projected out: singular values above
#: this fraction of the first.
UPPER_RANK_RATIO = 0.1
#: Draws of the correction from the LSFD covariance for its share of the intervals.
N_DRAWS = 24


@dataclass(frozen=True, eq=False)
class ModalCorrection:
    """What the correction did, for the report.

    Attributes
    ----------
    fit : ModalFit
    reason : str
        Why it was applied (or not).
    applied : bool
    mode : {"auto", "on", "off"}
    size_band : ndarray, shape (n_band_lines,)
        ``‖correction‖ / ‖H‖`` per line of the DIM band, kept accelerometers and inputs.
    band_frequencies_hz : ndarray
    se_modal : dict
        Standard error the fit's uncertainty adds to each parameter (and ``principal``).
    """

    fit: ModalFit | None
    reason: str
    applied: bool
    mode: str
    size_band: FloatArray | None = None
    band_frequencies_hz: FloatArray | None = None
    se_modal: dict[str, Any] | None = None

    def to_json(self) -> dict[str, Any]:
        out: dict[str, Any] = {"mode": self.mode, "applied": self.applied, "reason": self.reason}
        fit = self.fit
        if fit is None:
            return out
        out.update(
            {
                "poles": [p.to_json() for p in fit.poles],
                "modes_removed_hz": [p.frequency_hz for p in fit.poles if p.elastic],
                "modes_kept_hz": [p.frequency_hz for p in fit.poles if not p.elastic],
                "fit_range_hz": list(fit.fit_range_hz),
                "fit_error_rel": fit.fit_error,
                "fit_quality": fit.quality(),
            }
        )
        if self.size_band is not None and self.band_frequencies_hz is not None:
            out["correction_size"] = {
                "frequencies_hz": self.band_frequencies_hz.tolist(),
                "relative": self.size_band.tolist(),
                "max": float(np.max(self.size_band)) if self.size_band.size else 0.0,
            }
        if self.se_modal is not None:
            out["se_modal_fit"] = self.se_modal
        return out


@dataclass(frozen=True, eq=False)
class RigidBodyScreen:
    """What :func:`contamination` reads of the plain analysis: none of it depends on the
    estimator's answer (the output-error estimate), only on the band and the selections.

    Attributes
    ----------
    band_suggestion : BandSuggestion, optional
    verdict_reasons : list of VerdictReason
        The verdict's ``band`` and ``residual`` checks (the failing and warning ones first).
    band_hz : (lo, hi)
    excluded_responses, excluded_inputs : list of {"node": N, "direction": D}
    """

    band_suggestion: Any
    verdict_reasons: Sequence[VerdictReason]
    band_hz: tuple[float, ...]
    excluded_responses: Sequence[Mapping[str, int]]
    excluded_inputs: Sequence[Mapping[str, int]]


class PlainAnalysis(Protocol):
    """The analysis of the FRFs as given (``plain(frf, setup, opt)`` of
    :func:`analyse_with_modal`): its :class:`RigidBodyScreen` at once, its report on asking."""

    def screen(self) -> RigidBodyScreen: ...

    def report(self, figures: bool = True) -> Any: ...


def modal_fit(frf: FrfData, setup: TestSetup) -> ModalFit:
    """Poles and residues of every pair of ``frf`` (accelerances and reactions), elastic modes
    told from suspension modes by the setup's rigid-body shapes."""
    geo = response_geometry(frf, setup)
    psi = response_matrix(geo.positions_m, geo.directions, np.asarray(setup.reference_point))
    # Ψ rows in the FRF's order of accelerometer outputs
    kinds = tuple(frf.output_kinds)
    H = frf.H
    acc_rows = np.array([i for i, k in enumerate(kinds) if k == "acceleration"])
    pos = {int(o): int(i) for i, o in enumerate(geo.output_index)}
    keep = np.array([pos.get(int(r), -1) for r in acc_rows])
    if np.any(keep < 0):
        ch = frf.outputs[int(acc_rows[np.argmin(keep)])]
        raise SetupError(
            f"accelerometer output {ch.name} is not a response of the setup; add it to the "
            "setup's responses or leave its records out for the modal correction"
        )
    return fit_modal_model(frf.frequencies_hz, H, kinds, psi[keep])


def _subtracted(frf: FrfData, fit: ModalFit) -> FrfData:
    """The FRFs minus the fitted elastic-mode terms (reactions keep their static share), on
    the lines where the fit holds: the first estimate, for the mass matrix the shapes need."""
    lo, hi = fit.band_range_hz
    return frf.replace(H=frf.H - fit.correction).band(lo, hi)


def _mass_matrix(data: FrfData, setup: TestSetup) -> FloatArray:
    """6×6 rigid-body mass matrix about P from a joint equation-error DIM solve of ``data``."""
    res = solve_system(assemble(data, setup, length_unit="m"))
    return np.asarray(res.properties.mass_matrix(np.asarray(setup.reference_point, float)))


def corrected(
    frf: FrfData, fit: ModalFit, setup: TestSetup, n_iter: int = 2
) -> tuple[FrfData, ComplexArray]:
    """The FRFs with the elastic motion taken out of the accelerances, on the lines where the
    fit holds (``fit.band_range_hz``: within the FRFs' clean span, the LSFD residual within its
    noise), and the correction (n_lines, n_outputs, n_inputs) over the whole span.

    Each elastic mode's displacement residues ``A_r`` hold its elastic shape and the rigid-body
    motion ``U_r`` the supports give it; (1) of :mod:`dimacq.pipeline.modal` at the pole gives
    ``U_r = M⁻¹ W_r / λ_r²`` from the mode's reaction residues ``W_r`` mapped to P. With ``M``
    from a first solve (the subtracted FRFs, then the projected ones: ``n_iter`` passes; ``U_r``
    is small, so ``M``'s error enters at second order), the elastic shapes
    (:func:`~dimacq.pipeline.modal.elastic_shapes`) and the shapes of the residual term of the
    modes above the span are projected out of the accelerances line by line
    (:func:`~dimacq.pipeline.modal.project_out`). The reactions are measured forces and stay as
    they are: that keeps the quasi-static deformation the support forces cause out of the rigid
    motion, which a subtraction of the modes leaves in (its error grows as
    ``(f_suspension / f_elastic)²``: 0.4 % mass and 10 mm CG with the hull modes at 17 Hz,
    noise-free; projected: 0.001 %, 0.01 mm). The passes for ``M`` project only the band's lines
    (the projection is line by line).
    """
    lo, hi = fit.band_range_hz
    proj = _Projection(frf, fit, setup)
    band = frf.band(lo, hi)
    M = _mass_matrix(_subtracted(frf, fit), setup)
    for _ in range(n_iter):
        M = _mass_matrix(band.replace(H=proj.apply(band.H, M)), setup)
    H = proj.apply(frf.H, M)
    return frf.replace(H=H).band(lo, hi), frf.H - H


class _Projection:
    """The elastic shapes projected out of the accelerometer rows (:func:`corrected`): what
    does not change with ``M`` or a draw of the residues is worked out once.

    ``apply(H, M, residues_acc, upper_acc)`` returns ``H`` (any lines of the FRFs, n_lines ×
    n_outputs × n_inputs) with the shapes projected out; ``residues_acc`` (n_modes, n_acc,
    n_inputs) and ``upper_acc`` (n_acc, n_inputs) replace the fit's accelerometer residues and
    top-line residual term (for the uncertainty draws).
    """

    def __init__(self, frf: FrfData, fit: ModalFit, setup: TestSetup) -> None:
        self.fit = fit
        self.el = [r for r, p in enumerate(fit.poles) if p.elastic]
        geo = response_geometry(frf, setup)
        self.psi = response_matrix(
            geo.positions_m, geo.directions, np.asarray(setup.reference_point, float)
        )
        self.acc = geo.output_index
        pos = {int(o): k for k, o in enumerate(fit.kind_index["acceleration"])}
        self.rows = np.array([pos[int(o)] for o in self.acc], dtype=np.intp)
        # each elastic mode's reaction residues as a load at P, and λ²
        self.W: ComplexArray = np.asarray(
            [_reactions_at_p(frf, fit.residues[r], setup) for r in self.el], complex
        )
        self.lam2: ComplexArray = np.array([fit.poles[r].lam ** 2 for r in self.el], complex)

    def apply(
        self,
        H: ComplexArray,
        M: FloatArray,
        residues_acc: ComplexArray | None = None,
        upper_acc: ComplexArray | None = None,
    ) -> ComplexArray:
        fit, el, rows = self.fit, self.el, self.rows
        kind_acc = fit.kind_index["acceleration"]
        res = fit.residues[:, kind_acc] if residues_acc is None else residues_acc
        top = fit.upper_acc[fit.top_line][kind_acc] if upper_acc is None else upper_acc
        up = np.real(top[rows])
        u_up, sv_up, _ = np.linalg.svd(up, full_matrices=False)
        shapes = [u_up[:, sv_up > UPPER_RANK_RATIO * sv_up[0]] if sv_up[0] > 0 else u_up[:, :0]]
        if el:
            U = np.linalg.solve(M[None], self.W) / self.lam2[:, None, None]
            shapes.insert(0, elastic_shapes(res[el][:, rows], U, self.psi))
        out = H.copy()
        out[:, self.acc], _ = project_out(
            H[:, self.acc], self.psi, np.concatenate(shapes, 1).astype(complex)
        )
        return out


def _reactions_at_p(frf: FrfData, residue: ComplexArray, setup: TestSetup) -> ComplexArray:
    """A mode's reaction residues (every load cell) as one 6-DOF load at P, (6, n_inputs), SI."""
    one = FrfData(np.array([1.0]), residue[None], frf.outputs, frf.output_kinds, frf.inputs)
    sysr = assemble(one, setup, length_unit="m")
    return np.asarray(sysr.F[0] - sysr.phi)


def band_size(
    frf: FrfData,
    correction: ComplexArray,
    band_hz: tuple[float, float],
    rows: NDArray[np.intp],
    inputs: NDArray[np.intp],
) -> tuple[FloatArray, FloatArray]:
    """Per line of the band: ‖correction‖ / ‖H‖ over the given outputs and inputs."""
    f = frf.frequencies_hz
    sel = (f >= band_hz[0] - 1e-9) & (f <= band_hz[1] + 1e-9)
    c = correction[sel][:, rows][:, :, inputs]
    h = frf.H[sel][:, rows][:, :, inputs]
    den = np.sqrt(np.sum(np.abs(h) ** 2, axis=(1, 2)))
    size = np.sqrt(np.sum(np.abs(c) ** 2, axis=(1, 2))) / np.where(den > 0, den, 1.0)
    return f[sel], np.asarray(size)


def contamination(
    report: RigidBodyScreen, frf: FrfData, setup: TestSetup, fit_cache: dict[str, ModalFit]
) -> str | None:
    """Why the plain analysis is elastically contaminated, or None (module docstring)."""
    sugg = report.band_suggestion
    if sugg is not None and not sugg.qualified:
        return f"no band qualifies ({sugg.reason})"
    for reason in report.verdict_reasons:
        if reason.check in ("band", "residual") and reason.severity != "ok":
            return f"the {reason.check} check gives {reason.severity}: {reason.message}"
    if sugg is None or not sugg.deformation_peaks_hz:
        return None
    try:
        fit = fit_cache.get("fit") or modal_fit(frf, setup)
    except DataError as err:  # no fit on these lines (e.g. a pole read as a suspension mode
        # near Nyquist leaves none above it): no evidence of an elastic mode, as with none found
        log.warning("modal correction auto: deformation peaks, but no modal fit (%s)", err)
        return None
    fit_cache["fit"] = fit
    if not fit.elastic_poles:
        return None
    hi = float(report.band_hz[1])
    why = _suspension_peak_rejected(sugg.deformation_peaks_hz, hi, fit)
    if why is not None:
        return why
    geo = response_geometry(frf, setup)
    excluded = {(c["node"], c["direction"]) for c in report.excluded_responses}
    rows = np.array(
        [
            o
            for o, ch in zip(geo.output_index, geo.channels, strict=True)
            if (ch.node, ch.direction) not in excluded
        ],
        dtype=np.intp,
    )
    ex_in = {(c["node"], c["direction"]) for c in report.excluded_inputs}
    inputs = np.array(
        [j for j, ch in enumerate(frf.inputs) if (ch.node, ch.direction) not in ex_in],
        dtype=np.intp,
    )
    # the elastic modes above the band: their tails are the smooth trend. A mode below the band
    # (a small part isolated above its resonance) or inside it (a peak among the band's lines)
    # is what the per-line checks do see; counting those fired on the shipped x38's drogue-chute
    # pair at 5.1 Hz inside its band at 3 % noise and moved a right answer (CG 2.8 mm) to 5.3 mm.
    above = [r for r, p in enumerate(fit.poles) if p.elastic and p.frequency_hz > hi]
    if not above:
        return None
    s = 2j * np.pi * frf.frequencies_hz
    acc = fit.kind_index["acceleration"]
    terms = np.zeros_like(frf.H)
    for r in above:
        lam = fit.poles[r].lam
        A = fit.residues[r][acc]
        terms[:, acc] = terms[:, acc] + (s**2)[:, None, None] * (
            A[None] / (s - lam)[:, None, None] + A.conj()[None] / (s - np.conj(lam))[:, None, None]
        )
    _, size = band_size(frf, terms, (report.band_hz[0], report.band_hz[1]), rows, inputs)
    top = float(np.sqrt(np.mean(size**2))) if size.size else 0.0
    if top <= TRIGGER_SIZE:
        return None
    modes = ", ".join(f"{fit.poles[r].frequency_hz:.3g}" for r in above)
    return (
        f"elastic modes at {modes} Hz contribute {100 * top:.2g} % of the kept accelerances in "
        f"the band (limit {100 * TRIGGER_SIZE:g} %), a trend the rigid-body checks cannot see"
    )


def _suspension_peak_rejected(
    peaks_hz: tuple[float, ...], band_hi_hz: float, fit: ModalFit
) -> str | None:
    """Why the band was confined below the suspension by elastic motion, or None.

    The band suggestion ends the rigid-body band at the peaks above it that the rigid-body
    model does not explain. When the modal fit finds one of them, below its first elastic mode,
    to be a suspension mode (its
    residues lie in the rigid-body span: the body moves as one there) while it also finds elastic
    modes, what the per-line check rejected is the elastic motion riding on the suspension mode
    — the deformation the support forces cause when the elastic modes lie close above (an
    X-38-like hull with modes at 10 Hz, twice its top suspension mode, leaves a band of 8 lines
    below 0.5 Hz, quasi-static, CG 38 mm off)."""
    first_el = min(p.frequency_hz for p in fit.elastic_poles)
    line = float(np.median(np.diff(fit.frequencies_hz)))
    for peak in sorted(p for p in peaks_hz if band_hi_hz < p < first_el):
        tol = max(0.02 * peak, 2 * line)
        if any(not p.elastic and abs(p.frequency_hz - peak) <= tol for p in fit.poles):
            modes = ", ".join(f"{p.frequency_hz:.3g}" for p in fit.elastic_poles)
            return (
                f"the band ends at {band_hi_hz:.3g} Hz below a peak at {peak:.3g} Hz the "
                "rigid-body check rejects, which the modal fit finds a suspension mode moving "
                f"the body rigidly: the elastic modes at {modes} Hz deform it there"
            )
    return None


def with_modal_uncertainty(
    frf: FrfData,
    fit: ModalFit,
    setup: TestSetup,
    result: DimResult,
    unc: Uncertainty,
    weights: FloatArray,
    keep_idx: NDArray[np.intp],
    known: Mapping[str, float],
    length_unit: str | None,
) -> tuple[Uncertainty, dict[str, Any]]:
    """The intervals widened by the modal fit's uncertainty: residues drawn from the LSFD
    covariance (:func:`~dimacq.pipeline.modal.residue_draws`), the shapes projected out again
    (the mass matrix of ``result`` held), the DIM (joint, equation
    error) solved on each in the same band, channels and inputs; their spread is added in
    quadrature to every parameter's standard error and the 95 % half-width scaled with it."""
    lo, hi = result.band_hz
    M = np.asarray(result.properties.mass_matrix(np.asarray(setup.reference_point, float)))
    res, up = residue_draws(fit, N_DRAWS, seed=25)
    proj = _Projection(frf, fit, setup)
    band = frf.band(lo, hi)  # the projection is line by line: the band's lines are all it needs
    samples = []
    for r_d, u_d in zip(res, up, strict=True):
        data = band.replace(H=proj.apply(band.H, M, r_d, u_d))
        system = assemble(
            data, setup, length_unit=length_unit, response_weights=weights
        ).select_inputs(keep_idx)
        # the parameters alone: the plausibility checks are the headline solve's
        samples.append(solve_system(system, known=dict(known), check_plausibility=False).parameters)
    s = np.asarray(samples)
    se = s.std(axis=0, ddof=1)
    P = np.asarray(result.reference_point_m, float)
    se_pm = principal_of_parameters(s, P).std(axis=0, ddof=1)

    def widen(u: ParameterUncertainty, extra: float) -> ParameterUncertainty:
        new = float(np.hypot(u.standard_error, extra))
        k = new / u.standard_error if u.standard_error > 0 else 1.0
        half = 0.5 * (u.ci95[1] - u.ci95[0]) * k if u.standard_error > 0 else 1.96 * new
        return replace(u, standard_error=new, ci95=(u.value - half, u.value + half))

    params = {
        k: widen(u, float(se[PARAMETERS.index(k)])) if k in PARAMETERS else u
        for k, u in unc.parameters.items()
    }
    principal = tuple(widen(u, float(e)) for u, e in zip(unc.principal, se_pm, strict=False))
    out = replace(
        unc,
        parameters=params,
        principal=principal,
        components=(*unc.components, "modal_fit"),
    )
    info = {
        "n_draws": N_DRAWS,
        "standard_error": dict(zip(PARAMETERS, se.tolist(), strict=True)),
        "principal_moments": se_pm.tolist(),
    }
    return out, info


def analyse_with_modal(
    frf: FrfData,
    setup: TestSetup,
    opt: Any,
    plain: Callable[[FrfData, TestSetup, Any], PlainAnalysis],
    with_chain: Callable[[FrfData, TestSetup], tuple[FrfData, TestSetup]],
) -> Any:
    """:func:`dimacq.services.solve.analysis.analyse` with ``opt.modal_correction`` (module
    docstring): ``plain(frf, setup, opt)`` is the analysis as measured (its report an
    ``AnalysisReport``), ``with_chain`` applies the options' chain calibration as it does.

    ``auto`` decides on the plain analysis's :class:`RigidBodyScreen`; the plain report (its
    output-error estimate, the costly part) is made only when it is the answer or its verdict
    is needed (the corrected solve fails its checks).
    """
    if opt.modal_correction not in ("auto", "on", "off"):
        raise SetupError(f"modal_correction = {opt.modal_correction!r}; give auto, on or off")
    if opt.modal_correction == "off":
        return plain(frf, setup, opt).report()
    if opt.modal_correction == "on":
        return _analyse_modal(
            frf, setup, opt, plain, with_chain, "asked for (--modal-correction on)", {}
        )
    first = plain(frf, setup, opt)
    cache: dict[str, Any] = {}
    why = contamination(first.screen(), *with_chain(frf, setup), cache)
    if why is None:  # the plain answer as it is, bit for bit and key for key
        return first.report()
    fit: ModalFit | None = None
    try:
        fit = cache.get("fit") or modal_fit(*with_chain(frf, setup))
        why_not = "" if fit.elastic_poles else "the modal fit finds no elastic mode"
    except DataError as err:
        why_not = f"the modal fit is not possible ({err})"
    if why_not or fit is None:
        note = ModalCorrection(fit, f"{why}; but {why_not}: solved as measured", False, "auto")
        return replace(first.report(), modal_correction=note)
    cache["fit"] = fit
    log.warning("modal correction applied: %s", why)
    second = _analyse_modal(frf, setup, opt, plain, with_chain, why, cache)
    if second.verdict == "fail" and first.report(figures=False).verdict != "fail":
        assert second.modal_correction is not None
        note = replace(
            second.modal_correction,
            applied=False,
            reason=f"{why}; but the corrected solve fails its checks: solved as measured",
        )
        return replace(first.report(), modal_correction=note)
    return second


def _analyse_modal(
    frf: FrfData,
    setup: TestSetup,
    opt: Any,
    plain: Callable[[FrfData, TestSetup, Any], PlainAnalysis],
    with_chain: Callable[[FrfData, TestSetup], tuple[FrfData, TestSetup]],
    why: str,
    cache: dict[str, Any],
) -> Any:
    """The analysis on the FRFs with the elastic modes taken out, the fit's uncertainty added."""
    frf_c, setup_c = with_chain(frf, setup)
    fit = cache.get("fit") or modal_fit(frf_c, setup_c)
    # without a chain factor frf_c is frf; with one, _analyse must not apply it again
    data, correction = corrected(frf_c, fit, setup_c)
    opt_c = opt if opt.chain is None else replace(opt, chain=None)
    if opt.chain is not None:
        setup = setup_c
    rep = plain(data, setup, opt_c).report()
    if opt.chain is not None:
        rep = replace(rep, chain_calibration={"role": "applied", **opt.chain.to_json()})
    known = dict(setup.known.as_dict() if opt.known is None else opt.known)
    assert rep.weights_used is not None and rep.inputs_kept is not None
    unc, info = with_modal_uncertainty(
        frf_c,
        fit,
        rep.setup_used,
        rep.result,
        rep.uncertainty,
        rep.weights_used,
        np.nonzero(rep.inputs_kept)[0],
        known,
        opt.length_unit,
    )
    geo = response_geometry(frf_c, rep.setup_used)
    f_band, size = band_size(
        frf_c,
        correction,
        tuple(rep.result.band_hz),
        geo.output_index[rep.weights_used > 0],
        np.nonzero(rep.inputs_kept)[0],
    )
    note = ModalCorrection(
        fit, f"modal correction applied: {why}", True, opt.modal_correction, size, f_band, info
    )
    if opt.plots_dir is not None:
        from dimacq.plotting.figures import figure_modal_correction, save_figure

        f_all, size_all = band_size(
            frf_c,
            correction,
            fit.fit_range_hz,
            geo.output_index[rep.weights_used > 0],
            np.nonzero(rep.inputs_kept)[0],
        )
        fig = figure_modal_correction(
            f_all,
            size_all,
            [(p.frequency_hz, p.elastic) for p in fit.poles],
            band_hz=tuple(rep.result.band_hz),
        )
        rep = replace(rep, plots=[*rep.plots, *save_figure(fig, Path(opt.plots_dir), "modal")])
    reason = VerdictReason(
        "modal_correction",
        "ok",
        f"elastic modes at {', '.join(f'{p.frequency_hz:.3g}' for p in fit.elastic_poles)} Hz "
        f"taken out of the FRFs ({why}); fitted over {fit.fit_range_hz[0]:.3g}–"
        f"{fit.fit_range_hz[1]:.4g} Hz (the FRFs' noise within {100 * fit.noise_limit:.2g} %), "
        f"the fit holding over {fit.band_range_hz[0]:.4g}–{fit.band_range_hz[1]:.4g} Hz; "
        f"correction up to {100 * float(np.max(size, initial=0)):.3g} "
        "% of the kept accelerances in the band",
    )
    return replace(
        rep, uncertainty=unc, modal_correction=note, verdict_reasons=[*rep.verdict_reasons, reason]
    )
