"""Impact tests of the virtual lab through the simulated USB DAQ and CAN FD load cells, for the
inertial ``dimacq loadcell calibrate --simulated`` and the scripts that measure the drivers
against the virtual lab's truth. ``dimacq acquire``, the service and ``dimacq demo`` build their
rig with :func:`dimacq.services.rig.build_rig` from the backend tables (calibrations from files
only); this module drives a scenario's whole article with its nominal transducers.

:class:`SimulatedRig` wires one :class:`~dimacq.simulators.lab.timedomain.VirtualLab` (or any
``SampleSource`` over it, e.g. the calibration bench) to the real driver code:

- a :class:`~dimacq.simulators.daq.backend.VirtualDaqBackend` found through pyusb by
  :meth:`DaqDevice.open <dimacq.drivers.daq.driver.DaqDevice.open>`: the hammer on physical
  channel 0 (IEPE, ``hammer_mv_per_n``), every accelerometer axis on the next channels
  (IEPE, ``accel_mv_per_g``), one :class:`~dimacq.drivers.daq.driver.DaqTask`;
- per load cell a :class:`~dimacq.simulators.loadcell.amplifier.LoadCellAmplifierSim` on its own
  python-can ``virtual`` CAN FD channel counting the DAQ's sample clock, and a
  :class:`~dimacq.drivers.loadcell.driver.LoadCellAmplifier` on a bus to it, holding the 6×12
  calibration matrix it applies (``F = C g``);
- an :class:`~dimacq.services.acquisition.ImpactSession` whose operator strikes the lab.

:func:`~dimacq.services.acquisition.impact_frf` turns the session's result into
:class:`~dimacq.model.frf.FrfData`; :func:`model_frf` evaluates the true article consistently with the exponential
window, and :func:`frf_agreement` compares. :func:`simulated_inertial_calibration` runs the
load cell bench calibration (method §8) and its circular DIM check.
"""

from __future__ import annotations

import itertools
import logging
import os
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Literal

import can
import numpy as np
from numpy.typing import NDArray

from dimacq.drivers.daq.driver import DaqDevice, DaqTask
from dimacq.drivers.loadcell.driver import LoadCellAmplifier
from dimacq.errors import DataError, SetupError
from dimacq.io.acquisition_hdf5 import AcquisitionWriter
from dimacq.model.channels import gauge_names
from dimacq.model.frf import STANDARD_GRAVITY, FrfData
from dimacq.model.impact import ImpactSettings
from dimacq.model.setup import TestSetup
from dimacq.services.acquisition import ImpactResult, ImpactSession, Progress, impact_frf
from dimacq.simulators.daq.backend import DaqInput, VirtualDaqBackend
from dimacq.simulators.daq.clock import SampleClock
from dimacq.simulators.lab.forward import ForwardModel, calibration_mass, x38_like
from dimacq.simulators.lab.source import SampleSource
from dimacq.simulators.lab.timedomain import Hammer, LabNoise, VirtualLab, state_space
from dimacq.simulators.loadcell.amplifier import LoadCellAmplifierSim

__all__ = [
    "DIM_BAND_HZ",
    "SCENARIOS",
    "CalibrationRun",
    "FrfAgreement",
    "SimulatedRig",
    "default_noise",
    "frf_agreement",
    "model_frf",
    "run_scenario",
    "scenario_model",
    "simulated_inertial_calibration",
]

log = logging.getLogger(__name__)

FloatArray = NDArray[np.float64]
ComplexArray = NDArray[np.complex128]

_bus_names = itertools.count()


# ---------------------------------------------------------------------------------------------
# Scenarios
# ---------------------------------------------------------------------------------------------
#: Extra scenario names (aliases and variants) beside the versioned files in ``config/scenarios/``,
#: which take precedence (:func:`dimacq.simulators.lab.scenarios.build_scenario`).
SCENARIOS: dict[str, Callable[[int], ForwardModel]] = {
    "calibration-mass": lambda seed: calibration_mass(seed, support="bungee"),
    "calibration-mass-bungee": lambda seed: calibration_mass(seed, support="bungee"),
    "calibration-mass-air-ride": lambda seed: calibration_mass(seed, support="air-ride"),
    "calibration-mass-ground": lambda seed: calibration_mass(seed, support="ground"),
    "x38": lambda seed: x38_like(seed),
    "x38-flexible": lambda seed: x38_like(seed, flexible=True),
}


