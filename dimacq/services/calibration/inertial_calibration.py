"""Inertial bench calibration of a 6-DOF load cell and the circular check, on the configured rig.

Both run through the one rig builder (:func:`dimacq.services.acquisition.rig.build_rig`) and so through the
device backend tables: the same code drives a real rig (a person strikes when asked) and the
simulated lab (``daq = loadcell = "simulated"``: the world's hand strikes, the simulators are
reached only through their wires).

**Inertial calibration** (method §8, thesis §4.1). The calibration mass hangs on the cell; the
hammer strikes a light rigid fixture on the cell's *support side* at the setup's impact points,
so the cell carries every force on the mass. The rig is built with ``calibration_bench = node``
(the cell's amplifier needs no calibration file and gives its 12 gauges). With the accelerances
condensed to the rigid-body acceleration of P, ``a_P = T_q H_acc`` (least squares over the
response axes, :func:`~dimacq.pipeline.rigid_body.condense`), Newton–Euler about P gives, per line
and input,

    ``C g = (s T_c)⁻¹ M_rb(P) a_P``

with ``M_rb(P)`` the 6×6 rigid-body mass matrix of the certified calibration mass (the setup's
``[known]`` mass, CG and inertia), ``T_c`` the cell's placement and ``s`` its sign;
:func:`~dimacq.pipeline.loadcell_calibration.inertial_calibration` solves ``C`` (6×12) over the
band by rank-6 least squares.

The accelerometers' certificates (0.5 % each) would put 0.85 % into ``C``: the cell's force is
the small difference of the mass's large rotational terms, so the *differences* between channels
are amplified (:mod:`dimacq.pipeline.inertial_bench`). The calibration mass is rigid, so the
bench first finds the channels' relative gains from the rigid-body residual of its own FRFs
(:func:`~dimacq.pipeline.inertial_bench.rigid_body_gains`), keeps the certificates' common scale
(their weighted mean: ``σ/√n``, 0.1 % for 24 axes) and condenses with them; the matrix's
uncertainty propagates the gains' covariance (that scale, the jackknife of the relative gains,
:func:`~dimacq.pipeline.inertial_bench.matrix_gain_variance`) and adds the fit's jackknife over
inputs (:func:`~dimacq.pipeline.inertial_bench.jackknife_matrix_variance`: inputs on too few
faces leave loads weakly excited). A channel whose gain is far from its certificate (a wrong
sensitivity in the rig file), or a matrix known to worse than ±0.5 %, is a warning.

**Circular check** (:mod:`dimacq.services.calibration.circular_check`; thesis §4.1: "the same structure used
to calibrate the load cell in the same configuration"). The same mass on the same cell, now struck on the mass, acquired with the
amplifier applying the cell's *installed* calibration (the rig file's calibration file: what an
acquisition uses), solved by DIM with all ten properties unknown, compared with the certificate.
It follows a static or an inertial calibration alike.

Where the bench is described: the bench file (``loadcell_bench.toml`` beside the rig file),
``[inertial]``: the calibration mass's setup file, the fit band, the check's DIM band, the
averages per input (:mod:`dimacq.io.loadcell_bench`).
"""

from __future__ import annotations

import dataclasses
import datetime as _dt
import logging
import shutil
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from dimacq.config import Settings
from dimacq.errors import DataError, SetupError
from dimacq.io.loadcell_bench import BenchFile, load_bench_file
from dimacq.io.loadcell_calibration import LoadCellCalibration
from dimacq.io.rig_file import LoadCellEntry, RigFile, load_rig_file
from dimacq.model.properties import RigidBodyProperties
from dimacq.model.setup import TestSetup, direction_label
from dimacq.pipeline.inertial_bench import ChannelGains
from dimacq.services.acquisition.rig import (
    StrikeCallback,
    build_rig,
    run_impact_session,
)

