"""The selection steps of the analysis: band, responses, orientation, inputs, and the second band.

:func:`dimacq.services.solve.analysis.analyse` runs them in this order (its module docstring says
why): :func:`first_band` picks the band to start from, :func:`selected_responses` keeps the
channels that follow the rigid-body motion, :func:`repaired_orientation` corrects the kept sensors'
directions, :func:`selected_inputs` keeps the excitations the jackknife trusts, and
:func:`second_suggestion` suggests the band again on what was kept, never above the first pass's
elastic ceiling (:func:`below_first_elastic_ceiling`). Each step returns what it decided and the
record the report keeps of it.

``opt`` is the :class:`~dimacq.services.solve.analysis.AnalysisOptions` of the solve (this module
reads its ``band_hz``, ``auto_band``, ``select_responses``, ``repair_orientation`` and
``select_inputs``); it is not imported here, so that the analysis that composes these steps is
never imported by them.
"""

from __future__ import annotations

import logging
from dataclasses import replace
from typing import Any

import numpy as np

from dimacq.errors import SetupError
from dimacq.model.frf import Channel, FrfData
from dimacq.model.setup import TestSetup
from dimacq.pipeline.dim import DimSystem
from dimacq.pipeline.selection.band import MIN_BAND_LINES, BandSuggestion, suggest_band
from dimacq.pipeline.selection.inputs import JackknifeSelection, jackknife_inputs
from dimacq.pipeline.selection.orientation import (
    OrientationRepair,
    apply_orientation,
    estimate_orientation_frf,
)
from dimacq.pipeline.selection.responses import ResponseSelection, select_responses_frf

__all__ = [
    "below_first_elastic_ceiling",
    "first_band",
    "repaired_orientation",
    "second_suggestion",
    "selected_inputs",
    "selected_responses",
]

log = logging.getLogger(__name__)


def _ch(c: Channel) -> dict[str, int]:
    return {"node": int(c.node), "direction": int(c.direction)}


def first_band(
    frf: FrfData,
    setup: TestSetup,
    opt: Any,
    known: dict[str, float],
    w0: np.ndarray,
    in_out: np.ndarray,
) -> tuple[tuple[float, float], dict[str, Any], BandSuggestion | None]:
    """The band to start from: the one given, the automatic suggestion on every channel and
    input not forced out, or the whole measured span; with its ``band_selection`` record."""
    if opt.band_hz is not None:
        band = (float(opt.band_hz[0]), float(opt.band_hz[1]))
        if not band[0] < band[1]:
            raise SetupError(f"band {band[0]:g}–{band[1]:g} Hz is empty; give LO < HI in Hz")
        return (
            band,
            {"band_hz": list(band), "reason": "given by the user", "automatic": False},
            None,
        )
    if opt.auto_band:
        suggestion = suggest_band(frf, setup, known=known, response_weights=w0, input_keep=~in_out)
        return suggestion.band_hz, suggestion.to_json(), suggestion
    band = (float(frf.frequencies_hz[0]), float(frf.frequencies_hz[-1]))
    band_sel = {
        "band_hz": list(band),
        "reason": "whole measured span (automatic band turned off and no band given)",
        "automatic": False,
    }
    return band, band_sel, None


def selected_responses(
    data: FrfData,
    setup: TestSetup,
    opt: Any,
    force_in: list[tuple[int, ...]],
    force_out: list[tuple[int, ...]],
    w0: np.ndarray,
    geo_all: Any,
) -> tuple[ResponseSelection | None, np.ndarray, list[dict[str, int]]]:
    """Perimeter response selection when asked: the selection, the channel weights and the
    excluded channels (in the order of removal when selected)."""
    rsel: ResponseSelection | None = None
    weights = w0
    if opt.select_responses:
        rsel, _ = select_responses_frf(data, setup, force_in=force_in, force_out=force_out)  # type: ignore[arg-type]
        weights = rsel.weights
    excluded_resp = [_ch(geo_all.channels[i]) for i in np.nonzero(weights == 0)[0]]
    if rsel is not None:  # keep the order of removal
        excluded_resp = [_ch(c) for c in rsel.excluded]
    return rsel, weights, excluded_resp


