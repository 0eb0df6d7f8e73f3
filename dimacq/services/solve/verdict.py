"""One verdict per solution: ``ok`` | ``warn`` | ``fail`` with the reasons behind it.

A wrong answer reported as ok is the worst defect a measurement tool can have: every check below is
reported whatever its outcome, and any failing check fails the solution (``dimacq solve`` exits 3).
Split from :mod:`dimacq.services.solve.analysis`, which calls :func:`verdict` after the solve and
re-exports these names. This module does not import the analysis (not even for types): what it
reads of a solve is the :class:`SolveReport` protocol, so the two modules form no circle.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np
from numpy.typing import NDArray

from dimacq.model.frf import FrfData
from dimacq.pipeline.output_error import REACTION_SNR_LOW
from dimacq.pipeline.selection._common import response_geometry
from dimacq.pipeline.selection.band import MAX_RESIDUAL, MAX_RIGID_BODY_ERROR, BandSuggestion
from dimacq.pipeline.uncertainty import Uncertainty

if TYPE_CHECKING:
    from dimacq.model.setup import TestSetup
    from dimacq.pipeline.dim import DimResult
    from dimacq.pipeline.selection.inputs import ExcitationCheck


class SolveReport(Protocol):
    """What the verdict reads of a solve (:class:`dimacq.services.solve.analysis.AnalysisReport`)."""

    @property
    def result(self) -> DimResult: ...
    @property
    def excluded_responses(self) -> list[dict[str, int]]: ...
    @property
    def excluded_inputs(self) -> list[dict[str, int]]: ...
    @property
    def uncertainty(self) -> Uncertainty: ...
    @property
    def band_selection(self) -> dict[str, Any]: ...
    @property
    def excitation(self) -> ExcitationCheck: ...
    @property
    def setup_used(self) -> TestSetup: ...


__all__ = [
    "CI95_LIMIT_MASS",
    "CI95_LIMIT_PRINCIPAL",
    "PRECISION_FAIL_FACTOR",
    "RESIDUAL_FAIL",
    "RESIDUAL_WARN",
    "VerdictReason",
    "band_quality",
    "cross_check_checks",
    "estimator_checks",
    "rigid_body_checks",
    "verdict",
]

log = logging.getLogger(__name__)

#: Relative residual of the joint DIM solve above which the answer is refused / flagged.
RESIDUAL_FAIL = MAX_RESIDUAL
RESIDUAL_WARN = 0.05
#: Largest useful relative half-width of the 95 % interval of the mass and of each principal
#: moment. Principal moments: ±5 %, the accuracy accepted of any answer (flexible
#: structures). Mass: ±2 %, twice what a careful lab's stated uncertainties give (the default
#: 0.5 % (1σ) hammer certificate alone is ±1 %; 2 mm / 0.5° / 1° geometry adds about ±0.3 % on
#: the 18 kg calibration mass, whose principal moments come out near ±3 %). An interval wider than
#: that cannot show the answer is usable: ``warn``; :data:`PRECISION_FAIL_FACTOR` times wider:
#: ``fail``.
CI95_LIMIT_MASS = 0.02
CI95_LIMIT_PRINCIPAL = 0.05
PRECISION_FAIL_FACTOR = 10.0


#: Order of the reasons: the failing ones first, then the warning ones.
_ORDER = {"fail": 0, "warn": 1, "ok": 2}


@dataclass(frozen=True)
class VerdictReason:
    """One check behind the verdict: ``severity`` ``ok`` | ``warn`` | ``fail``."""

    check: str
    severity: str
    message: str

    def to_json(self) -> dict[str, str]:
        return {"check": self.check, "severity": self.severity, "message": self.message}


def band_quality(
    data: FrfData,
    setup: TestSetup,
    use: NDArray[np.bool_],
    in_keep: Sequence[int],
    known: Mapping[str, float] | None = None,
) -> tuple[float, float]:
    """Worst rigid-body error and median per-line DIM residual over the band's lines.

    e(ω) = ‖Q − Ψ Ψ⁺ Q‖_F / ‖Q‖_F on the kept accelerometer channels ``use`` (one flag per
    channel of ``response_geometry``) and inputs ``in_keep``: the share of the measured motion
    no rigid body explains, with the stated geometry.
    """
    from dimacq.pipeline.dim import assemble as _assemble
    from dimacq.pipeline.dim import line_residuals
    from dimacq.pipeline.rigid_body import response_matrix

    geo = response_geometry(data, setup)
    q = data.H[:, geo.output_index][:, use][:, :, list(in_keep)]
    psi = response_matrix(geo.positions_m[use], geo.directions[use], setup.reference_point)
    fit = np.einsum("ck,lkj->lcj", psi @ np.linalg.pinv(psi), q)
    with np.errstate(divide="ignore", invalid="ignore"):
        e = np.sqrt(np.sum(np.abs(q - fit) ** 2, axis=(1, 2)) / np.sum(np.abs(q) ** 2, axis=(1, 2)))
    system = _assemble(data, setup, response_weights=use.astype(float)).select_inputs(list(in_keep))
    r = line_residuals(system, known=dict(known or {}))
    return float(np.nanmax(e)), float(np.nanmedian(r))


def _band_quality(report: SolveReport, data: FrfData) -> tuple[float, float]:
    """:func:`band_quality` of a report's kept data."""
    setup = report.setup_used
    geo = response_geometry(data, setup)
    kept = {(c["node"], c["direction"]) for c in report.excluded_responses}
    use = np.array([(c.node, c.direction) not in kept for c in geo.channels])
    in_keep = [
        i
        for i, c in enumerate(data.inputs)
        if {"node": c.node, "direction": c.direction} not in report.excluded_inputs
    ]
    return band_quality(data, setup, use, in_keep, report.result.known)