__all__ = [
    "InertialRun",
    "bench_file_of",
    "calibration_mass",
    "hammer_ratio",
    "run_inertial_calibration",
    "scratch_rig",
    "select_cell",
]

log = logging.getLogger(__name__)

FloatArray = NDArray[np.float64]
#: ``on_progress(fraction, message)``; on a real rig the message asks the person to strike.
ProgressFn = Callable[[float, str], None]

_PARAMS = ("m", "cx", "cy", "cz", "Ixx", "Ixy", "Ixz", "Iyy", "Iyz", "Izz")


def select_cell(rig: RigFile, node: int | None) -> LoadCellEntry:
    """The rig file's load cell ``node`` (the only one when None).

    Raises
    ------
    SetupError
        No load cell, several and none chosen, or an unknown node.
    """
    cells = {lc.node: lc for lc in rig.load_cells}
    if not cells:
        raise SetupError(f"rig file {rig.path} has no [[load_cells]]; add the cell to calibrate")
    if node is None:
        if len(cells) > 1:
            raise SetupError(
                f"rig file {rig.path} has load cells {sorted(cells)}: give the node to calibrate"
            )
        node = next(iter(cells))
    if node not in cells:
        raise SetupError(f"load cell {node} is not in {rig.path}; use one of {sorted(cells)}")
    return cells[node]


def bench_file_of(settings: Settings, bench_file: str | Path | None = None) -> BenchFile:
    """The bench file: ``bench_file``, else ``loadcell_bench.toml`` beside the rig file."""
    return load_bench_file(bench_file or settings.rig_path.parent / "loadcell_bench.toml")


def calibration_mass(
    bench: BenchFile, node: int, *, check: bool = False
) -> tuple[TestSetup, RigidBodyProperties]:
    """The calibration mass's setup (``[inertial] setup_file``; ``check``: the circular check's
    ``check_setup_file``) and its certified properties (the setup's ``[known]``: all ten).

    Raises
    ------
    SetupError
        No ``[inertial]`` table, an unreadable setup, properties not all known, or the setup
        does not mount the mass on load cell ``node``.
    """
    from dimacq.io.setup_file import load_setup

    path = bench.check_setup_path() if check else bench.inertial_setup_path()
    setup = load_setup(path)
    known = setup.known.as_dict()
    missing = [p for p in _PARAMS if p not in known]
    if missing:
        raise SetupError(
            f"calibration mass setup {path}: [known] lacks {', '.join(missing)}; give the "
            "certified mass, CG and inertia (all ten) of the calibration mass"
        )
    if node not in {lc.node for lc in setup.load_cells}:
        raise SetupError(
            f"calibration mass setup {path}: no load cell {node}; give the cell's node, "
            "position and rotation under [[load_cells]]"
        )
    P = np.asarray(setup.reference_point_m, float)
    I_p = np.array(
        [
            [known["Ixx"], known["Ixy"], known["Ixz"]],
            [known["Ixy"], known["Iyy"], known["Iyz"]],
            [known["Ixz"], known["Iyz"], known["Izz"]],
        ]
    )
    props = RigidBodyProperties.from_about_point(
        known["m"], np.array([known["cx"], known["cy"], known["cz"]]), I_p, P
    )
    return setup, props