def scenario_model(name: str, seed: int = 0) -> ForwardModel:
    """The true article of scenario ``name``: a file of ``config/scenarios/`` or an alias of
    :data:`SCENARIOS`."""
    from dimacq.simulators.lab.scenarios import build_scenario, list_scenarios

    files = list_scenarios()
    if name in files:
        return build_scenario(name, seed).model
    try:
        build = SCENARIOS[name]
    except KeyError as err:
        raise SetupError(
            f"scenario {name!r} is unknown; use one of {', '.join(sorted({*files, *SCENARIOS}))}"
        ) from err
    return build(seed)


#: DIM band of the simulated calibration-mass tests: above the bungee/air-ride suspension modes
#: (≤ 2 Hz) and below where the hammer pulse's spectrum has fallen by 13 dB (400 Hz at the
#: lab's default pulse width σ = 1.4/fs, fs = 2048 Hz).
DIM_BAND_HZ = (20.0, 400.0)


#: Blocks a streamed simulated test keeps cached: the DAQ and the amplifier read each block
#: about once, the amplifier's tare a little behind (256 samples per block: 16 k samples).
_STREAM_CACHE_BLOCKS = 64


def default_noise() -> LabNoise:
    """Transducer noise of the simulated tests: accelerometers 0.5 mm/s² rms (50 µg), hammer 0.05 N rms,
    gauges 2 µV rms (plus the 24-bit quantisation of the DAQ and the amplifier)."""
    return LabNoise(accel_noise_ms2=5e-4, force_noise_n=0.05, gauge_noise_v=2e-6)