def verdict(
    report: SolveReport,
    data: FrfData,
    suggestion: BandSuggestion | None = None,
    *,
    ci95_limits: tuple[float, float] = (CI95_LIMIT_MASS, CI95_LIMIT_PRINCIPAL),
) -> tuple[str, list[VerdictReason]]:
    """One verdict for a solution: ``fail`` if any check fails, else ``warn`` if any warns, else
    ``ok``; the reasons list every check (failing and warning ones first).

    Checks: ``band`` (an automatic band that qualified, or a given band whose worst rigid-body
    error and median DIM residual stay below the absolute limits
    :data:`~dimacq.pipeline.selection.band.MAX_RIGID_BODY_ERROR` and ``MAX_RESIDUAL``),
    ``residual`` (relative residual of the joint solve: fail above 0.10, warn above 0.05), the
    plausibility diagnostics of the solver (error severity → fail, warning → warn),
    ``excitation`` (every rigid-body DOF excited), ``coverage`` (lines in the band, share of the
    channels and inputs kept, rank-deficient leave-outs), ``registration`` (the setup's
    registration residual against its limit), ``uncertainty`` (every source included),
    ``precision`` (the relative half-width of the 95 % interval of the mass and of each principal
    moment against ``ci95_limits``: above → warn, :data:`PRECISION_FAIL_FACTOR` times above → fail;
    an interval that wide cannot tell whether the answer is good enough).
    """
    res = report.result
    out = rigid_body_checks(report, data, suggestion)
    out.extend(_plausibility_checks(res.diagnostics))
    out.extend(_coverage_checks(report))
    out.extend(_registration_checks(report.setup_used.geometry_uncertainty))
    out.extend(estimator_checks(res.extras.get("output_error")))
    out.append(_uncertainty_check(report.uncertainty.components))
    out.extend(cross_check_checks(getattr(report, "cross_check", None)))
    out.append(_precision(report.uncertainty, ci95_limits))
    out.sort(key=lambda r: _ORDER.get(r.severity, 3))
    v = (
        "fail"
        if any(r.severity == "fail" for r in out)
        else ("warn" if any(r.severity == "warn" for r in out) else "ok")
    )
    return v, out


def rigid_body_checks(
    report: SolveReport, data: FrfData, suggestion: BandSuggestion | None = None
) -> list[VerdictReason]:
    """The ``band`` and ``residual`` checks of :func:`verdict` (the failing and warning ones
    first, as :func:`verdict` orders them): what the data in the band say of the rigid-body
    model, read before the estimator's answer (they do not depend on it)."""
    out = [_band_check(report, data, suggestion), _residual_check(report.result.residual_rel)]
    out.sort(key=lambda r: _ORDER.get(r.severity, 3))
    return out


