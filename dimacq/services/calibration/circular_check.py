"""The circular check of a load cell's installed calibration (thesis §4.1): DIM on the
calibration mass through the matrix the amplifier applies, against the mass's certificate.

The mass is mounted as the bench file's ``[inertial] check_setup_file`` says (default: as for the
inertial calibration) and struck on the mass; the acquisition reads the cell through its
*installed* calibration file, as every acquisition does. The check can only vouch for the cell
where the cell carries a real share of the force in the band: hung on bungees above their modes
it carries the suspension's force only (a 1 % cell error moves DIM's mass by ~0.001 %:
``inconclusive``); standing on the cell (``config/calibration_mass_on_cell.toml``) it carries
the hammer's force below its mounted modes and DIM's mass is the difference of hammer and cell
forces: there a 1 % cell error moves the mass by ~2.5 %, and as much of the hammer's and
accelerometers' scale (the check compares the cell with the hammer–accelerometer chain). The
accelerometers' relative gains are taken from the rigid-body residual of the check's own FRFs
(:func:`~dimacq.pipeline.inertial_bench.rigid_body_gains`; their certificates' scatter is
amplified on the cell as on the inertial bench) before DIM.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from dimacq.config import Settings
from dimacq.errors import DataError, SetupError
from dimacq.io.loadcell_bench import BenchFile
from dimacq.io.rig_file import load_rig_file
from dimacq.model.properties import RigidBodyProperties
from dimacq.model.setup import KnownProperties, TestSetup
from dimacq.services.acquisition.rig import StrikeCallback, build_rig, run_impact_test
from dimacq.services.calibration.inertial_calibration import (
    ProgressFn,
    bench_file_of,
    calibration_mass,
    select_cell,
)

__all__ = [
    "MIN_CELL_SENSITIVITY",
    "SIMULATED_ON_CELL_SCENARIO",
    "CircularCheck",
    "cell_sensitivity",
    "chain_sensitivities",
    "check_world",
    "circular_check",
    "solution_errors",
]

log = logging.getLogger(__name__)


def solution_errors(sol: Any, props: RigidBodyProperties) -> dict[str, float]:
    """Errors of a DIM solution against reference properties: mass %, CG distance (mm) and per
    component, principal moments about the CG (%)."""
    from dimacq.model.properties import principal_moments

    est = sol.properties
    out = {"mass_pct": float(100 * (est.mass_kg - props.mass_kg) / props.mass_kg)}
    d = 1e3 * (np.asarray(est.cg_m) - np.asarray(props.cg_m))
    out["cg_error_mm"] = float(np.linalg.norm(d))
    for k, ax in enumerate("xyz"):
        out[f"c{ax}_error_mm"] = float(d[k])
    est_pm = principal_moments(est.inertia_cg_kgm2)[0]
    true_pm = principal_moments(props.inertia_cg_kgm2)[0]
    for k in range(3):
        out[f"I{k + 1}_pct"] = float(100 * (est_pm[k] - true_pm[k]) / true_pm[k])
    return out


@dataclass(frozen=True, eq=False)
class CircularCheck:
    """DIM on the calibration mass through the cell's installed calibration.

    Attributes
    ----------
    solution : DimResult
    errors_pct : dict
        Against the certificate: ``mass_pct``, ``cg_error_mm`` (and per axis), ``I1_pct`` ..
    band_hz : DIM band, Hz
    calibration_version : int
        Version of the calibration file the amplifier applied.
    tolerance_pct : float
        The check passes when ``|mass error|`` is within it (bench file).
    cell_sensitivity : float
        ``(Δm/m) / (Δc/c)``: how much the solved mass moves with a common scale error ``c`` of
        the cell's loads (:func:`cell_sensitivity`). Where the cell carries little of the force
        in the band (a soft suspension above its modes) the check cannot see the cell.
    verdict : {"ok", "fail", "inconclusive"}
    reasons : why it failed, or why it says nothing about the cell
    setup_file : str
        The mounting checked (the bench file's ``check_setup_file``).
    accel_gain_max_pct : float or None
        Largest correction of an accelerometer's certificate by the rigid-body gains applied
        before DIM (None: not identified, certificates used).
    chain_uncertainty_pct : float or None
        Expanded (k = 2) uncertainty of the mass error from the hammer's and accelerometers'
        common scales with an exact cell (:func:`chain_sensitivities` × their stated
        uncertainties): on the cell the check compares the cell with that chain, amplified.
    """

    solution: Any
    errors_pct: dict[str, float]
    band_hz: tuple[float, float]
    calibration_version: int
    tolerance_pct: float
    cell_sensitivity: float
    verdict: str
    reasons: tuple[str, ...]
    setup_file: str = ""
    accel_gain_max_pct: float | None = None
    chain_uncertainty_pct: float | None = None

    @property
    def mass_error_pct(self) -> float:
        return self.errors_pct["mass_pct"]

    def to_json(self) -> dict[str, Any]:
        return {
            "circular_mass_error_pct": self.mass_error_pct,
            "circular_errors_pct": self.errors_pct,
            "circular_dim_band_hz": list(self.band_hz),
            "circular_calibration_version": self.calibration_version,
            "circular_tolerance_pct": self.tolerance_pct,
            "circular_cell_sensitivity": self.cell_sensitivity,
            "circular_verdict": self.verdict,
            "circular_reasons": list(self.reasons),
            "circular_setup_file": self.setup_file,
            "circular_accel_gain_max_pct": self.accel_gain_max_pct,
            "circular_chain_uncertainty_pct": self.chain_uncertainty_pct,
        }


#: Below this sensitivity (mass change per unit relative error of the cell's loads) the circular
#: check cannot vouch for the cell: a 10 % matrix error would move the mass by less than 0.5 %.
MIN_CELL_SENSITIVITY = 0.05


def cell_sensitivity(frf: Any, setup: TestSetup, band_hz: tuple[float, float]) -> float:
    """``(Δm/m) / ε``: the DIM mass's relative change when every load cell output is scaled by
    ``1 + ε`` (ε = 1 %), all ten properties unknown. 1 where the cell carries the whole force
    (its matrix's scale error goes straight into the mass), about 0 where a soft suspension
    above its modes leaves the cell nearly unloaded."""
    from dimacq.pipeline import dim

    eps = 0.01
    react = np.array([k == "reaction" for k in frf.output_kinds])
    if not react.any():
        return 0.0
    H = np.array(frf.H, copy=True)
    H[:, react, :] *= 1 + eps
    m0 = dim.solve(frf, setup, known={}, band_hz=band_hz).properties.mass_kg
    m1 = dim.solve(frf.replace(H=H), setup, known={}, band_hz=band_hz).properties.mass_kg
    return float(abs(m1 - m0) / m0 / eps)


def chain_sensitivities(
    frf: Any, setup: TestSetup, band_hz: tuple[float, float]
) -> tuple[float, float]:
    """``(Δm/m) / η`` for a common scale error ``η`` (1 %) of the hammer's force and of the
    accelerometers, all ten properties unknown: a hammer reading ``1 + η`` divides every FRF by
    it; accelerometers reading ``1 + η`` scale the acceleration FRFs. Free (or hung) +1 and −1:
    DIM's mass is force over acceleration; with the cell's sensitivity ``s_c``
    (:func:`cell_sensitivity`) the hammer's is ``1 − s_c`` (hammer and cell read high together:
    every force scaled), −1.45 standing on the cell in 20–400 Hz.
    """
    from dimacq.pipeline import dim

    eps = 0.01
    acc = np.array([k == "acceleration" for k in frf.output_kinds])
    m0 = dim.solve(frf, setup, known={}, band_hz=band_hz).properties.mass_kg
    H = np.asarray(frf.H)
    m_h = dim.solve(frf.replace(H=H / (1 + eps)), setup, known={}, band_hz=band_hz)
    Ha = np.array(H, copy=True)
    Ha[:, acc, :] *= 1 + eps
    m_a = dim.solve(frf.replace(H=Ha), setup, known={}, band_hz=band_hz)
    return (
        float((m_h.properties.mass_kg - m0) / m0 / eps),
        float((m_a.properties.mass_kg - m0) / m0 / eps),
    )


def circular_check(
    settings: Settings,
    *,
    node: int | None = None,
    bench_file: str | Path | None = None,
    cfg: Mapping[str, Any] | None = None,
    on_progress: ProgressFn,
    on_strike: StrikeCallback | None = None,
) -> CircularCheck:
    """The circular check of load cell ``node``'s installed calibration (module docstring).

    Raises
    ------
    SetupError
        As :func:`run_inertial_calibration`; or the cell has no calibration file.
    """
    from dimacq.io.loadcell_calibration import read_calibration
    from dimacq.pipeline import dim

    rig_file = load_rig_file(settings.rig_path)
    entry = select_cell(rig_file, node)
    bench = bench_file_of(settings, bench_file)
    setup, props = calibration_mass(bench, entry.node, check=True)
    assert bench.inertial is not None
    unknown = setup.model_copy(update={"known": KnownProperties()})
    request = {"averages_per_input": bench.inertial.averages_per_input, **(cfg or {})}
    path = rig_file.calibration_path(entry)
    try:
        version = read_calibration(path).version
    except (OSError, DataError) as err:
        raise SetupError(
            f"load cell {entry.node}: no calibration to check ({path}: {err}); calibrate it "
            "first (dimacq loadcell calibrate)"
        ) from err
    where = bench.check_setup_path()
    on_progress(
        0.0, f"mount the calibration mass as {where.name} states ({setup.name}), then strike"
    )
    rig = build_rig(check_world(settings, bench), unknown, request)
    try:
        frf = run_impact_test(
            rig,
            unknown,
            request,
            on_average=lambda *_: None,
            on_progress=on_progress,
            meta={"source": f"circular check of load cell {entry.node}"},
            on_strike=on_strike,
        )
    finally:
        rig.close()
    band = bench.inertial.check_band_hz
    frf, gain_max = _rigid_gains_applied(frf, unknown, band)
    sol = dim.solve(frf, unknown, known={}, band_hz=band)
    errs = solution_errors(sol, props)
    tol = bench.inertial.check_tolerance_pct
    sens = cell_sensitivity(frf, unknown, band)
    # what the chain alone may put into the mass (an exact cell): the hammer's calibration (its
    # chain calibration's, else its certificate's) and the accelerometers' common scale
    s_h, s_a = chain_sensitivities(frf, unknown, band)
    tu = unknown.transducer_uncertainty
    hammers = [h.chain_calibration for h in rig_file.hammers if h.chain_calibration is not None]
    u_h = max((c.u_rel for c in hammers), default=tu.force_sensitivity_rel)
    n_acc = len(unknown.responses)
    u_a = (
        tu.accel_sensitivity_rel / np.sqrt(n_acc)
        if gain_max is not None
        else tu.accel_sensitivity_rel
    )
    chain_u = float(200 * np.hypot(s_h * u_h, s_a * u_a))
    reasons: tuple[str, ...] = ()
    verdict = "ok"
    if not abs(errs["mass_pct"]) <= tol:
        verdict = "fail"
        reasons = (
            f"mass {errs['mass_pct']:+.3f} % off the certificate, beyond ±{tol:g} %: the "
            "cell's calibration, or the hammer's or accelerometers' sensitivities in the rig "
            "file, are off (DIM's mass scales with the hammer force)",
        )
    if sens < MIN_CELL_SENSITIVITY:
        verdict = "fail" if verdict == "fail" else "inconclusive"
        reasons += (
            f"the check hardly sees the cell: a 1 % error of its loads moves the mass by "
            f"{sens:.2g} % (the cell carries little of the force in {band[0]:g}–{band[1]:g} Hz); "
            "it says nothing about the cell's calibration; stand the mass on the cell "
            "([inertial] check_setup_file)",
        )
    log.info(
        "load cell %d: circular check, mass %+.4f %% (%s)", entry.node, errs["mass_pct"], verdict
    )
    return CircularCheck(
        sol,
        errs,
        (float(band[0]), float(band[1])),
        version,
        tol,
        sens,
        verdict,
        reasons,
        setup_file=str(where),
        accel_gain_max_pct=gain_max,
        chain_uncertainty_pct=chain_u,
    )


#: The simulated lab's world of the circular check when the bench file stands the mass on the
#: cell (``check_setup_file``): the calibration mass bolted to the floor through the cell.
SIMULATED_ON_CELL_SCENARIO = "calibration-mass-ground"


def check_world(settings: Settings, bench: BenchFile) -> Settings:
    """The settings the circular check's rig is built with. A real rig: as configured (the
    person mounts the mass as the check's setup file says). The simulated lab (``daq`` and
    ``loadcell`` simulated), whose world is a scenario: when the check's setup differs from the
    calibration's (the mass standing on the cell), the scenario where it does
    (:data:`SIMULATED_ON_CELL_SCENARIO`); otherwise the configured one."""
    if "simulated" not in (settings.daq, settings.loadcell):
        return settings
    if bench.check_setup_path() == bench.inertial_setup_path():
        return settings
    return settings.model_copy(update={"scenario": SIMULATED_ON_CELL_SCENARIO})


def _rigid_gains_applied(frf: Any, setup: TestSetup, band: tuple[float, float]) -> tuple[Any, Any]:
    """The check's FRFs with the accelerometers' relative gains from their own rigid-body
    residual over the band applied (the certificates' scatter is amplified where the cell
    carries the force, as on the inertial bench: :mod:`dimacq.pipeline.inertial_bench`), and
    the largest correction in % (None when the gains are not identified: FRFs unchanged)."""
    from dimacq.pipeline.inertial_bench import rigid_body_gains
    from dimacq.pipeline.rigid_body import response_matrix

    acc = np.array([k == "acceleration" for k in frf.output_kinds])
    f = np.asarray(frf.frequencies_hz, float)
    sel = (f >= band[0]) & (f <= band[1])
    if acc.sum() != len(setup.responses) or sel.sum() < 2:
        return frf, None
    psi = response_matrix(
        setup.response_positions,
        setup.response_directions,
        np.asarray(setup.reference_point_m, float),
    )
    gains = rigid_body_gains(
        np.asarray(frf.H)[sel][:, acc], psi, setup.transducer_uncertainty.accel_sensitivity_rel
    )
    if not gains.identified:
        return frf, None
    H = np.array(frf.H, copy=True)
    H[:, acc, :] *= gains.gains[None, :, None]
    return frf.replace(H=H), float(np.max(np.abs(100 * (1 / gains.gains - 1))))