# ---------------------------------------------------------------------------------------------
# The rig
# ---------------------------------------------------------------------------------------------
class SimulatedRig:
    """The virtual lab behind the simulated USB DAQ and CAN FD load cells, with real drivers.

    Parameters
    ----------
    lab : VirtualLab
        The physics (its model's setup gives the channels).
    source : SampleSource, optional
        What the devices read and the operator strikes (default: ``lab``; e.g. a
        :class:`~dimacq.simulators.loadcell.bench.SupportSideBench` over it).
    calibration : mapping node → (6, 12) array, optional
        Matrix each load cell driver applies. Default: the true one, ``pinv(S)`` of the lab
        (the drivers-vs-simulator checks of ``tests/cli/test_simulated_lab.py``).
    uncalibrated : bool
        The load cell drivers get no matrix at all (a new cell on the calibration bench:
        gauge outputs only; the matrix is what the bench finds).
    accel_mv_per_g, hammer_mv_per_n : float
        Transducer sensitivities (the simulated transducers are exact).
    accel_range_v, hammer_range_v : float
        DAQ input ranges (see ``dimacq.drivers.daq.protocol.RANGES_V``).
    samples_per_frame : int
        USB frame size, samples.

    Use as a context manager: closes the USB device, the CAN buses and simulator threads.
    """

    def __init__(
        self,
        lab: VirtualLab,
        *,
        source: SampleSource | None = None,
        calibration: Mapping[int, FloatArray] | None = None,
        uncalibrated: bool = False,
        accel_mv_per_g: float = 100.0,
        hammer_mv_per_n: float = 2.25,
        accel_range_v: float = 10.0,
        hammer_range_v: float = 5.0,
        samples_per_frame: int = 256,
    ) -> None:
        self.lab = lab
        self.source: SampleSource = source if source is not None else lab
        self.setup: TestSetup = lab.model.setup
        n_acc = len(self.setup.responses)
        if n_acc + 1 > 64:
            raise SetupError(
                f"{n_acc} responses and a hammer need {n_acc + 1} DAQ channels; the simulated DAQ "
                "has 64: split the test into runs"
            )
        self._closers: list[Callable[[], None]] = []
        try:
            self._build(
                None if uncalibrated else calibration,
                uncalibrated,
                accel_mv_per_g,
                hammer_mv_per_n,
                accel_range_v,
                hammer_range_v,
                samples_per_frame,
            )
        except BaseException:
            self.close()
            raise

    def _build(
        self,
        calibration: Mapping[int, FloatArray] | None,
        uncalibrated: bool,
        accel_mv_per_g: float,
        hammer_mv_per_n: float,
        accel_range_v: float,
        hammer_range_v: float,
        samples_per_frame: int,
    ) -> None:
        lab = self.lab
        self.clock = SampleClock()
        n_acc = len(self.setup.responses)
        self.response_channels = [lab.channel_names[i] for i in range(n_acc)]
        hammer = lab.channel_index("hammer")
        wiring = {0: DaqInput(hammer, hammer_mv_per_n * 1e-3)}
        for k in range(n_acc):
            wiring[1 + k] = DaqInput(k, accel_mv_per_g * 1e-3 / STANDARD_GRAVITY)
        self.backend = VirtualDaqBackend(self.source, wiring, clock=self.clock)
        self.device = DaqDevice.open(backend=self.backend)
        self._closers.append(self.device.close)
        task = DaqTask(self.device, "impact")
        task.add_force_channel(0, "hammer", hammer_mv_per_n, range_v=hammer_range_v)
        for k, name in enumerate(self.response_channels):
            task.add_accel_channel(1 + k, name, accel_mv_per_g, range_v=accel_range_v)
        task.configure_timing(lab.sample_rate_hz, samples_per_frame)
        self.task = task
        self.loadcells: list[LoadCellAmplifier] = []
        for lc in self.setup.load_cells:
            name = f"dimacq-sim-{os.getpid()}-{next(_bus_names)}-lc{lc.node}"
            gauges = [lab.channel_index(n) for n in gauge_names(lc.node)]
            sim = LoadCellAmplifierSim(
                name, self.source, gauges, clock=self.clock, serial_number=lc.node
            )
            self._closers.append(sim.close)
            bus = can.Bus(interface="virtual", channel=name, fd=True)
            self._closers.append(bus.shutdown)
            if uncalibrated:
                self.loadcells.append(LoadCellAmplifier(bus, timeout_s=5.0))
                continue
            C = (calibration or {}).get(lc.node)
            if C is None:
                C = np.asarray(np.linalg.pinv(lab.gauge_matrix(lc.node)), dtype=np.float64)
            self.loadcells.append(
                LoadCellAmplifier(bus, timeout_s=5.0, calibration_matrix=np.asarray(C, float))
            )

    def close(self) -> None:
        while self._closers:
            fn = self._closers.pop()
            try:
                fn()
            except Exception:  # closing must go on for the others
                log.exception("closing part of the simulated rig failed")

    def __enter__(self) -> SimulatedRig:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def strike(self, input_index: int, daq_sample: int) -> None:
        """The virtual operator: strike input ``input_index`` at DAQ sample ``daq_sample``."""
        self.source.excite(input_index, self.backend.world_sample(daq_sample))

    def run(
        self,
        settings: ImpactSettings,
        *,
        data_path: Path | None = None,
        progress: Callable[[Progress], None] | None = None,
        loadcell_outputs: Literal["forces", "gauges"] = "forces",
    ) -> ImpactResult:
        """One impact test of every input of the setup (raw data to ``data_path`` if given)."""
        n_in = len(self.setup.excitations)
        if settings.hit_delay_samples < self.lab.block_samples:
            # The lab can only be struck at or after what it has already generated (whole blocks).
            settings = settings.model_copy(update={"hit_delay_samples": self.lab.block_samples})
        kwargs: dict[str, Any] = dict(
            settings=settings,
            operator=self.strike,
            progress=progress,
            loadcell_outputs=loadcell_outputs,
        )
        if data_path is None:
            return ImpactSession(
                self.task, ["hammer"] * n_in, self.response_channels, self.loadcells, **kwargs
            ).run()
        data_path.parent.mkdir(parents=True, exist_ok=True)
        with AcquisitionWriter(
            data_path,
            sample_rate_hz=self.lab.sample_rate_hz,
            daq_channels=self.task.channel_names,
            daq_units=tuple(c.units for c in self.task.channels),
            n_loadcells=len(self.loadcells),
        ) as writer:
            return ImpactSession(
                self.task,
                ["hammer"] * n_in,
                self.response_channels,
                self.loadcells,
                writer=writer,
                **kwargs,
            ).run()