def _band_check(
    report: SolveReport, data: FrfData, suggestion: BandSuggestion | None
) -> VerdictReason:
    """``band``: an automatic band that qualified, or a given band whose worst rigid-body error
    and median DIM residual stay below their absolute limits."""
    if suggestion is not None:
        if suggestion.qualified:
            return VerdictReason("band", "ok", f"automatic band: {suggestion.reason}")
        return VerdictReason("band", "fail", suggestion.reason)
    e_max, r_med = _band_quality(report, data)
    lo, hi = report.result.band_hz
    bad = e_max > MAX_RIGID_BODY_ERROR or r_med > MAX_RESIDUAL
    return VerdictReason(
        "band",
        "fail" if bad else "ok",
        f"band {lo:g}–{hi:g} Hz ({report.band_selection.get('reason', '')}): worst "
        f"rigid-body error {e_max:.3g} (limit {MAX_RIGID_BODY_ERROR:g}), median DIM "
        f"residual {r_med:.3g} (limit {MAX_RESIDUAL:g})"
        + ("; the data in this band are not a rigid body with measured forces" if bad else ""),
    )


def _residual_check(rr: float) -> VerdictReason:
    """``residual``: the joint solve's relative residual against the warn and fail limits."""
    sev = "fail" if rr > RESIDUAL_FAIL else "warn" if rr > RESIDUAL_WARN else "ok"
    return VerdictReason(
        "residual",
        sev,
        f"relative residual of the DIM system {rr:.3g} (warn above {RESIDUAL_WARN:g}, "
        f"fail above {RESIDUAL_FAIL:g})"
        + (
            ""
            if sev == "ok"
            else ": the rigid-body equations do not explain the data; "
            "check the setup against the FRFs (channels, signs, units, geometry)"
        ),
    )


def _plausibility_checks(diagnostics: Any) -> list[VerdictReason]:
    """``plausibility:CODE``: each solver diagnostic (error → fail, warning → warn)."""
    out = []
    for d in diagnostics:
        if d.ok:
            out.append(VerdictReason(f"plausibility:{d.code}", "ok", d.message))
        else:
            out.append(
                VerdictReason(
                    f"plausibility:{d.code}",
                    "fail"
                    if d.severity == "error"
                    else "warn"
                    if d.severity == "warning"
                    else "ok",
                    d.message,
                )
            )
    return out


def _coverage_checks(report: SolveReport) -> list[VerdictReason]:
    """``excitation`` (every rigid-body DOF excited), ``coverage`` (lines, share of channels and
    inputs kept) and ``coverage:leave_one_out`` (rank-deficient leave-outs)."""
    res = report.result
    exc_j = report.excitation.to_json()
    rank = int(exc_j.get("rank", 6))
    out = [
        VerdictReason(
            "excitation",
            "ok" if rank >= 6 else "fail",
            f"the kept inputs excite {rank} of 6 rigid-body DOF"
            + ("" if rank >= 6 else "; add inputs in the missing directions"),
        )
    ]
    n_lines = res.frequencies_hz.size
    n_ch = len(res.responses)
    n_ex_r = len(report.excluded_responses)
    n_in = len(res.inputs) + len(report.excluded_inputs)
    n_ex_i = len(report.excluded_inputs)
    warn_cov = n_lines < 5 or n_ex_r > n_ch / 3 or n_ex_i > n_in / 3
    out.append(
        VerdictReason(
            "coverage",
            "warn" if warn_cov else "ok",
            f"{n_lines} lines in the band; {n_ex_r} of {n_ch} response channels and {n_ex_i} of "
            f"{n_in} inputs excluded"
            + ("; a large share of the data was set aside, check why" if warn_cov else ""),
        )
    )
    nbad = report.uncertainty.n_rank_deficient
    if nbad:
        out.append(
            VerdictReason(
                "coverage:leave_one_out",
                "warn",
                f"{nbad} leave-one-out solve(s) rank deficient: some input or sensor node is "
                "indispensable; the interval cannot show what losing it would do",
            )
        )
    return out