@dataclass(frozen=True, eq=False)
class InertialRun:
    """An inertial calibration of load cell ``node``.

    Attributes
    ----------
    node, serial_number : the cell and its amplifier's serial number
    fit : LoadCellCalibrationFit
        ``fit.matrix`` is ``C`` (6×12, N and N·m per gauge unit).
    band_hz : (lo, hi) lines used, Hz
    averages_per_input : int
    n_inputs : int
        Inputs with FRFs (complete ones).
    gauge_unit : str
    hammer_ratio : (mean, std) or None
        The hammer's stated sensitivity over the one the calibration mass implies (see
        :func:`hammer_ratio`); 1 when the rig file's hammer certificate is right.
    gains : ChannelGains or None
        The accelerometer channels' relative gains from the rigid-body residual, applied.
    matrix_std : ndarray, shape (6, 12), or None
        Standard uncertainty of each element of ``C``: the gains' (scale included) and the
        fit's (jackknife over inputs).
    channel_labels : tuple of str
        The response channels, in the order of ``gains``.
    verdict : {"ok", "warn"}
    reasons : tuple of str
    """

    node: int
    serial_number: str
    fit: Any
    band_hz: tuple[float, float]
    averages_per_input: int
    n_inputs: int
    gauge_unit: str
    hammer_ratio: tuple[float, float] | None = None
    gains: ChannelGains | None = None
    matrix_std: FloatArray | None = None
    channel_labels: tuple[str, ...] = ()
    verdict: str = "ok"
    reasons: tuple[str, ...] = ()

    @property
    def matrix(self) -> FloatArray:
        return np.asarray(self.fit.matrix, dtype=np.float64)

    def _std(self) -> FloatArray:
        if self.matrix_std is not None:
            return np.asarray(self.matrix_std, float)
        return np.asarray(self.fit.matrix_std, float)

    def matrix_uncertainty_rel(self) -> float:
        """Expanded (k = 2) relative Frobenius uncertainty of ``C``:
        ``2 √(Σ Var C_ab) / ‖C‖_F`` (what ``matrix_error_rel`` should stay within)."""
        return float(2 * np.sqrt(np.sum(self._std() ** 2)) / np.linalg.norm(self.matrix))

    def uncertainty_pct_fs(self) -> list[float]:
        """Expanded (k = 2) uncertainty of each load axis, % of the reading (the inertial
        method has no rated-load reference: the % FS of a load at the rated load):
        ``200 √(r_i² + u_i²)`` with ``r_i`` the fit's relative residual of that load (a single
        reading's scatter) and ``u_i = √(Σ_b Var C_ib) / ‖C_i‖`` (the matrix row's)."""
        u = np.sqrt(np.sum(self._std() ** 2, axis=1)) / np.linalg.norm(self.matrix, axis=1)
        r = np.asarray(self.fit.residual_rel_per_load, float)
        return [float(v) for v in 200 * np.sqrt(r**2 + u**2)]

    def gains_json(self) -> dict[str, Any] | None:
        g = self.gains
        if g is None:
            return None
        return {
            "identified": g.identified,
            "separation": g.separation,
            "residual_rel": g.residual_rel,
            "scale_std_rel": g.scale_std,
            "channels": list(self.channel_labels),
            "gain": g.gains.tolist(),
            "gain_std_rel": g.relative_std.tolist(),
        }

    def fit_json(self) -> dict[str, Any]:
        fit = self.fit
        return {
            "residual_rel": fit.residual_rel,
            "residual_rel_per_load": fit.residual_rel_per_load.tolist(),
            "singular_values": fit.singular_values.tolist(),
            "rank_used": fit.rank_used,
            "condition": fit.condition,
            "noise_separation": fit.noise_separation,
            "load_condition": fit.load_condition,
            "n_equations": fit.n_equations,
            "hammer_sensitivity_ratio": None if self.hammer_ratio is None else self.hammer_ratio[0],
            "hammer_sensitivity_ratio_std": (
                None if self.hammer_ratio is None else self.hammer_ratio[1]
            ),
            "matrix_uncertainty_rel": self.matrix_uncertainty_rel(),
            "accelerometer_gains": self.gains_json(),
        }

    def calibration(self) -> LoadCellCalibration:
        """The calibration document (version set when installed)."""
        return LoadCellCalibration(
            serial_number=self.serial_number,
            date=_dt.date.today().isoformat(),
            matrix=self.matrix,
            method="inertial",
            gauge_unit=self.gauge_unit,
            diagnostics={
                **{k: v for k, v in self.fit_json().items() if not isinstance(v, (list, dict))},
                "band_hz": list(self.band_hz),
                "averages_per_input": self.averages_per_input,
                "inputs": self.n_inputs,
            },
            certificate={
                "uncertainty_pct_fs": self.uncertainty_pct_fs(),
                "matrix_uncertainty_rel": self.matrix_uncertainty_rel(),
                "verdict": self.verdict,
                "reasons": list(self.reasons),
            },
            notes="inertial calibration with the calibration mass (support-side impacts)",
        )