# ---------------------------------------------------------------------------------------------
# Results as FRF data, and the model to compare with
# ---------------------------------------------------------------------------------------------
def model_frf(
    model: ForwardModel, frequencies_hz: FloatArray, exponential_tau_s: float | None = None
) -> ComplexArray:
    """True FRFs ``H(s) = C (sE − A)⁻¹ B + D`` at ``s = i2πf + 1/τ``, shape (L, n_out, n_in).

    The exponential window ``e^{−t/τ}`` applied to input and output turns the measured FRF into
    ``H(iω + 1/τ)``; ``exponential_tau_s=None`` gives ``H(iω)``. Outputs in
    :meth:`ForwardModel.frf` order (accelerometers, then 6 loads per load cell).
    """
    A, B, C, D, _ = state_space(model)
    s = 2j * np.pi * np.asarray(frequencies_hz, float)
    if exponential_tau_s:
        s = s + 1.0 / exponential_tau_s
    n = A.shape[0]
    if n == 0:
        return np.broadcast_to(D.astype(complex), (s.size, *D.shape)).copy()
    # Batched (sE − A) X = B: complex solve over small systems (n ≤ a few dozen).
    Msys = s[:, None, None] * np.eye(n)[None] - A[None]
    X = np.linalg.solve(Msys, np.broadcast_to(B.astype(complex), (s.size, *B.shape)))
    # C X with real arithmetic (complex GEMM is slow on this machine's BLAS).
    H = np.einsum("on,lni->loi", C, X.real) + 1j * np.einsum("on,lni->loi", C, X.imag)
    return np.asarray(H + D[None], dtype=complex)


@dataclass(frozen=True)
class FrfAgreement:
    """Measured vs true FRFs on the lines where the coherence exceeds a threshold.

    Attributes
    ----------
    max_rel_error : float
        ``max |H_meas − H_true| / |H_true|`` over the kept (line, output, input) entries,
        per kind ``"acceleration"`` / ``"reaction"`` in ``by_kind``.
    p99_rel_error, median_rel_error : float
    fraction_kept : float
        Kept entries / all entries.
    n_kept : int
    """

    max_rel_error: float
    p99_rel_error: float
    median_rel_error: float
    fraction_kept: float
    n_kept: int
    coherence_threshold: float | None
    band_hz: tuple[float, float]
    by_kind: dict[str, float] = field(default_factory=dict)

    def to_json(self) -> dict[str, Any]:
        return {
            "max_rel_error": self.max_rel_error,
            "p99_rel_error": self.p99_rel_error,
            "median_rel_error": self.median_rel_error,
            "fraction_kept": self.fraction_kept,
            "n_kept": self.n_kept,
            "coherence_threshold": self.coherence_threshold,
            "band_hz": list(self.band_hz),
            "max_rel_error_by_kind": self.by_kind,
        }


def frf_agreement(
    frf: FrfData,
    model: ForwardModel,
    *,
    exponential_tau_s: float | None = None,
    coherence_threshold: float | None = 0.99,
    band_hz: tuple[float, float] | None = None,
) -> FrfAgreement:
    """Compare measured FRFs with :func:`model_frf` where ``coherence > coherence_threshold``
    (``None``: every value, e.g. noise-free single-average FRFs, whose coherence is undefined)."""
    if frf.coherence is None and coherence_threshold is not None:
        raise DataError("the FRFs carry no coherence; compare FRFs from an impact session")
    f = frf.frequencies_hz
    sel = np.ones(f.size, bool)
    if band_hz is not None:
        sel = (f >= band_hz[0]) & (f <= band_hz[1])
    H_true = model_frf(model, f[sel], exponential_tau_s)
    H = frf.H[sel]
    keep = (
        np.ones(H.shape, bool)
        if coherence_threshold is None or frf.coherence is None
        else frf.coherence[sel] > coherence_threshold
    )
    rel = np.abs(H - H_true) / np.maximum(np.abs(H_true), np.finfo(float).tiny)
    kept = rel[keep]
    if kept.size == 0:
        raise DataError(f"no FRF value has coherence above {coherence_threshold}")
    kinds = np.array(frf.output_kinds)
    by_kind = {}
    for kind in ("acceleration", "reaction"):
        m = keep & (kinds == kind)[None, :, None]
        if m.any():
            by_kind[kind] = float(rel[m].max())
    return FrfAgreement(
        max_rel_error=float(kept.max()),
        p99_rel_error=float(np.quantile(kept, 0.99)),
        median_rel_error=float(np.median(kept)),
        fraction_kept=float(keep.mean()),
        n_kept=int(kept.size),
        coherence_threshold=coherence_threshold,
        band_hz=(float(f[sel][0]), float(f[sel][-1])),
        by_kind=by_kind,
    )