def _registration_checks(gu: Any) -> list[VerdictReason]:
    """``registration``: the setup's registration RMS residual against its limit (none when the
    setup states no registration)."""
    if gu.registration_rms_m is None:
        return []
    lim = gu.registration_limit_m
    if lim is not None and gu.registration_rms_m > lim:
        return [
            VerdictReason(
                "registration",
                "fail",
                f"registration RMS residual {gu.registration_rms_m * 1000:.3g} mm exceeds its "
                f"limit {lim * 1000:.3g} mm: the digitized geometry is not trustworthy; "
                "re-register the array (check the reference nodes)",
            )
        ]
    return [
        VerdictReason(
            "registration",
            "ok",
            f"registration RMS residual {gu.registration_rms_m * 1000:.3g} mm"
            + (f" (limit {lim * 1000:.3g} mm)" if lim is not None else " (no limit stated)"),
        )
    ]


def _uncertainty_check(components: Any) -> VerdictReason:
    """``uncertainty``: which sources the 95 % intervals include (warn when one is left out)."""
    missing = [c for c in ("inputs", "responses", "geometry", "lines") if c not in components]
    return VerdictReason(
        "uncertainty",
        "warn" if missing else "ok",
        "95 % intervals include "
        + ", ".join(components)
        + (f"; they leave out {', '.join(missing)}" if missing else ""),
    )


def estimator_checks(oe: Any) -> list[VerdictReason]:
    """The ``estimator`` checks of an output-error solve.

    - ``estimator:adequacy``: the refined answer against the stated-geometry one
      (:func:`dimacq.pipeline.output_error.checks.adequacy_test`). A refinement that moved the properties
      beyond what the stated geometry uncertainty allows explained a misfit that is not
      geometry: ``warn``, with the difference already in the intervals (model-form term).
    - ``estimator:refinement``: a refinement the data refused (corrections far beyond the stated
      uncertainty after the gross-error search): ``warn``, the stated geometry was used — by the
      output-error fit, or, when that fit's misfit is far above the noise, by the equation-error
      estimate reported instead (:mod:`dimacq.services.solve.estimation`): the data the refinement
      could not reconcile are no less suspect for the estimator that stays.
    - ``estimator:noise``: the misfit against the measured noise model (the a posteriori
      variance factor): stated for the record; the intervals are scaled by it.
    """
    if isinstance(oe, dict) and not oe.get("used") and oe.get("refinement_refused"):
        return [
            VerdictReason(
                "estimator:refinement",
                "warn",
                f"{oe['refinement_refused']}; the output-error fit on it was not used either "
                "(its misfit is far above the noise): the equation-error estimate is reported",
            )
        ]
    if not isinstance(oe, dict) or not oe.get("used"):
        return []
    out: list[VerdictReason] = []
    ad = oe.get("adequacy") or {}
    if ad.get("tested"):
        if ad.get("passed"):
            out.append(
                VerdictReason(
                    "estimator:adequacy",
                    "ok",
                    f"the refined geometry moves the properties as far as its stated uncertainty "
                    f"allows (Hausman {ad['statistic']:.3g} ≤ {ad['critical_value']:.3g}, "
                    f"{ad['dof']} dof)",
                )
            )
        else:
            out.append(
                VerdictReason(
                    "estimator:adequacy",
                    "warn",
                    f"the refinement moved the properties further from the stated-geometry "
                    f"estimate than the stated geometry uncertainty allows (Hausman "
                    f"{ad['statistic']:.3g} > {ad['critical_value']:.3g}, {ad['dof']} dof): it "
                    "explained a misfit that is not geometry (channel calibration, a load-cell "
                    "chain, a support or mode the rigid model lacks); the difference is in the "
                    "95 % intervals. Check the channels' sensitivities and the band",
                )
            )
    noise = oe.get("noise") or {}
    if noise.get("refinement_refused"):
        out.append(VerdictReason("estimator:refinement", "warn", str(noise["refinement_refused"])))
    low = noise.get("reaction_lines_at_noise")
    if low is not None and low > 0:
        out.append(
            VerdictReason(
                "estimator:reactions",
                "ok",
                f"the load cells' reactions are at their noise level (power ≤ {REACTION_SNR_LOW:g}× "
                f"noise) on {100 * low:.0f} % of the band's lines × inputs: the fit weighs them by "
                "that noise (their bias compensated), not as exact forces",
            )
        )
    vf = noise.get("variance_factor")
    if vf is not None and vf > 1.0:
        out.append(
            VerdictReason(
                "estimator:noise",
                "ok",
                f"misfit {vf**0.5:.3g}× the FRFs' own noise (line-to-line scatter): the "
                "intervals are scaled by it (calibration errors, modelling)",
            )
        )
    return out


