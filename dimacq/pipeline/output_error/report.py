"""What the output-error solve is asked and what it answers.

Holds :class:`OutputErrorOptions` and :class:`OutputErrorResult` (the estimate with its evidence,
and its JSON), and the parts of the report formed from a fit: the size of fitted residual terms
(RMS of ``G b(ω)`` relative to the RMS of the FRFs, :func:`residual_size`), the sensor and input
corrections with their standard deviations or the reason they were not estimated
(:func:`corrections`), and the setup with the refined geometry (:func:`refined_setup`:
``d_c = exp([δθ_n]x) d_c⁰``, ``r_c = r_c⁰ + δp_n`` per sensor node; inputs moved and turned).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from dimacq.model.frf import Channel
from dimacq.model.setup import PARAMETERS, TestSetup
from dimacq.pipeline._batched import cross3
from dimacq.pipeline.output_error.model import CELL_PARAMS, Problem, mass_matrix
from dimacq.pipeline.rotations import apply_rotvec, rotvec_to_matrix

FloatArray = NDArray[np.float64]
ComplexArray = NDArray[np.complex128]


# ------------------------------------------------------------------------------------------
# Options and result
# ------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class OutputErrorOptions:
    """What :func:`solve_output_error` estimates.

    Attributes
    ----------
    refine_geometry : bool
        Estimate sensor rotations and offsets and input lines of action (priors from
        ``setup.geometry_uncertainty``). Off: the stated geometry is taken as exact.
    residual_flexibility : bool or None
        ``True``: fit the residual terms (and report the Hausman test of whether they were
        needed); ``False`` (default): never; ``None`` (auto): keep them only when the test says so.
        When they are kept, the difference of the properties with and without them is added to
        the covariance as a model-form term (``dx dxᵀ``).
    refine_positions : bool
        Include the sensor position offsets (where identified).
    refine_load_cells : bool
        With the geometry, turn and move each load cell within its stated uncertainty
        (``load_cell_orientation_deg``, ``load_cell_position_m``), so that the instrumentation's
        similarity is again a symmetry of the model and the fixed gauge holds. Off: the cells
        are exact, and their reactions alone tie the scale of the sensors against the inputs'
        (the fixed scale gauge then lets a reaction error move the principal moments: a
        bungee-hung mass through the simulated lab came out 0.3–0.5 % low, seeds 3, 5, 7 of
        ``netft-udp-simulated``).
    refuse_ratio : float
        A geometry parameter whose posterior σ exceeds this fraction of its prior σ is not
        estimated (not identified by the data).
    max_iterations : int
    max_correction_sigma : float
        A refined correction beyond this many stated σ is a gross error: the item (sensor node or
        input) is left out and the solve repeated, at most ``max_gross_items`` times; beyond
        that the model, not the geometry, is wrong: the refinement is refused.
    max_gross_items : int
    fix_gauge : bool
        Fix the gauge modes the data do not identify (:func:`gauge_constraint`) and add their
        prior variance to the properties' covariance; off: the priors alone hold them.
    gauge_from_reactions : bool
        Let the load-cell reactions identify a common translation or rotation of the
        instrumentation (estimated where their information passes ``refuse_ratio``). Off
        (default): every similarity mode is fixed at the stated geometry's. The reactions tie the
        instrumentation only to the load cells' *stated* positions and orientations, which are
        measured geometry too (digitized or drawn, as uncertain as a sensor's): they cannot pin
        the frame better than those, and a misfit that is not geometry (a load-cell chain error,
        gauge noise on a cell that carries almost no reaction, channel gains) projects onto the
        common translation as if it were information. Seen on acquired data: a bungee-
        hung calibration mass, reactions at noise level, came out with the CG moved 5 mm along a
        "identified" translation, intervals 0.5 mm wide, verdict ok; with the frame fixed, 0.2 mm.
        The scale and the common accelerometer gain are fixed either way
        (:func:`gauge_constraint`).
    geometry_test : bool
        Test whether the data need the geometry moved at all (:func:`geometry_needed`): when
        the channel gains alone explain the misfit as well, the stated geometry is kept and its
        stated uncertainty propagated into the intervals (default on).
    """

    refine_geometry: bool = True
    residual_flexibility: bool | None = False
    refine_positions: bool = True
    refine_load_cells: bool = True
    refuse_ratio: float = 0.9
    max_iterations: int = 30
    max_correction_sigma: float = 6.0
    max_gross_items: int = 3
    fix_gauge: bool = True
    gauge_from_reactions: bool = False
    geometry_test: bool = True


@dataclass(frozen=True, eq=False)
class OutputErrorResult:
    """The output-error estimate with its evidence.

    Attributes
    ----------
    parameters : ndarray, shape (10,)
        ``[m, cx, cy, cz, Ixx..Izz]``: CG in the GCS (m), inertia about P (kg·m²).
    covariance : ndarray, shape (10, 10)
        Posterior covariance (geometry marginalised, scaled by ``max(1, χ²_red)``, registration
        residual added to the CG); zero rows for known properties.
    covariance_noise : ndarray, shape (10, 10)
        The same with the geometry held at its estimate: the noise's share; the difference is
        the geometry's (priors, gauge, registration).
    sensor_corrections, input_corrections, load_cell_corrections : list of dict
        Each correction with its standard deviation, or the reason it was not estimated.
    residual_flexibility : dict
        ``fitted``, ``needed``, the likelihood-ratio statistic and the size of the residual.
    noise : dict
        Median FRF noise relative to the band RMS, reduced χ², how σ was estimated.
    setup : TestSetup
        The setup with the refined geometry.
    refine_geometry : bool
        Whether the geometry was refined (False when asked but refused).
    """

    parameters: FloatArray
    covariance: FloatArray
    covariance_noise: FloatArray
    chi2_reduced: float
    iterations: int
    elapsed_s: float
    sensor_corrections: list[dict[str, Any]]
    input_corrections: list[dict[str, Any]]
    residual_flexibility: dict[str, Any]
    noise: dict[str, Any]
    gauge: str
    setup: TestSetup
    refine_geometry: bool
    n_inputs: int
    gross_errors: list[dict[str, Any]] = field(default_factory=list)
    response_weights: FloatArray | None = None
    input_keep: NDArray[np.bool_] | None = None
    extras: dict[str, Any] = field(default_factory=dict)
    load_cell_corrections: list[dict[str, Any]] = field(default_factory=list)

    @property
    def standard_errors(self) -> FloatArray:
        return np.sqrt(np.clip(np.diag(self.covariance), 0.0, None))

    def to_json(self) -> dict[str, Any]:
        se = self.standard_errors
        return {
            "estimator": "output-error",
            "refine_geometry": self.refine_geometry,
            "parameters": {k: float(v) for k, v in zip(PARAMETERS, self.parameters, strict=True)},
            "standard_errors": {k: float(v) for k, v in zip(PARAMETERS, se, strict=True)},
            "chi2_reduced": self.chi2_reduced,
            "iterations": self.iterations,
            "elapsed_s": self.elapsed_s,
            "gauge": self.gauge,
            "sensor_corrections": self.sensor_corrections,
            "load_cell_corrections": self.load_cell_corrections,
            "input_corrections": self.input_corrections,
            "residual_flexibility": self.residual_flexibility,
            "noise": self.noise,
            "gross_errors": list(self.gross_errors),
            "gauge_modes": self.extras.get("gauge", {}),
            "adequacy": self.extras.get("adequacy", {}),
            "geometry_test": self.extras.get("geometry_test", {}),
        }


def rf_mode_label(mode: bool | None) -> str:
    """The residual-flexibility option as reported: ``None`` "auto", ``True`` "on", ``False`` "off"."""
    return "auto" if mode is None else ("on" if mode else "off")


def residual_size(
    prob: Problem,
    theta: FloatArray,
    H: ComplexArray,
    R: ComplexArray,
    sigma: FloatArray,
    basis: ComplexArray,
) -> dict[str, Any]:
    """Fitted residual terms: RMS of ``G b(ω)`` relative to the RMS of the FRFs, median and max
    over channels and inputs."""
    x = prob.full_x(theta)
    gfull = prob.full_g(theta)
    r, d, rin, din = prob.geometry(gfull)
    A = np.linalg.inv(mass_matrix(x)[0])
    psi = np.concatenate([d, cross3(r, d)], axis=1)
    phi = np.concatenate([din, cross3(rin, din)], axis=1)
    Rp = prob.reactions_at_p(gfull, R)
    mot = np.einsum("ab,ljb->lja", A, phi[None] + np.moveaxis(Rp, 1, 2))  # (L, J, 6)
    rigid = np.einsum("ca,lja->lcj", psi, mot)
    e = H - rigid
    Bm = basis.real  # (L, nb)
    coef = np.linalg.lstsq(Bm, np.real(e).reshape(e.shape[0], -1), rcond=None)[0]
    fitted = (Bm @ coef).reshape(e.shape)
    rel = np.sqrt(np.mean(fitted**2, axis=0)) / np.sqrt(np.mean(np.abs(H) ** 2, axis=0))
    return {
        "relative_rms_median": float(np.median(rel)),
        "relative_rms_max": float(np.max(rel)),
        "basis": "(ω/ω_hi)², (ω/ω_hi)⁴ per channel and input",
    }


def corrections(
    g: FloatArray,
    se: FloatArray,
    sig: FloatArray,
    prob: Problem,
    refused: list[int],
    inputs: tuple[Channel, ...],
    in_idx: NDArray[np.intp],
    refine: bool,
    note: str,
    cell_nodes: tuple[int, ...] = (),
) -> tuple[list[dict[str, Any]], list[dict[str, Any]], list[dict[str, Any]]]:
    """The sensor nodes', inputs' and load cells' corrections (in that order) with their
    standard deviations, priors and status."""
    nn = prob.n_nodes
    free = set(int(i) for i in prob.free_g)
    ref = set(refused)

    def status(idx: list[int]) -> tuple[bool, str]:
        if not refine:
            return False, "geometry refinement off: stated value used"
        if note:
            return False, note
        if all(i in free for i in idx):
            return True, "estimated"
        if any(i in ref for i in idx):
            return False, (
                "not identified by the data (posterior σ above the stated prior's "
                "refuse ratio): stated value kept"
            )
        return False, "no stated uncertainty (prior σ = 0): stated value kept"

    def pose(node: int, b: int, rot: tuple[bool, str], off: tuple[bool, str]) -> dict[str, Any]:
        """A rotation (``g[b:b+3]``, rad) and an offset (``g[b+3:b+6]``, m) with their σ and
        their ``(estimated, status)``."""
        (ok_r, why_r), (ok_p, why_p) = rot, off
        return {
            "node": int(node),
            "rotation_deg": np.rad2deg(g[b : b + 3]).tolist(),
            "rotation_se_deg": np.rad2deg(se[b : b + 3]).tolist(),
            "rotation_prior_deg": float(np.rad2deg(sig[b])),
            "rotation_status": why_r,
            "rotation_estimated": ok_r,
            "offset_mm": (1e3 * g[b + 3 : b + 6]).tolist(),
            "offset_se_mm": (1e3 * se[b + 3 : b + 6]).tolist(),
            "offset_prior_mm": float(1e3 * sig[b + 3]),
            "offset_status": why_p,
            "offset_estimated": ok_p,
        }

    sens = []
    for n in range(nn):
        b = 6 * n
        sens.append(
            pose(prob.nodes[n], b, status(list(range(b, b + 3))), status(list(range(b + 3, b + 6))))
        )
    inps = []
    for k, j in enumerate(in_idx):
        b = 6 * nn + 4 * k
        ok_d, why_d = status([b, b + 1])
        ok_o, why_o = status([b + 2, b + 3])
        inps.append(
            {
                "node": int(inputs[j].node),
                "direction": int(inputs[j].direction),
                "line_of_action_deg": float(np.rad2deg(np.hypot(g[b], g[b + 1]))),
                "line_of_action_components_deg": np.rad2deg(g[b : b + 2]).tolist(),
                "line_of_action_se_deg": np.rad2deg(se[b : b + 2]).tolist(),
                "line_of_action_status": why_d,
                "line_of_action_estimated": ok_d,
                "offset_mm": float(1e3 * np.hypot(g[b + 2], g[b + 3])),
                "offset_components_mm": (1e3 * g[b + 2 : b + 4]).tolist(),
                "offset_se_mm": (1e3 * se[b + 2 : b + 4]).tolist(),
                "offset_status": why_o,
                "offset_estimated": ok_o,
            }
        )
    cells = []
    for k, node in enumerate(cell_nodes):
        b = prob.cell_base + CELL_PARAMS * k
        ok_r, why_r = status(list(range(b, b + 3)))
        ok_p, why_p = status(list(range(b + 3, b + 6)))
        ok_g, why_g = status(list(range(b + 6, b + 9)))
        if refine and not note and not np.any(sig[b : b + 9] > 0):
            held = "held at its stated pose and calibration (load cells not refined)"
            why_r = why_p = why_g = held
        cells.append(
            {
                **pose(node, b, (ok_r, why_r), (ok_p, why_p)),
                "moment_gain_pct": (100 * g[b + 6 : b + 9]).tolist(),
                "moment_gain_se_pct": (100 * se[b + 6 : b + 9]).tolist(),
                "moment_gain_prior_pct": float(100 * sig[b + 6]),
                "moment_gain_status": why_g,
                "moment_gain_estimated": ok_g,
            }
        )
    return sens, inps, cells


def refined_setup(
    setup: TestSetup,
    geo: Any,
    active: NDArray[np.bool_],
    prob: Problem,
    g: FloatArray,
    inputs: tuple[Channel, ...],
    in_idx: NDArray[np.intp],
    p: FloatArray,
    cell_nodes: tuple[int, ...] = (),
) -> TestSetup:
    """The setup with the refined sensor (all channels of a refined node), input and load cell
    geometry."""
    nn = prob.n_nodes
    gs = g[: 6 * nn].reshape(nn, 6)
    by_node = {int(n): gs[i] for i, n in enumerate(prob.nodes)}
    responses = []
    for c in setup.responses:
        corr = by_node.get(int(c.node))
        if corr is None:
            responses.append(c)
            continue
        d = apply_rotvec(corr[:3], np.asarray(c.direction_gcs))
        responses.append(
            c.model_copy(
                update={
                    "direction_gcs": tuple(float(v) for v in d / np.linalg.norm(d)),
                    "position_m": tuple(float(v) for v in np.asarray(c.position_m) + corr[3:]),
                }
            )
        )
    _, _, rin, din = prob.geometry(g)
    moved = {}
    for k, j in enumerate(in_idx):
        ch = inputs[j]
        moved[(ch.node, abs(ch.direction))] = (rin[k] + p, din[k], ch.direction)
    excitations = []
    for e in setup.excitations:
        hit = moved.get((e.node, abs(e.direction)))
        if hit is None:
            excitations.append(e)
            continue
        pos, dv, rec_dir = hit
        s = 1.0 if rec_dir == e.direction else -1.0
        excitations.append(
            e.model_copy(
                update={
                    "position_m": tuple(float(v) for v in pos),
                    "direction_gcs": tuple(float(v) for v in s * dv / np.linalg.norm(dv)),
                }
            )
        )
    load_cells = list(setup.load_cells)
    if cell_nodes:
        gc = g[prob.cell_base : prob.gain_base].reshape(-1, CELL_PARAMS)
        Q = rotvec_to_matrix(gc[:, :3])
        at = {int(n): k for k, n in enumerate(cell_nodes)}
        for i, lc in enumerate(load_cells):
            kc = at.get(int(lc.node))
            if kc is None:
                continue
            rot = Q[kc] @ np.asarray(lc.rotation_matrix, float)
            load_cells[i] = lc.model_copy(
                update={
                    "position_m": tuple(float(v) for v in np.asarray(lc.position_m) + gc[kc, 3:6]),
                    "rotation": tuple(tuple(float(v) for v in row) for row in rot),
                }
            )
    return setup.model_copy(
        update={
            "responses": tuple(responses),
            "excitations": tuple(excitations),
            "load_cells": tuple(load_cells),
        }
    )