# ---------------------------------------------------------------------------------------------
# One scenario, end to end
# ---------------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class ScenarioRun:
    """An acquired scenario: the true model, its setup, the session result and the FRFs."""

    model: ForwardModel
    setup: TestSetup
    result: ImpactResult
    frf: FrfData
    settings: ImpactSettings


def impact_settings(
    averages_per_input: int,
    *,
    record_samples: int = 4096,
    exponential_tau_s: float | None = None,
    force_window_samples: int | None = 64,
) -> ImpactSettings:
    """Impact settings of the simulated tests (trigger at 5 N, 32 samples pre-trigger)."""
    return ImpactSettings(
        record_samples=record_samples,
        pretrigger_samples=32,
        trigger_level_n=5.0,
        averages_per_input=averages_per_input,
        force_window_samples=force_window_samples,
        exponential_tau_s=exponential_tau_s,
        block_samples=512,
    )


def run_scenario(
    model: ForwardModel,
    *,
    averages_per_input: int = 5,
    seed: int = 0,
    sample_rate_hz: float = 2048.0,
    record_samples: int = 4096,
    exponential_tau_s: float | None = None,
    noise: LabNoise | None = None,
    hammer: Hammer | None = None,
    data_path: Path | None = None,
    progress: Callable[[Progress], None] | None = None,
    calibration: Mapping[int, FloatArray] | None = None,
    gauge_sensitivity: dict[int, FloatArray] | None = None,
    bridges: dict[int, Any] | None = None,
) -> ScenarioRun:
    """Acquire ``model`` through the simulated USB DAQ and CAN load cells; FRFs in setup order.

    ``bridges`` (node → :class:`~dimacq.simulators.lab.bridge.StrainGaugeCell`): DC-coupled
    strain-gauge cells; the others are AC-coupled. The lab keeps only a few blocks cached (the
    session streams through it once).
    """
    lab = VirtualLab(
        model,
        sample_rate_hz=sample_rate_hz,
        hammer=hammer or Hammer(peak_n=200.0),
        noise=noise if noise is not None else default_noise(),
        gauge_sensitivity=gauge_sensitivity,
        seed=seed,
        bridges=bridges,
        cache_blocks=_STREAM_CACHE_BLOCKS,
    )
    settings = impact_settings(
        averages_per_input, record_samples=record_samples, exponential_tau_s=exponential_tau_s
    )
    with SimulatedRig(lab, calibration=calibration) as rig:
        result = rig.run(settings, data_path=data_path, progress=progress)
    frf = impact_frf(
        result,
        model.setup,
        meta={
            "source": "dimacq acquire (simulated USB DAQ + CAN load cells)",
            "scenario": model.setup.name,
        },
    )
    return ScenarioRun(model, model.setup, result, frf, settings)


