"""The interval steps of the analysis: the stated geometry through the joint solve
(:func:`geometry_step`) and the 95 % intervals from the inputs, the sensor nodes and the geometry
(:func:`uncertainty_step`).

:func:`dimacq.services.solve.analysis.analyse` runs them after the equation-error solve of the
kept data (its module docstring, step 5). ``opt`` is its
:class:`~dimacq.services.solve.analysis.AnalysisOptions` (this module reads ``length_unit``,
``uncertainty_method`` and ``geometry_samples``); it is not imported here, so that the analysis
that composes these steps is never imported by them.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from dataclasses import replace
from typing import Any

import numpy as np

from dimacq.errors import SetupError
from dimacq.model.frf import FrfData
from dimacq.model.setup import TestSetup
from dimacq.pipeline.dim import DimResult, DimSystem, assemble
from dimacq.pipeline.selection._common import response_geometry
from dimacq.pipeline.uncertainty import GeometrySpread, estimate_uncertainty, geometry_spread

__all__ = ["geometry_step", "uncertainty_step"]

#: the analysis's logger, whose steps these were: the messages keep its name
log = logging.getLogger("dimacq.services.solve.analysis")


def uncertainty_step(
    data: FrfData,
    setup_used: TestSetup,
    system_used: DimSystem,
    result: DimResult,
    known: dict[str, float],
    opt: Any,
    nodes: np.ndarray,
    weights: np.ndarray,
    keep_idx: np.ndarray,
    geo: GeometrySpread | None,
) -> Any:
    """The 95 % intervals: resampling of the inputs, leave-one-sensor-node-out and geometry.

    The leave-one-node-out systems (K and F of every line: 6 MB each on an acquired test) live
    only as long as this step, not through the output-error fit and the cross-check.
    """
    resp_systems: list[DimSystem] = []
    n_node_rank = 0
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
        geometry=geo,
    )
    del resp_systems
    if n_node_rank:
        unc = replace(unc, n_rank_deficient=unc.n_rank_deficient + n_node_rank)
    return unc


def geometry_step(
    data: FrfData,
    setup: TestSetup,
    system: DimSystem,
    weights: np.ndarray,
    keep_idx: np.ndarray,
    known: Mapping[str, float],
    opt: Any,
) -> GeometrySpread:
    """The setup's stated geometry uncertainty through the joint solve of the kept data."""
    geo = response_geometry(data, setup)
    ex_key = {(e.node, e.direction): e for e in setup.excitations}
    in_pos, in_dir = [], []
    for j in keep_idx:
        ch = data.inputs[int(j)]
        ex = ex_key.get((ch.node, ch.direction)) or ex_key.get((ch.node, -ch.direction))
        assert ex is not None and ex.direction_gcs is not None  # assemble checked it
        sign = 1.0 if ex.direction == ch.direction else -1.0
        in_pos.append(ex.position_m)
        in_dir.append(sign * np.asarray(ex.direction_gcs, float))
    gu = setup.geometry_uncertainty
    H_acc = data.H[:, geo.output_index][:, :, keep_idx]
    return geometry_spread(
        system,
        H_acc,
        geo.positions_m,
        geo.directions,
        geo.nodes,
        np.asarray(weights, float),
        np.asarray(in_pos, float),
        np.asarray(in_dir, float),
        sensor_position_m=gu.sensor_position_m,
        sensor_orientation_deg=gu.sensor_orientation_deg,
        input_position_m=gu.input_position_m,
        line_of_action_deg=gu.line_of_action_deg,
        registration_rms_m=gu.registration_rms_m,
        accel_sensitivity_rel=setup.transducer_uncertainty.accel_sensitivity_rel,
        force_sensitivity_rel=setup.transducer_uncertainty.force_sensitivity_rel,
        known=known,
        n_samples=opt.geometry_samples,
    )