def repaired_orientation(
    data: FrfData, setup: TestSetup, opt: Any, weights: np.ndarray
) -> tuple[TestSetup, OrientationRepair | None]:
    """Sensor orientation repair when asked: the setup with the repair applied, and the repair."""
    if not opt.repair_orientation:
        return setup, None
    repair, geo_b = estimate_orientation_frf(data, setup, active=weights > 0)
    setup_used = apply_orientation(setup, repair, geo_b)
    repair = OrientationRepair(**{**repair.__dict__, "applied": True})
    log.info(
        "orientation repair applied: %s",
        ", ".join(f"{n}: {a:.2f}°" for n, a in zip(repair.nodes, repair.angles_deg, strict=True)),
    )
    return setup_used, repair


def selected_inputs(
    system: DimSystem,
    frf: FrfData,
    opt: Any,
    known: dict[str, float],
    in_in: np.ndarray,
    in_out: np.ndarray,
) -> tuple[JackknifeSelection | None, np.ndarray, list[dict[str, int]]]:
    """Jackknife input selection when asked: the selection, the inputs kept, the excluded ones."""
    if opt.select_inputs:
        jsel = jackknife_inputs(system, known=known, force_in=in_in, force_out=in_out)
        return jsel, jsel.keep, [_ch(c) for c in jsel.excluded]
    return None, ~in_out, [_ch(frf.inputs[i]) for i in np.nonzero(in_out)[0]]


def second_suggestion(
    frf: FrfData,
    setup_used: TestSetup,
    known: dict[str, float],
    first: BandSuggestion | None,
    unchanged: bool,
    weights: np.ndarray,
    keep_in: np.ndarray,
) -> BandSuggestion:
    """The band suggested again on the selected channels and inputs (and repaired setup).

    When the selection kept every channel and input, the second pass would see exactly what
    the first saw and repeat its answer (a deterministic function of the data): the first is
    kept. The second stays below the first's elastic ceiling.
    """
    if first is not None and unchanged:
        suggestion = first
    else:
        suggestion = suggest_band(
            frf, setup_used, known=known, response_weights=weights, input_keep=keep_in
        )
    if first is not None:
        suggestion = below_first_elastic_ceiling(suggestion, first)
    return suggestion


def below_first_elastic_ceiling(second: BandSuggestion, first: BandSuggestion) -> BandSuggestion:
    """The second band suggestion (on the selected channels and inputs), kept below the first's
    upper edge when the first found an elastic mode above its band.

    Response selection drops the channels that do not follow the rigid-body motion, among them
    the sensors on an elastic part near its resonance; the lines where the whole array showed
    that part moving on its own then look rigid to the kept channels. The part's unmeasured
    inertia force still acts on the body there (the DIM would see a different, smaller body), so
    the evidence of the whole array stands: the band may move or widen below the first pass's
    upper edge, not above it. Measured on the X-38-like vehicle with drogue-chute modes at
    17 / 24 Hz (``tests/scripts/accuracy_must_show.py``): without this the second pass moved to
    11.4–15.1 Hz (the chute sensors dropped) and the CG came out 6 mm off, 10 σ outside its
    interval. If fewer than :data:`MIN_BAND_LINES` lines are left, the first band is kept.
    """
    hi1 = first.band_hz[1]
    if not first.qualified or not any(f > hi1 for f in first.deformation_peaks_hz):
        return second
    lo2, hi2 = second.band_hz
    if hi2 <= hi1:
        return second
    f = second.frequencies_hz
    lo, hi = (lo2, hi1) if lo2 < hi1 else first.band_hz
    inside = (f >= lo - 1e-9) & (f <= hi + 1e-9)
    if inside.sum() < MIN_BAND_LINES:
        lo, hi = first.band_hz
        inside = (f >= lo - 1e-9) & (f <= hi + 1e-9)
    modes = ", ".join(f"{m:g}" for m in first.deformation_peaks_hz if m > hi1)
    reason = (
        f"{lo:g}–{hi:g} Hz: the selected data suggested {lo2:g}–{hi2:g} Hz, but with every channel "
        f"the lines above {hi1:g} Hz did not move rigidly (elastic modes at {modes} Hz; their "
        "sensors were dropped by the selection, their inertia force still acts on the body): "
        "the band stays below"
    )
    res = second.residual
    return replace(
        second,
        band_hz=(float(lo), float(hi)),
        reason=reason,
        band_rigid_body_error=float(np.max(second.rigid_body_error[inside])),
        band_residual=float(np.median(res[inside])) if res is not None else second.band_residual,
    )