# ---------------------------------------------------------------------------------------------
# Load cell inertial calibration on the virtual bench
# ---------------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class CalibrationRun:
    """Inertial calibration on the virtual bench and its circular DIM check.

    Attributes
    ----------
    matrix : (6, 12) fitted ``C``
    true_matrix : (6, 12) ``pinv(S)`` of the simulated cell
    matrix_error_rel : ``‖C − S⁺‖_F / ‖S⁺‖_F``
    fit : LoadCellCalibrationFit (residual, singular values, condition)
    circular : DimResult of the DIM test through ``C``
    circular_errors_pct : % error per parameter (mass, CG, inertia about P) and principal moments
    circular_mass_error_pct : float
    band_hz : band used for the calibration
    """

    matrix: FloatArray
    true_matrix: FloatArray
    matrix_error_rel: float
    fit: Any
    circular: Any
    circular_errors_pct: dict[str, float]
    circular_mass_error_pct: float
    band_hz: tuple[float, float]
    node: int
    averages_per_input: int
    method: str = "inertial"
    certificate: Any = None
    static_run: Any = None
    gauge_unit: str = "mV/V"

    def to_json(self) -> dict[str, Any]:
        """The figures; the contract keys first: ``method``, ``matrix_error_rel``,
        ``nonlinearity_pct_fs``, ``hysteresis_pct_fs``, ``uncertainty_pct_fs`` (six values
        each; None for the inertial method, which cannot see them), ``circular_mass_error_pct``.
        """
        fit = self.fit
        cert = self.certificate
        return {
            "method": self.method,
            "matrix_error_rel": self.matrix_error_rel,
            "nonlinearity_pct_fs": None if cert is None else cert.nonlinearity_pct_fs.tolist(),
            "hysteresis_pct_fs": None if cert is None else cert.hysteresis_pct_fs.tolist(),
            "uncertainty_pct_fs": (
                self.inertial_uncertainty_pct_fs()
                if cert is None
                else cert.uncertainty_pct_fs.tolist()
            ),
            "circular_mass_error_pct": self.circular_mass_error_pct,
            "crosstalk_pct_fs": None if cert is None else cert.crosstalk_pct_fs.tolist(),
            "rated_load": None if cert is None else cert.rated_load.tolist(),
            "verdict": "ok" if cert is None else cert.verdict,
            "reasons": [] if cert is None else list(cert.reasons),
            "gauge_unit": self.gauge_unit,
            "load_cell_node": self.node,
            "averages_per_input": self.averages_per_input,
            "band_hz": list(self.band_hz),
            "circular_dim_band_hz": list(self.circular.band_hz),
            "circular_errors_pct": self.circular_errors_pct,
            "fit": {
                "residual_rel": fit.residual_rel,
                "residual_rel_per_load": fit.residual_rel_per_load.tolist(),
                "singular_values": fit.singular_values.tolist(),
                "rank_used": fit.rank_used,
                "condition": fit.condition,
                "noise_separation": fit.noise_separation,
                "load_condition": fit.load_condition,
                "n_equations": fit.n_equations,
            },
            "matrix": self.matrix.tolist(),
            "true_matrix": self.true_matrix.tolist(),
        }

    def inertial_uncertainty_pct_fs(self) -> list[float]:
        """Inertial method: expanded (k = 2) relative residual of each load row, % of that
        row's rms dynamic load (the method has no rated-load reference: a bound, not % FS)."""
        return [float(v) for v in 200 * np.asarray(self.fit.residual_rel_per_load, float)]