def hammer_ratio(
    accel_p: NDArray[np.complex128],
    mass_matrix: FloatArray,
    directions: FloatArray,
) -> tuple[float, float]:
    """The hammer's stated sensitivity over the one the calibration mass implies.

    On the bench the mass moves as a free rigid body above its suspension modes, so the force
    on it along input ``j``'s line of action is the hammer's true force: ``d_jᵀ F_P = f`` with
    ``F_P`` the first three rows of ``M_rb(P) a_P``. With ``a_P`` per *measured* hammer force
    (a hammer read with the stated sensitivity ``s_stated`` while its true one is ``s_true``
    reads ``f s_true / s_stated``), ``r_j(ω) = Re d_jᵀ (M_rb a_P)[:3] = s_stated / s_true``;
    DIM's mass through that hammer comes out ``1/r − 1`` off.

    Parameters
    ----------
    accel_p : (n_lines, 6, n_inputs) complex
        Rigid-body acceleration of P per measured input force, lines above the suspension.
    mass_matrix : (6, 6)
    directions : (n_inputs, 3) unit lines of action

    Returns
    -------
    (mean, std) of ``r`` over lines and inputs.
    """
    F = np.einsum("ab,lbi->lai", np.asarray(mass_matrix, float)[:3], accel_p.real)
    r = np.einsum("ia,lai->li", np.asarray(directions, float), F)
    return float(r.mean()), float(r.std())


def _gauge_unit(rig: RigFile, entry: LoadCellEntry) -> str:
    """The unit of the cell's gauges: as its present calibration file says, else mV/V (a
    strain-gauge bridge, what this system is built for)."""
    from dimacq.io.loadcell_calibration import read_calibration

    path = rig.calibration_path(entry)
    if path.exists():
        try:
            return read_calibration(path).gauge_unit
        except DataError:
            pass
    return "mV/V"


#: A channel's gain this many of its certificate's σ away from it: the rig file is wrong.
GAIN_OUTLIER_SIGMA = 4.0
#: Above this expanded (k = 2) relative uncertainty the inertial matrix is a warning.
MAX_MATRIX_UNCERTAINTY_REL = 0.005
#: The rigid-body residual of the bench's accelerometers above which the calibration is refused
#: (0.4 % on the simulated bench up to 800 Hz; 31 % with the triaxes turned as another seed's).
MAX_RIGID_RESIDUAL = 0.05


def _gain_reasons(gains: ChannelGains, labels: tuple[str, ...], sigma: float) -> tuple[str, ...]:
    """Warnings: gains not identified (the certificates' scatter stays in ``C``), or channels
    whose gain is more than :data:`GAIN_OUTLIER_SIGMA` certificate σ off the certificate."""
    if not gains.identified:
        return (
            f"the rigid-body residual does not single out the accelerometers' gains "
            f"(λ₁/λ₂ = {gains.separation:.2g}): their certificates' scatter stays in the matrix "
            "(see its uncertainty); strike more inputs, on three faces",
        )
    off = np.log(gains.gains)
    bad = np.flatnonzero(np.abs(off) > GAIN_OUTLIER_SIGMA * sigma)
    if not bad.size:
        return ()
    worst = bad[np.argmax(np.abs(off[bad]))]
    return (
        f"{bad.size} accelerometer channel(s) read more than {GAIN_OUTLIER_SIGMA * sigma * 100:g} % "
        f"off their certificate on the rigid calibration mass (worst {labels[worst]}: "
        f"{-100 * off[worst]:+.2f} %); check their sensitivities and directions in the rig file",
    )


