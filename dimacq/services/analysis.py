"""Analysis service: band → response selection → orientation repair → input selection → solve →
uncertainty → figures, with every decision recorded in the report.

Used by ``dimacq solve`` (``--select-responses``, ``--select-inputs``, ``--repair-orientation``,
``--auto-band``, ``--plots DIR``) and by the REST API. Pure orchestration over
:mod:`dimacq.pipeline` (no devices, no threads); the only I/O is writing figures when asked.

Order of the steps and why
--------------------------
1. Band: given, automatic (:func:`~dimacq.pipeline.selection.band.suggest_band`), or the whole span.
   An automatic band is suggested again after the selections (step 5) on the selected data, and
   the solve uses that second suggestion.
2. Perimeter response selection on the band (gross channel errors first, so that they do not
   corrupt the orientation fit of their node).
3. Orientation repair of the kept channels (only when asked; the setup given to the solver then
   carries the corrected directions and the report says so).
4. Jackknife excitation selection on the assembled system of the kept channels.
5. Joint DIM solve, uncertainty from the input jackknife, a delete-one-sensor-node jackknife and
   the line spread.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from dimacq.errors import SetupError
from dimacq.model.frf import Channel, FrfData
from dimacq.model.setup import TestSetup
from dimacq.pipeline.dim import DimResult, DimSystem, assemble, solve_system
from dimacq.pipeline.selection._common import match_pairs, response_geometry
from dimacq.pipeline.selection.band import BandSuggestion, suggest_band
from dimacq.pipeline.selection.inputs import (
    ExcitationCheck,
    JackknifeSelection,
    excitation_check,
    jackknife_inputs,
)
from dimacq.pipeline.selection.orientation import (
    OrientationRepair,
    apply_orientation,
    estimate_orientation_frf,
)
from dimacq.pipeline.selection.responses import ResponseSelection, select_responses_frf
from dimacq.pipeline.uncertainty import Uncertainty, estimate_uncertainty

__all__ = ["AnalysisOptions", "AnalysisReport", "analyse"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class AnalysisOptions:
    """What :func:`analyse` should do.

    Attributes
    ----------
    select_responses : bool
        Automatic perimeter response selection.
    select_inputs : bool
        Jackknife excitation selection.
    repair_orientation : bool
        Estimate one small rotation per sensor node and apply it to the setup.
    auto_band : bool
        Suggest the band automatically (overrides ``band_hz``).
    plots_dir : Path, optional
        Write the figures (PNG and SVG) there.
    band_hz : (lo, hi), optional
        Analysis band when ``auto_band`` is off; default the whole span.
    known : dict, optional
        Known properties (``m``, ``cx``.., ``Ixx``..); default ``setup.known``.
    length_unit : {"m", "cm", "mm"}, optional
        Default ``setup.length_unit``.
    force_in, force_out : list of (node, direction)
        Channels or inputs the user keeps / drops whatever the selection says. A pair applies to
        the response channel and to the input it names (either sign of the direction).
    uncertainty_method : {"jackknife", "bootstrap"}
    """

    select_responses: bool = False
    select_inputs: bool = False
    repair_orientation: bool = False
    auto_band: bool = False
    plots_dir: Path | None = None
    band_hz: tuple[float, float] | None = None
    known: Mapping[str, float] | None = None
    length_unit: str | None = None
    force_in: Sequence[tuple[int, int]] = ()
    force_out: Sequence[tuple[int, int]] = ()
    uncertainty_method: str = "jackknife"


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
            }
        )
        if self.response_selection is not None:
            out["response_selection"] = self.response_selection.to_json()
        if self.input_selection is not None:
            out["input_selection"] = self.input_selection.to_json()
        return out


def _ch(c: Channel) -> dict[str, int]:
    return {"node": int(c.node), "direction": int(c.direction)}


def analyse(
    frf: FrfData, setup: TestSetup, options: AnalysisOptions | None = None
) -> AnalysisReport:
    """Run selection → solve → uncertainty → figures (module docstring).

    Raises
    ------
    SetupError, DataError
        Bad setup, options or data (messages name the item and the fix).
    SolverError
        The kept data cannot be solved (rank < 6 ...).
    """
    opt = options or AnalysisOptions()
    known = dict(setup.known.as_dict() if opt.known is None else opt.known)
    force_in = [tuple(map(int, p)) for p in opt.force_in]
    force_out = [tuple(map(int, p)) for p in opt.force_out]
    if set(force_in) & set(force_out):
        raise SetupError(
            f"{sorted(set(force_in) & set(force_out))[0]} is both forced in and forced out; choose one"
        )
    geo_all = response_geometry(frf, setup)
    w0 = (~match_pairs(force_out, geo_all.channels)).astype(float)  # type: ignore[arg-type]
    in_out = match_pairs(force_out, frf.inputs)  # type: ignore[arg-type]
    in_in = match_pairs(force_in, frf.inputs)  # type: ignore[arg-type]

    # 1. band ------------------------------------------------------------------------------
    suggestion: BandSuggestion | None = None
    if opt.auto_band:
        suggestion = suggest_band(frf, setup, known=known, response_weights=w0, input_keep=~in_out)
        band = suggestion.band_hz
        band_sel = suggestion.to_json()
    elif opt.band_hz is not None:
        band = (float(opt.band_hz[0]), float(opt.band_hz[1]))
        band_sel = {"band_hz": list(band), "reason": "given by the user", "automatic": False}
    else:
        band = (float(frf.frequencies_hz[0]), float(frf.frequencies_hz[-1]))
        band_sel = {
            "band_hz": list(band),
            "reason": "whole measured span (no band given; use --auto-band for a suggestion)",
            "automatic": False,
        }
    data = frf.band(*band)

    # 2. responses -------------------------------------------------------------------------
    rsel: ResponseSelection | None = None
    weights = w0
    if opt.select_responses:
        rsel, _ = select_responses_frf(data, setup, force_in=force_in, force_out=force_out)  # type: ignore[arg-type]
        weights = rsel.weights
    excluded_resp = [_ch(geo_all.channels[i]) for i in np.nonzero(weights == 0)[0]]
    if rsel is not None:  # keep the order of removal
        excluded_resp = [_ch(c) for c in rsel.excluded]

    # 3. orientation -----------------------------------------------------------------------
    setup_used = setup
    repair: OrientationRepair | None = None
    if opt.repair_orientation:
        repair, geo_b = estimate_orientation_frf(data, setup, active=weights > 0)
        setup_used = apply_orientation(setup, repair, geo_b)
        repair = OrientationRepair(**{**repair.__dict__, "applied": True})
        log.info(
            "orientation repair applied: %s",
            ", ".join(
                f"{n}: {a:.2f}°" for n, a in zip(repair.nodes, repair.angles_deg, strict=True)
            ),
        )

    # 4. inputs ----------------------------------------------------------------------------
    system = assemble(data, setup_used, length_unit=opt.length_unit, response_weights=weights)
    jsel: JackknifeSelection | None = None
    keep_in = ~in_out
    if opt.select_inputs:
        jsel = jackknife_inputs(system, known=known, force_in=in_in, force_out=in_out)
        keep_in = jsel.keep
        excluded_in = [_ch(c) for c in jsel.excluded]
    else:
        excluded_in = [_ch(frf.inputs[i]) for i in np.nonzero(in_out)[0]]
    keep_idx = np.nonzero(keep_in)[0]
    if suggestion is not None and (rsel is not None or jsel is not None or repair is not None):
        # the first suggestion saw every channel and input; suggest again on the selected data
        suggestion = suggest_band(
            frf, setup_used, known=known, response_weights=weights, input_keep=keep_in
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
    result = solve_system(system_used, known=known)
    nodes = geo_all.nodes
    resp_systems: list[DimSystem] = []
    for g in np.unique(nodes[weights > 0]):
        wg = weights * (nodes != g)
        try:
            resp_systems.append(
                assemble(
                    data, setup_used, length_unit=opt.length_unit, response_weights=wg
                ).select_inputs(keep_idx)
            )
        except SetupError:
            log.info(
                "leaving out sensor node %s drops the response rank; not used for the uncertainty",
                g,
            )
    unc = estimate_uncertainty(
        system_used,
        result,
        known=known,
        method="bootstrap" if opt.uncertainty_method == "bootstrap" else "jackknife",
        response_systems=resp_systems,
    )
    exc = excitation_check(_phi_m(system_used))
    result = _with_extras(result, rsel, jsel, repair)

    report = AnalysisReport(
        result=result,
        excluded_responses=excluded_resp,
        excluded_inputs=excluded_in,
        uncertainty=unc,
        orientation_corrections=repair.to_json() if repair is not None else [],
        band_selection=band_sel,
        excitation=exc,
        setup_used=setup_used,
        response_selection=rsel,
        input_selection=jsel,
        band_suggestion=suggestion,
        orientation=repair,
    )
    if opt.plots_dir is not None:
        from dimacq.plotting import write_report_figures

        paths = write_report_figures(report, frf, setup_used, Path(opt.plots_dir), weights, keep_in)
        report = AnalysisReport(**{**report.__dict__, "plots": paths})
    return report


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
    from dataclasses import replace

    extras = dict(result.extras)
    extras["selection_applied"] = {
        "responses": rsel is not None,
        "inputs": jsel is not None,
        "orientation_repair": repair is not None and repair.applied,
    }
    return replace(result, extras=extras)