def simulated_inertial_calibration(
    *,
    seed: int = 0,
    averages_per_input: int = 5,
    band_hz: tuple[float, float] = (5.0, 800.0),
    dim_band_hz: tuple[float, float] = DIM_BAND_HZ,
    noise: LabNoise | None = None,
    progress: Callable[[str, Progress], None] | None = None,
    method: Literal["inertial", "static"] = "inertial",
    gauges: Literal["strain-gauge", "piezo"] = "strain-gauge",
    static_progress: Callable[[int, int, str], None] | None = None,
    minimal_plan: bool = False,
) -> CalibrationRun:
    """Calibrate the calibration mass's load cell on the virtual bench, then check circularly.

    The cell is the virtual lab's strain-gauge cell (DC bridges, mV/V,
    :func:`~dimacq.simulators.lab.bridge.strain_gauge_cell`) or, with ``gauges="piezo"``, the
    AC-coupled gauges of the thesis's cell (V). One and the same cell serves every step.

    1. **Static** (``method="static"``, strain gauges only): the dead-weight calibration
       (:func:`~dimacq.services.loadcell_calibration.simulated_static_calibration`) gives ``C``
       and the certificate.
    1. **Inertial** (``method="inertial"``, method §8, thesis §4.1): the calibration mass hangs
       on its cell on bungees; the 24 impacts land on the support side of the cell
       (:class:`~dimacq.simulators.loadcell.bench.SupportSideBench`), so the cell carries every
       force on the mass. Accelerometer FRFs and the 12 gauge FRFs come through the USB and CAN
       simulators; the accelerances are condensed to ``a_O`` (GCS origin, least squares over
       the 24 axes) and :func:`~dimacq.pipeline.loadcell_calibration.inertial_calibration`
       solves ``C`` from ``C g = s T_c⁻¹ M_rb a_O`` over the band.
    2. **Circular check** (thesis §4.1: "the same structure used to calibrate the load cell in
       the same configuration"): the same mass on the same cell, now struck directly on the mass,
       acquired with the driver applying ``C``, solved by DIM (all ten properties unknown).
    """
    from dimacq.pipeline import dim
    from dimacq.pipeline.loadcell_calibration import inertial_calibration
    from dimacq.pipeline.rigid_body import condense, response_matrix
    from dimacq.simulators.lab.bridge import strain_gauge_cell
    from dimacq.simulators.loadcell.bench import SupportSideBench

    if method not in ("inertial", "static"):
        raise SetupError(f"calibration method {method!r}: use static or inertial")
    if method == "static" and gauges != "strain-gauge":
        raise SetupError(
            "static dead-weight calibration needs DC-coupled gauges; the piezo variant is "
            "AC-coupled: use --method inertial"
        )
    model = calibration_mass(seed, support="bungee")
    setup = model.setup
    (support,) = model.supports
    bridges = None
    if gauges == "strain-gauge":
        bridges = {support.node: strain_gauge_cell(support.node)}
    base_noise = noise if noise is not None else default_noise()

    def prog(stage: str) -> Callable[[Progress], None] | None:
        if progress is None:
            return None
        return lambda p: progress(stage, p)

    certificate = None
    static_run = None
    if method == "static":
        from dimacq.services.loadcell_calibration import simulated_static_calibration

        assert bridges is not None
        cell = bridges[support.node]
        srun = simulated_static_calibration(
            seed=seed,
            node=support.node,
            cell=cell,
            minimal_plan=minimal_plan,
            progress=static_progress,
        )
        S = np.asarray(cell.sensitivity_mvv, float)
        fit = srun.run.certificate.fit
        certificate = srun.run.certificate
        static_run = srun.run
        band = (0.0, 0.0)
    else:
        bench_noise = replace(base_noise, force_noise_n=0.0)
        lab = VirtualLab(
            model,
            hammer=Hammer(peak_n=200.0),
            noise=bench_noise,
            seed=seed,
            bridges=bridges,
            cache_blocks=_STREAM_CACHE_BLOCKS,
        )
        S = lab.gauge_matrix(support.node)
        bench = SupportSideBench(lab, support.node)
        settings = impact_settings(averages_per_input)
        # A new cell: its driver has no matrix (the bench finds it), gauge outputs only.
        with SimulatedRig(lab, source=bench, uncalibrated=True) as rig:
            res = rig.run(settings, progress=prog("bench"), loadcell_outputs="gauges")
        f = res.frequencies_hz
        sel = (f >= band_hz[0]) & (f <= band_hz[1])
        n_acc = len(setup.responses)
        P = np.zeros(3)
        psi = response_matrix(setup.response_positions, setup.response_directions, P)
        Tq = condense(psi).transform  # (6, n_acc)
        acc = res.H[sel, :n_acc]
        a_p = np.einsum("kc,lci->lki", Tq, acc.real) + 1j * np.einsum("kc,lci->lki", Tq, acc.imag)
        gauge_frf = res.H[sel, n_acc : n_acc + 12]
        del res, acc
        fit = inertial_calibration(
            gauge_frf,
            a_p,
            model.properties.mass_matrix(P),
            support.position_m,
            support.rotation,
            P,
            sign=1.0 if support.sign == "on_structure" else -1.0,
        )
        band = (float(f[sel][0]), float(f[sel][-1]))
    C = fit.matrix
    C_true = np.linalg.pinv(S)
    err = float(np.linalg.norm(C - C_true) / np.linalg.norm(C_true))
    log.info("%s calibration: matrix error %.3g (relative Frobenius)", method, err)

    run = run_scenario(
        model,
        averages_per_input=averages_per_input,
        seed=seed + 1,
        noise=base_noise,
        progress=prog("circular check"),
        calibration={support.node: C},
        gauge_sensitivity={support.node: S},
        bridges=bridges,
    )
    sol = dim.solve(run.frf, setup, known={}, band_hz=dim_band_hz)
    errs = solution_errors(sol, model.properties)
    return CalibrationRun(
        matrix=C,
        true_matrix=np.asarray(C_true, dtype=np.float64),
        matrix_error_rel=err,
        fit=fit,
        circular=sol,
        circular_errors_pct=errs,
        circular_mass_error_pct=errs["mass_pct"],
        band_hz=band,
        node=support.node,
        averages_per_input=averages_per_input,
        method=method,
        certificate=certificate,
        static_run=static_run,
        gauge_unit="mV/V" if bridges else "V",
    )


def solution_errors(sol: Any, props: Any) -> dict[str, float]:
    """Errors of a DIM solution against the true properties: mass %, CG distance (mm) and per
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