def run_inertial_calibration(
    settings: Settings,
    *,
    node: int | None = None,
    bench_file: str | Path | None = None,
    cfg: Mapping[str, Any] | None = None,
    on_progress: ProgressFn,
    download: Callable[[Any, FloatArray], Any] | None = None,
    on_strike: StrikeCallback | None = None,
) -> tuple[InertialRun, Any]:
    """Calibrate load cell ``node`` of the configured rig on the inertial bench.

    Parameters
    ----------
    settings : Settings
        ``daq``/``loadcell`` backends, ``rig_file``.
    node : int, optional
        The rig file's load cell (default: the only one).
    bench_file : path, optional
        Default ``loadcell_bench.toml`` beside the rig file; its ``[inertial]`` table.
    cfg : mapping, optional
        Impact-test request values (``seed``, ``noise_scale``, ``averages_per_input``, ...;
        default averages: the bench file's).
    on_progress : callable (fraction, message)
    on_strike : callable (StrikeRequest), optional
        Told each request to the person to strike (a real rig; :class:`StrikeRequest`).
    download : callable (amplifier, matrix), optional
        Called with the open amplifier and ``C`` once the fit succeeded (e.g. store it in the
        amplifier and read it back); its result is returned beside the run.

    Returns
    -------
    (InertialRun, download result or None)

    Raises
    ------
    SetupError
        Bad bench file, setup or rig file (named).
    DataError
        The fit is refused (too few inputs, loads not excited), or the accelerometers do not
        move as one rigid body with the setup's geometry (:data:`MAX_RIGID_RESIDUAL`).
    """
    from dimacq.pipeline.rigid_body import condense, response_matrix

    rig_file = load_rig_file(settings.rig_path)
    entry = select_cell(rig_file, node)
    bench = bench_file_of(settings, bench_file)
    setup, props = calibration_mass(bench, entry.node)
    assert bench.inertial is not None
    request = {"averages_per_input": bench.inertial.averages_per_input, **(cfg or {})}
    k = [lc.node for lc in setup.load_cells].index(entry.node)
    rig = build_rig(settings, setup, request, calibration_bench=entry.node)
    try:
        serial = str(rig.loadcells[k].identify().serial_number)
        res = run_impact_session(
            rig,
            setup,
            request,
            on_progress=on_progress,
            loadcell_outputs="gauges",
            on_strike=on_strike,
        )
        f = res.frequencies_hz
        sel = _band_lines(bench, f)
        n_acc = len(setup.responses)
        P = np.asarray(setup.reference_point_m, float)
        psi = response_matrix(setup.response_positions, setup.response_directions, P)
        gains = _rigid_body_gains(bench, setup, res.H[sel, :n_acc], psi)
        Tq = condense(psi).transform * gains.gains[None, :]  # (6, n_acc), gains applied
        a_p = _platform_motion(Tq, res.H[sel, :n_acc])
        gauges = res.H[sel, n_acc + 12 * k : n_acc + 12 * (k + 1)]
        n_inputs = res.H.shape[2]
        kept = list(res.input_indices or range(n_inputs))
        M = props.mass_matrix(P)
        ratio = _check_band_hammer_ratio(bench, res, Tq, M, setup.input_directions[kept])
        del res
        lc = setup.load_cells[k]
        fit, var, var_fit = _fit_matrix(gauges, a_p, M, lc, P, gains, Tq, psi)
        labels = tuple(f"{r.node}{direction_label(r.direction)}" for r in setup.responses)
        reasons = _calibration_reasons(setup, gains, labels, fit, var + var_fit)
        run = InertialRun(
            node=entry.node,
            serial_number=serial,
            fit=fit,
            band_hz=(float(f[sel][0]), float(f[sel][-1])),
            averages_per_input=int(request["averages_per_input"]),
            n_inputs=int(n_inputs),
            gauge_unit=_gauge_unit(rig_file, entry),
            hammer_ratio=ratio,
            gains=gains,
            matrix_std=np.sqrt(var + var_fit),
            channel_labels=labels,
            verdict="warn" if reasons else "ok",
            reasons=reasons,
        )
        done = None if download is None else download(rig.loadcells[k], run.matrix)
    finally:
        rig.close()
    log.info(
        "load cell %d: inertial calibration, residual %.3g, condition %.3g over %g–%g Hz",
        run.node,
        fit.residual_rel,
        fit.condition,
        *run.band_hz,
    )
    return run, done