def _precision(unc: Uncertainty, limits: tuple[float, float]) -> VerdictReason:
    """The ``precision`` check: is each 95 % interval narrow enough to be useful?"""
    parts: list[str] = []
    worst = 0.0
    items = [("mass", unc.parameters["m"], limits[0])]
    items += [(f"I{k + 1}", u, limits[1]) for k, u in enumerate(unc.principal)]
    for name, u, lim in items:
        if u.value == 0 or lim <= 0:
            continue
        half = 0.5 * (u.ci95[1] - u.ci95[0]) / abs(u.value)
        worst = max(worst, half / lim)
        if half > lim:
            parts.append(f"{name} ±{100 * half:.3g} % (limit ±{100 * lim:.3g} %)")
    sev = "fail" if worst > PRECISION_FAIL_FACTOR else "warn" if worst > 1 else "ok"
    if sev == "ok":
        msg = (
            f"95 % intervals within ±{100 * limits[0]:g} % of the mass and ±{100 * limits[1]:g} % "
            "of each principal moment"
        )
    else:
        msg = (
            "95 % interval too wide to show the answer is good enough: "
            + ", ".join(parts)
            + "; see uncertainty.*.se_* for the dominant source (inputs: check or re-strike "
            "them; geometry: measure positions and directions more accurately; lines: a wider band)"
        )
    return VerdictReason("precision", sev, msg)


def cross_check_checks(cc: Any) -> list[VerdictReason]:
    """The ``cross_check`` check: the mass-line estimate against the DIM's.

    ``warn`` when an item differs by more than the combined 95 % interval and the largest |z|
    is beyond the family-wise limit of the 13 items compared (the two estimators
    read different properties from the same data: one of them is misled by a channel, an input
    or a geometry the model does not describe — a mis-mounted sensor, a wrong line of action,
    elastic motion in the band), naming the items with their z-scores and the mass-line fit's
    rigid-structure test; ``warn`` when the cross-check could not be made; else ``ok``.
    ``cc`` is a :class:`dimacq.services.solve.cross_check.CrossCheck` or None (not run: no check).
    """
    if cc is None:
        return []
    if cc.fit is None:
        return [
            VerdictReason(
                "cross_check",
                "warn",
                f"the mass-line cross-check could not be made ({cc.error}); the DIM answer "
                "stands without a second estimate",
            )
        ]
    f = cc.fit
    struct = (
        f"the mass-line fit's mass matrix departs from rigid-body form by {f.structure_rel:.2g} "
        f"(χ² {f.structure_chi2:.3g} on 11 dof against noise, inputs and stated geometry)"
    )
    bad = cc.disagreements()
    limit = float(cc.family_wise_limit)
    if not bad:
        return [
            VerdictReason(
                "cross_check",
                "ok",
                f"the mass-line estimate agrees with the DIM within the combined 95 % intervals "
                f"on mass, CG, inertia about P and principal moments (mass "
                f"{f.value('m'):.6g} kg, z = {cc.z['mass']:+.2f}); {struct}",
            )
        ]
    items = ", ".join(f"{k} z = {zv:+.2f}" for k, zv in bad[:6])
    more = f" and {len(bad) - 6} more" if len(bad) > 6 else ""
    if max(abs(zv) for _, zv in bad) <= limit:
        return [
            VerdictReason(
                "cross_check",
                "ok",
                f"the mass-line estimate differs from the DIM beyond the combined 95 % interval on "
                f"{items}{more}, but within the family-wise limit |z| ≤ {limit:.3g} of the 13 "
                "items compared (one item outside its own 95 % interval is expected by chance "
                f"in many solves); {struct}",
            )
        ]
    return [
        VerdictReason(
            "cross_check",
            "warn",
            f"the mass-line estimate disagrees with the DIM beyond the combined 95 % intervals "
            f"on {items}{more} (family-wise limit |z| ≤ {limit:.3g} over the 13 items "
            "compared): the two estimators read different properties from the same "
            "data, so a channel, an input or the geometry does not follow the rigid-body model "
            "as stated (a mis-mounted or mis-oriented sensor, a wrong line of action, elastic "
            f"motion in the band); {struct}. Check the setup against the FRFs "
            "(dimacq solve --select-responses, --plots) before using either answer",
        )
    ]