def _band_lines(bench: BenchFile, f: FloatArray) -> NDArray[np.bool_]:
    """The lines of the bench file's ``[inertial] band_hz`` (at least two, else refused)."""
    assert bench.inertial is not None
    lo, hi = bench.inertial.band_hz
    sel = (f >= lo) & (f <= hi)
    if sel.sum() < 2:
        raise SetupError(
            f"bench file {bench.path}: [inertial] band_hz = [{lo}, {hi}] holds "
            f"{int(sel.sum())} lines of 0–{f[-1]:g} Hz; give a band inside it"
        )
    return sel


def _rigid_body_gains(bench: BenchFile, setup: TestSetup, acc: Any, psi: Any) -> ChannelGains:
    """The accelerometers' gains that make them move as one rigid body; refused (nothing
    installed) when their rms residual exceeds :data:`MAX_RIGID_RESIDUAL` of their motion."""
    from dimacq.pipeline.inertial_bench import rigid_body_gains

    gains = rigid_body_gains(acc, psi, setup.transducer_uncertainty.accel_sensitivity_rel)
    if not gains.residual_rel <= MAX_RIGID_RESIDUAL:
        raise DataError(
            f"the accelerometers do not move as one rigid body with the setup's geometry "
            f"(rms residual {100 * gains.residual_rel:.1f} % of their motion, "
            f"{100 * MAX_RIGID_RESIDUAL:g} % at most): a sensor's position or direction in "
            f"{bench.inertial_setup_path()} or its cabling in the rig file is wrong; the "
            "matrix would be wrong by as much, nothing installed"
        )
    return gains


def _platform_motion(Tq: Any, acc: Any) -> Any:
    """The mass's rigid-body accelerations at P, ``T_q H`` per line: shape (lines, 6, inputs).

    Real and imaginary parts apart (complex GEMM is slow on common BLAS builds).
    """
    return np.einsum("kc,lci->lki", Tq, acc.real) + 1j * np.einsum("kc,lci->lki", Tq, acc.imag)


def _check_band_hammer_ratio(
    bench: BenchFile, res: Any, Tq: Any, M: FloatArray, directions: FloatArray
) -> Any:
    """:func:`hammer_ratio` in the bench's check band (above the suspension modes), or None
    when the band holds no line."""
    assert bench.inertial is not None
    f = res.frequencies_hz
    n_acc = Tq.shape[1]
    clo, chi = bench.inertial.check_band_hz  # above the suspension modes
    above = (f >= clo) & (f <= chi)
    a_hi = _platform_motion(Tq, res.H[above, :n_acc])
    return hammer_ratio(a_hi, M, directions) if above.any() else None


def _calibration_reasons(
    setup: TestSetup, gains: ChannelGains, labels: tuple[str, ...], fit: Any, var: FloatArray
) -> tuple[str, ...]:
    """Why the calibration only warns: the accelerometers' gains (:func:`_gain_reasons`) and a
    matrix known to worse than :data:`MAX_MATRIX_UNCERTAINTY_REL` (k = 2) from its variance
    ``var`` (gains and fit).

    u_rel = 2 sqrt(Σ var) / ‖C‖_F
    """
    u_rel = float(2 * np.sqrt(np.sum(var)) / np.linalg.norm(fit.matrix))
    reasons = _gain_reasons(gains, labels, setup.transducer_uncertainty.accel_sensitivity_rel)
    if u_rel > MAX_MATRIX_UNCERTAINTY_REL:
        reasons += (
            f"the matrix is known to ±{100 * u_rel:.2f} % only (k = 2; fit condition "
            f"σ1/σ6 {fit.condition:.3g}): the inputs do not excite the six loads evenly; "
            "strike the mass on three faces, off its centre",
        )
    return reasons


def _fit_matrix(
    gauges: Any,
    a_p: Any,
    M: FloatArray,
    lc: Any,
    P: FloatArray,
    gains: ChannelGains,
    Tq: Any,
    psi: Any,
) -> tuple[Any, FloatArray, FloatArray]:
    """The calibration matrix fit, the variance its elements owe to the accelerometers' gains,
    and the fit's own variance (jackknife over inputs, else the residuals' lower bound)."""
    from dimacq.pipeline.inertial_bench import jackknife_matrix_variance, matrix_gain_variance
    from dimacq.pipeline.loadcell_calibration import inertial_calibration
    from dimacq.pipeline.rigid_body import load_cell_transform

    fit = inertial_calibration(
        gauges,
        a_p,
        M,
        np.asarray(lc.position_m, float),
        lc.rotation_matrix,
        P,
        sign=lc.sign_factor,
    )
    Tc = load_cell_transform(
        np.asarray(lc.position_m, float), lc.rotation_matrix, P, lc.sign_factor
    )
    var = matrix_gain_variance(fit.matrix, gains.covariance, Tq, psi, M, Tc)
    var_fit = jackknife_matrix_variance(
        gauges,
        a_p,
        M,
        np.asarray(lc.position_m, float),
        lc.rotation_matrix,
        P,
        sign=lc.sign_factor,
    )
    if var_fit is None:  # fewer than 4 inputs: the residuals' (a lower bound)
        var_fit = np.asarray(fit.matrix_std, float) ** 2
    return fit, var, var_fit


# ---------------------------------------------------------------------------------------------
# A scratch copy of the rig (simulated runs leave the configured calibration files alone)
# ---------------------------------------------------------------------------------------------
def scratch_rig(settings: Settings, directory: Path) -> Settings:
    """Copy the rig file, its load cells' calibration files, the bench file and the calibration
    mass's setup file into ``directory`` (same relative layout) and return the settings with
    ``rig_file`` pointing at the copy: a simulated calibration installs its versions there, and
    the circular check reads them, without touching the configured rig's files."""
    src = settings.rig_path
    rig = load_rig_file(src)
    directory.mkdir(parents=True, exist_ok=True)
    files = [src.name]
    for e in rig.load_cells:
        cal = rig.calibration_path(e)
        if cal.exists():
            try:
                files.append(cal.relative_to(src.parent).as_posix())
            except ValueError:
                pass  # an absolute path outside the rig folder: left where it is (read only)
    bench = src.parent / "loadcell_bench.toml"
    if bench.exists():
        files.append(bench.name)
        b = load_bench_file(bench)
        if b.inertial is not None:
            for name in (b.inertial.setup_file, b.inertial.check_setup_file):
                if name and not Path(name).is_absolute():
                    files.append(name)
    for rel in files:
        dst = directory / rel
        dst.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(src.parent / rel, dst)
    return settings.model_copy(update={"rig_file": str(directory / src.name)})


def install_inertial(rig_file: RigFile, entry: LoadCellEntry, run: InertialRun) -> Any:
    """Keep the inertial calibration as the cell's next version (JSON and XML) and make it the
    current file (:func:`~dimacq.io.loadcell_calibration.install_calibration`)."""
    from dimacq.io.loadcell_calibration import install_calibration

    return install_calibration(run.calibration(), rig_file.calibration_path(entry))


def installed_document(cal: LoadCellCalibration, version: int) -> dict[str, Any]:
    doc: dict[str, Any] = dataclasses.replace(cal, version=version).to_json()
    return doc
