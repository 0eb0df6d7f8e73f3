"""Virtual-lab scenarios: versioned files in ``config/scenarios/`` that fix a simulated test.

A scenario file (TOML, ``schema_version = 1``) names the test article and its support, the
recommended DIM band, the frequency axis of the model FRFs, the errors between the true and the
nominal (written) geometry, the transducers' imperfections, the hammer and the acquisition
settings for time-domain simulation. Every item is checked on loading; a bad file is refused with
the item and the fix named (:class:`~dimacq.errors.SetupError`). Everything random derives from
the scenario's ``seed`` (or the one given on the command line), so a scenario is deterministic.

File layout (every table but ``[article]`` and ``[band]`` optional)::

    schema_version = 1
    name = "calibration-mass-bungee"
    description = "..."
    seed = 0

    [article]          # model = calibration-mass | x38 | cube
    model = "calibration-mass"
    support = "bungee"             # calibration-mass: bungee | air-ride | ground | free
    sensor_skew_deg = 25.0         # calibration-mass: random triax rotations up to this angle
    flexible = true                # x38: drogue-chute pair near 5 Hz, tails near 23 Hz
    elastic_modes_hz = [17.0, 24.0, 31.0]  # x38: hull bending/torsion/lateral instead of those
    elastic_modal_mass_fraction = 0.2      # x38 hull modes: modal mass / vehicle mass
    elastic_damping = 0.02         # x38 hull modes: damping ratio
    half_size_m = 1.0              # cube: triaxes at (±H, ±H, ±H)

    [band]             # the recommended DIM band, Hz
    lo_hz = 20.0
    hi_hz = 60.0

    [frequency_axis]   # lines k·resolution_hz, k = 1 .. max_hz/resolution_hz
    max_hz = 200.0
    resolution_hz = 0.5

    [analysis]
    exclude_nodes = []             # response nodes the recommended solution leaves out

    [errors]           # true vs nominal geometry (standard deviations)
    position_m = 0.0               # per triax and per input point
    orientation_deg = 0.0          # rotation of each triax about a random axis
    line_of_action_deg = 0.0       # rotation of each input's line of action

    [transducers]      # time-domain signals (model FRFs: see model_frf)
    accel_noise_ms2 = 5e-4
    force_noise_n = 0.05
    gauge_noise_v = 2e-6
    gauge_drift_v_per_s = 0.0
    sensitivity_error = 0.0        # relative, per accelerometer axis
    cross_axis = 0.0               # fraction of the other two axes of the triax

    [loadcell]         # the 6-DOF load cells' gauges
    kind = "strain-gauge"          # strain-gauge (DC bridges, mV/V) | piezo (AC-coupled, V)
    excitation_v = 10.0            # strain-gauge: bridge excitation
    noise_uv = 0.05                # strain-gauge: amplifier input noise, µV rms per sample
    nonlinearity_pct_fs = 0.05     # strain-gauge: per axis, % of rated load
    hysteresis_pct_fs = 0.03       # strain-gauge: per axis, % of rated load

    [hammer]
    peak_n = 200.0
    pulse_sigma_ms = 0.7           # Gaussian pulse; omitted: 1.4 samples
    double_hit_probability = 0.0
    double_hit_delay_ms = 4.0
    double_hit_ratio = 0.4
    line_of_action_error_deg = 0.0 # each strike's direction off the input's, std

    [acquisition]
    sample_rate_hz = 2048.0
    record_samples = 4096
    averages = 5
    pretrigger_samples = 64
    exponential_tau_s = 0.5
    settle_s = 30.0                # the operator waits for the swing to die down

    [shaker]           # dimacq simulate --time-domain --excitation random|burst-random|swept-sine
    kind = "random"                # random | burst-random | swept-sine
    shakers = 2                    # driving at once (multiple-input H1); moved input group by group
    inputs = []                    # input indices (from 0) visited; empty: all
    level_n = 20.0                 # rms (random) or amplitude (sine), N
    record_samples = 4096          # omitted: acquisition.record_samples
    averages = 40                  # Welch segments (random) or records per shaker position
    overlap = 0.5                  # random: Welch overlap (Hann window)
    burst_fraction = 0.5           # burst random: rectangular window, burst then decay
    sweep = "linear"               # swept sine: linear | log chirp per record
    f_lo_hz = 10.0                 # sweep start, random band's lower edge; omitted: band.lo_hz / 2
    f_hi_hz = 400.0                # sweep end, random band's upper edge; omitted: frequency_axis.max_hz
    band_limited = true            # random kinds: band-pass the drive (FIR) to f_lo_hz–f_hi_hz
    settle_s = 2.0                 # drive time before the first record
    oversample = 4                 # internal rate of the exact integration (anti-alias filter)
"""

from __future__ import annotations

import logging
import tomllib
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray
from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator
from scipy.spatial.transform import Rotation

from dimacq.errors import SetupError
from dimacq.io.validation import refuse
from dimacq.model.frf import FrfData
from dimacq.model.properties import RigidBodyProperties
from dimacq.model.setup import Excitation, GeometryUncertainty, ResponseChannel, TestSetup
from dimacq.simulators.lab.elastic import hull_modes
from dimacq.simulators.lab.forward import (
    ForwardModel,
    calibration_mass,
    cube,
    reference_block,
    x38_like,
)

__all__ = [
    "SCENARIO_DIR",
    "BuiltScenario",
    "LoadCellSpec",
    "Scenario",
    "ShakerSpec",
    "build_scenario",
    "gross_errors",
    "list_scenarios",
    "load_scenario",
    "mismounted_truth",
]

log = logging.getLogger(__name__)

FloatArray = NDArray[np.float64]

#: Where the bundled scenario files live (``config/scenarios/`` of the checkout).
SCENARIO_DIR = Path(__file__).resolve().parents[2] / "config" / "scenarios"


class _Spec(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class ArticleSpec(_Spec):
    model: Literal["calibration-mass", "x38", "cube", "reference-block"] = Field(
        description="the test article: calibration-mass, x38, cube or reference-block (the "
        "lab's weighed aluminium block for the chain calibration, on a bungee)"
    )
    support: Literal["bungee", "air-ride", "ground", "free"] | None = Field(
        default=None, description="calibration-mass support: bungee, air-ride, ground or free"
    )
    sensor_skew_deg: float = Field(
        default=25.0, ge=0, le=180, description="largest random triax rotation, degrees (0–180)"
    )
    flexible: bool = Field(default=True, description="x38: true to include the elastic modes")
    chute_modes_hz: tuple[float, float] | None = Field(
        default=None,
        description="x38: the drogue-chute pair's lateral and vertical frequencies, Hz "
        "(default 4.8, 5.3)",
    )
    deformation_mode_hz: float | None = Field(
        default=None, gt=0, description="x38: first deformation (tails) mode, Hz (default 23)"
    )
    suspension_hz: float | None = Field(
        default=None,
        gt=0,
        description="x38: nominal vertical frequency of each air-ride support, Hz (default 1.8)",
    )
    half_size_m: float | None = Field(
        default=None, gt=0, description="cube: half the side H in metres (> 0)"
    )
    elastic_modes_hz: tuple[float, float, float] | None = Field(
        default=None,
        description="x38: global hull modes instead of the chute pair and tails: vertical "
        "bending, torsion, lateral bending, Hz (simulators.lab.elastic)",
    )
    elastic_modal_mass_fraction: float | None = Field(
        default=None, gt=0, le=1, description="x38 hull modes: modal mass / vehicle mass (0.2)"
    )
    elastic_damping: float | None = Field(
        default=None, ge=0, lt=1, description="x38 hull modes: damping ratio (default 0.02)"
    )

    @model_validator(mode="after")
    def _fits_model(self) -> ArticleSpec:
        if self.model == "calibration-mass" and self.support is None:
            raise ValueError(
                "calibration-mass needs article.support = bungee, air-ride, ground or free"
            )
        if self.model != "calibration-mass" and self.support is not None:
            raise ValueError(
                f"article.support applies to the calibration mass only; remove it for {self.model}"
            )
        if self.model == "cube" and self.half_size_m is None:
            raise ValueError("cube needs article.half_size_m (H, metres; triaxes at ±H)")
        x38_only = {
            k: v
            for k, v in (
                ("chute_modes_hz", self.chute_modes_hz),
                ("deformation_mode_hz", self.deformation_mode_hz),
                ("suspension_hz", self.suspension_hz),
                ("elastic_modes_hz", self.elastic_modes_hz),
                ("elastic_modal_mass_fraction", self.elastic_modal_mass_fraction),
                ("elastic_damping", self.elastic_damping),
            )
            if v is not None
        }
        if self.model != "x38" and x38_only:
            raise ValueError(
                f"article.{', '.join(x38_only)} applies to the x38 only; remove it for {self.model}"
            )
        if self.model != "cube" and self.half_size_m is not None:
            raise ValueError(
                f"article.half_size_m applies to the cube only; remove it for {self.model}"
            )
        return self


class BandSpec(_Spec):
    lo_hz: float = Field(gt=0, description="lower edge of the recommended DIM band, Hz (> 0)")
    hi_hz: float = Field(gt=0, description="upper edge of the recommended DIM band, Hz (> lo_hz)")

    @model_validator(mode="after")
    def _ordered(self) -> BandSpec:
        if self.hi_hz <= self.lo_hz:
            raise ValueError(
                f"band.hi_hz = {self.hi_hz} is not above band.lo_hz = {self.lo_hz}; give lo_hz < hi_hz"
            )
        return self


class FrequencyAxisSpec(_Spec):
    max_hz: float = Field(default=200.0, gt=0, description="highest model FRF line, Hz (> 0)")
    resolution_hz: float = Field(default=0.5, gt=0, description="line spacing, Hz (> 0)")

    @model_validator(mode="after")
    def _lines(self) -> FrequencyAxisSpec:
        n = self.max_hz / self.resolution_hz
        if n < 1 or n > 200_000:
            raise ValueError(
                f"frequency_axis gives {n:.0f} lines; choose max_hz / resolution_hz between 1 and 200000"
            )
        return self


class AnalysisSpec(_Spec):
    exclude_nodes: tuple[int, ...] = Field(
        default=(), description="response nodes the recommended solution leaves out (list of ints)"
    )


class ErrorsSpec(_Spec):
    position_m: float = Field(
        default=0.0, ge=0, le=0.5, description="position error std, m (0–0.5)"
    )
    orientation_deg: float = Field(
        default=0.0, ge=0, le=45, description="triax orientation error std, degrees (0–45)"
    )
    line_of_action_deg: float = Field(
        default=0.0, ge=0, le=45, description="line-of-action error std, degrees (0–45)"
    )
    mismounted_channels: int = Field(
        default=0,
        ge=0,
        le=50,
        description="single accelerometer axes mounted off their stated direction by a gross "
        "angle (mismount_deg): a sensor turned on its base, a wrong axis label (0–50)",
    )
    mismount_deg: float = Field(
        default=15.0, gt=0, le=90, description="angle of a mis-mounted axis, degrees (0–90]"
    )
    bad_impacts: int = Field(
        default=0,
        ge=0,
        le=50,
        description="inputs struck away from their stated point and line of action by "
        "bad_impact_deg and bad_impact_shift_m (0–50)",
    )
    bad_impact_deg: float = Field(
        default=20.0, gt=0, le=90, description="line-of-action error of a bad impact, degrees"
    )
    bad_impact_shift_m: float = Field(
        default=0.03, ge=0, le=1, description="point error of a bad impact, m (0–1)"
    )


class TransducerSpec(_Spec):
    accel_noise_ms2: float = Field(
        default=5e-4, ge=0, description="accelerometer noise rms, m/s² (≥ 0)"
    )
    force_noise_n: float = Field(default=0.05, ge=0, description="hammer force noise rms, N (≥ 0)")
    gauge_noise_v: float = Field(
        default=2e-6, ge=0, description="load cell gauge noise rms, V (≥ 0)"
    )
    gauge_drift_v_per_s: float = Field(default=0.0, ge=0, description="gauge zero drift, V/s (≥ 0)")
    sensitivity_error: float = Field(
        default=0.0,
        ge=0,
        le=0.5,
        description="relative accelerometer sensitivity error std (0–0.5)",
    )
    cross_axis: float = Field(
        default=0.0, ge=0, le=0.2, description="cross-axis sensitivity, fraction (0–0.2)"
    )


class LoadCellSpec(_Spec):
    kind: Literal["strain-gauge", "piezo"] = Field(
        default="strain-gauge",
        description="load cell gauges: strain-gauge (DC-coupled bridges, mV/V) or piezo "
        "(AC-coupled, V)",
    )
    excitation_v: float = Field(default=10.0, gt=0, le=20, description="bridge excitation, V")
    rated_scale: float = Field(
        default=1.0,
        gt=0,
        le=1000,
        description="cell size: rated loads this many times (500, 500, 1000 N, 50 N·m) and a "
        "sensitivity this many times smaller (a cell chosen for the article's loads)",
    )
    noise_uv: float = Field(
        default=0.05, ge=0, description="amplifier input noise, µV rms per sample (≥ 0)"
    )
    nonlinearity_pct_fs: float = Field(
        default=0.05, ge=0, le=5, description="nonlinearity per axis, % of rated load (0–5)"
    )
    hysteresis_pct_fs: float = Field(
        default=0.03, ge=0, le=5, description="hysteresis per axis, % of rated load (0–5)"
    )


class HammerSpec(_Spec):
    peak_n: float = Field(default=200.0, gt=0, description="peak hammer force, N (> 0)")
    pulse_sigma_ms: float | None = Field(
        default=None, gt=0, description="Gaussian pulse width (std), ms (> 0)"
    )
    double_hit_probability: float = Field(
        default=0.0, ge=0, le=1, description="probability of a double hit (0–1)"
    )
    double_hit_delay_ms: float = Field(
        default=4.0, gt=0, description="delay of the second hit, ms (> 0)"
    )
    double_hit_ratio: float = Field(
        default=0.4, gt=0, le=1, description="second hit / first hit (0–1]"
    )
    line_of_action_error_deg: float = Field(
        default=0.0,
        ge=0,
        le=30,
        description="std of each strike's angle from the input's line of action, degrees (0–30)",
    )


class ShakerSpec(_Spec):
    kind: Literal["random", "burst-random", "swept-sine"] = Field(
        default="random", description="shaker signal: random, burst-random or swept-sine"
    )
    shakers: int = Field(
        default=2, ge=1, le=8, description="shakers driving at once (multiple-input test, 1–8)"
    )
    inputs: tuple[int, ...] = Field(
        default=(),
        description="indices (from 0) of the inputs the shakers visit, in groups of `shakers`; "
        "empty: every input",
    )
    level_n: float = Field(
        default=20.0, gt=0, description="rms force (random kinds) or sine amplitude, N (> 0)"
    )
    record_samples: int | None = Field(
        default=None, ge=64, description="samples per record (≥ 64); omit: acquisition's"
    )
    averages: int = Field(
        default=40, ge=1, le=10000, description="averages per shaker position (1–10000)"
    )
    overlap: float = Field(
        default=0.5, ge=0, lt=0.95, description="random: Welch segment overlap, fraction (0–0.95)"
    )
    burst_fraction: float = Field(
        default=0.5, gt=0, lt=1, description="burst random: driven fraction of a record (0–1)"
    )
    sweep: Literal["linear", "log"] = Field(
        default="linear", description="swept sine: linear or log"
    )
    f_lo_hz: float | None = Field(
        default=None,
        gt=0,
        description="sweep start / random band's lower edge, Hz (> 0); omit: band.lo_hz / 2",
    )
    f_hi_hz: float | None = Field(
        default=None,
        gt=0,
        description="sweep end / random band's upper edge, Hz; omit: frequency_axis.max_hz",
    )
    band_limited: bool = Field(
        default=True, description="random kinds: band-pass the drive to f_lo_hz–f_hi_hz (bool)"
    )
    settle_s: float = Field(
        default=2.0, ge=0, description="drive time before the first record, s (≥ 0)"
    )
    oversample: int = Field(
        default=4, ge=1, le=16, description="internal rate factor of the exact integration (1–16)"
    )


class AcquisitionSpec(_Spec):
    sample_rate_hz: float = Field(default=2048.0, gt=0, description="sample rate, S/s (> 0)")
    record_samples: int = Field(default=4096, ge=64, description="samples per record (≥ 64)")
    averages: int = Field(default=5, ge=1, le=1000, description="averages per input (1–1000)")
    pretrigger_samples: int = Field(default=64, ge=0, description="samples before the strike (≥ 0)")
    exponential_tau_s: float | None = Field(
        default=0.5, gt=0, description="exponential window time constant, s (> 0), or omit for none"
    )
    settle_s: float = Field(
        default=30.0, ge=0, description="wait between a record and the next strike, s (≥ 0)"
    )

    @model_validator(mode="after")
    def _fits(self) -> AcquisitionSpec:
        if self.pretrigger_samples >= self.record_samples // 2:
            raise ValueError(
                f"acquisition.pretrigger_samples = {self.pretrigger_samples} leaves no room in "
                f"{self.record_samples} samples; give fewer than record_samples / 2"
            )
        return self


class Scenario(_Spec):
    """One scenario file (see the module docstring)."""

    schema_version: Literal[1] = Field(description="scenario file format version: 1")
    name: str = Field(min_length=1, description="scenario name, e.g. calibration-mass-bungee")
    description: str = Field(default="", description="free text")
    seed: int = Field(default=0, ge=0, description="seed of everything random (integer ≥ 0)")
    article: ArticleSpec
    band: BandSpec
    frequency_axis: FrequencyAxisSpec = FrequencyAxisSpec()
    analysis: AnalysisSpec = AnalysisSpec()
    errors: ErrorsSpec = ErrorsSpec()
    transducers: TransducerSpec = TransducerSpec()
    loadcell: LoadCellSpec = LoadCellSpec()
    hammer: HammerSpec = HammerSpec()
    acquisition: AcquisitionSpec = AcquisitionSpec()
    shaker: ShakerSpec = ShakerSpec()

    @model_validator(mode="after")
    def _band_in_axis(self) -> Scenario:
        if self.band.hi_hz > self.frequency_axis.max_hz:
            raise ValueError(
                f"band.hi_hz = {self.band.hi_hz} lies above frequency_axis.max_hz = "
                f"{self.frequency_axis.max_hz}; raise max_hz or lower the band"
            )
        if self.band.hi_hz >= self.acquisition.sample_rate_hz / 2:
            raise ValueError(
                f"band.hi_hz = {self.band.hi_hz} is not below the Nyquist frequency "
                f"{self.acquisition.sample_rate_hz / 2:g} Hz of acquisition.sample_rate_hz; raise the rate"
            )
        sh, nyq = self.shaker, self.acquisition.sample_rate_hz / 2
        lo = self.band.lo_hz / 2 if sh.f_lo_hz is None else sh.f_lo_hz
        hi = self.frequency_axis.max_hz if sh.f_hi_hz is None else sh.f_hi_hz
        if not lo < hi < nyq:
            raise ValueError(
                f"shaker sweep {lo:g}–{hi:g} Hz does not fit below the Nyquist frequency "
                f"{nyq:g} Hz; give shaker.f_lo_hz < shaker.f_hi_hz < sample_rate_hz / 2"
            )
        return self


# --------------------------------------------------------------------------------------------
# Loading
# --------------------------------------------------------------------------------------------
def _refuse(source: str, err: ValidationError) -> SetupError:
    return refuse(
        "scenario",
        source,
        err,
        Scenario,
        "see the scenario format (dimacq.simulators.lab.scenarios)",
    )


def list_scenarios(directory: Path | None = None) -> dict[str, Path]:
    """Scenario name → file, for every ``*.toml`` in ``directory`` (default :data:`SCENARIO_DIR`)."""
    d = SCENARIO_DIR if directory is None else Path(directory)
    return {p.stem: p for p in sorted(d.glob("*.toml"))}


def load_scenario(name_or_path: str | Path, directory: Path | None = None) -> Scenario:
    """Read and check a scenario by name (a file of :func:`list_scenarios`) or by path.

    Raises
    ------
    SetupError
        Unknown name, unreadable file, TOML syntax error, or an item that fails its check (the
        message names the item and the fix).
    """
    path = Path(name_or_path)
    known = list_scenarios(directory)
    if str(name_or_path) in known:
        path = known[str(name_or_path)]
    elif not path.suffix or not path.exists():
        raise SetupError(
            f"scenario {str(name_or_path)!r} is unknown; use one of {', '.join(known) or '(none)'} "
            "(dimacq simulate --list) or give the path of a scenario .toml file"
        )
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except OSError as err:
        raise SetupError(f"scenario file {path}: cannot read it ({err}); check the path") from err
    except tomllib.TOMLDecodeError as err:
        raise SetupError(
            f"scenario file {path}: not valid TOML ({err}); fix the syntax there"
        ) from err
    try:
        scn = Scenario.model_validate(data)
    except ValidationError as err:
        raise _refuse(f"file {path}", err) from err
    if path.stem != scn.name:
        log.info("scenario file %s holds scenario %r", path, scn.name)
    return scn


# --------------------------------------------------------------------------------------------
# Building
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class BuiltScenario:
    """A scenario made concrete for one seed.

    Attributes
    ----------
    spec : Scenario
    seed : int
    model : ForwardModel
        The TRUE article (geometry, supports, elastic modes).
    setup : TestSetup
        The nominal setup written with the FRFs: the true one with the scenario's geometry errors.
    """

    spec: Scenario
    seed: int
    model: ForwardModel
    setup: TestSetup

    @property
    def truth(self) -> RigidBodyProperties:
        return self.model.properties

    @property
    def band_hz(self) -> tuple[float, float]:
        return (self.spec.band.lo_hz, self.spec.band.hi_hz)

    def frequencies_hz(self) -> FloatArray:
        """The model FRF lines ``k · resolution_hz``, ``k = 1 .. ⌊max_hz / resolution_hz⌋``."""
        ax = self.spec.frequency_axis
        n = int(np.floor(ax.max_hz / ax.resolution_hz + 1e-9))
        return np.asarray(ax.resolution_hz * np.arange(1, n + 1), dtype=np.float64)

    def article(self, rigid_only: bool = False) -> ForwardModel:
        return self.model.rigid() if rigid_only else self.model

    def model_frf(
        self,
        *,
        rigid_only: bool = False,
        noise: float = 0.0,
        frequencies_hz: FloatArray | None = None,
    ) -> FrfData:
        """Model FRFs of the true article, in the nominal setup's channel order.

        ``noise`` adds complex Gaussian noise with a standard deviation of ``noise`` times the RMS
        magnitude of each FRF (over the lines), seeded by the scenario seed; 0 gives exact FRFs.
        """
        f = self.frequencies_hz() if frequencies_hz is None else np.asarray(frequencies_hz, float)
        frf = self.article(rigid_only).frf(f)
        if noise < 0:
            raise SetupError(f"noise = {noise}; give a relative noise level ≥ 0")
        if noise > 0:
            rng = np.random.default_rng([self.seed, 23])
            rms = np.sqrt(np.mean(np.abs(frf.H) ** 2, axis=0, keepdims=True))
            e = rng.standard_normal(frf.H.shape) + 1j * rng.standard_normal(frf.H.shape)
            frf = frf.replace(H=frf.H + noise * rms * e / np.sqrt(2))
        return frf.replace(meta={"source": f"dimacq simulate {self.spec.name} (model)"})

    def truth_json(self) -> dict[str, Any]:
        """The true properties with the keys of ``dimacq solve --json`` plus the scenario's advice."""
        out = self.truth.to_json(self.setup.reference_point)
        out.update(
            scenario=self.spec.name,
            seed=self.seed,
            band_hz=list(self.band_hz),
            recommended={
                "band_hz": list(self.band_hz),
                "exclude_nodes": list(self.spec.analysis.exclude_nodes),
            },
            elastic_modes=[
                {"name": m.name, "frequency_hz": m.frequency_hz, "damping_ratio": m.damping_ratio}
                for m in self.model.modes
            ],
            suspension_frequencies_hz=self.model.suspension_frequencies_hz().tolist()
            if self.model.supports
            else [],
        )
        return out


def _article(spec: ArticleSpec, seed: int) -> ForwardModel:
    if spec.model == "reference-block":
        return reference_block(seed)
    if spec.model == "calibration-mass":
        assert spec.support is not None
        return calibration_mass(seed, support=spec.support, sensor_skew_deg=spec.sensor_skew_deg)
    if spec.model == "x38":
        extra: dict[str, Any] = {}
        if spec.chute_modes_hz is not None:
            extra["chute_modes_hz"] = spec.chute_modes_hz
        if spec.deformation_mode_hz is not None:
            extra["deformation_mode_hz"] = spec.deformation_mode_hz
        if spec.suspension_hz is not None:
            extra["suspension_hz"] = spec.suspension_hz
        if spec.elastic_modes_hz is None:
            return x38_like(seed, flexible=spec.flexible, **extra)
        fm = x38_like(seed, flexible=False, **extra)
        if not spec.flexible:
            return fm
        modes = hull_modes(
            spec.elastic_modes_hz,
            mass_kg=fm.properties.mass_kg,
            nodes=fm.node_positions(),
            x_range_m=(0.0, 9.0),
            z_axis_m=float(fm.properties.cg_m[2]),
            modal_mass_fraction=spec.elastic_modal_mass_fraction or 0.2,
            damping_ratio=0.02 if spec.elastic_damping is None else spec.elastic_damping,
        )
        return replace(fm, modes=modes)
    assert spec.half_size_m is not None
    return cube(spec.half_size_m, seed)


def _small_rotation(rng: np.random.Generator, std_deg: float) -> FloatArray:
    """A rotation about a random axis by an angle ~ N(0, std)."""
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    return Rotation.from_rotvec(np.deg2rad(std_deg) * rng.standard_normal() * axis).as_matrix()


def nominal_setup(true_setup: TestSetup, errors: ErrorsSpec, seed: int) -> TestSetup:
    """The setup a user would have: the true geometry with seeded errors.

    Each triax (all axes of one node together) moves by ``N(0, position_m)`` per coordinate and
    turns by a rotation of ``N(0, orientation_deg)`` about a random axis; each input point moves
    likewise and its line of action turns by ``N(0, line_of_action_deg)``. Load cells are exact.
    Then ``bad_impacts`` inputs are told a line of action ``bad_impact_deg`` away and a point
    ``bad_impact_shift_m`` away: gross errors a careful user still makes, which data selection
    must catch. The ``mismounted_channels`` are gross errors of the *true* geometry
    (:func:`mismounted_truth`: an axis that measures ``mismount_deg`` away from where its triax
    says), not of what is stated: a lab states each triax as the jig measured it, an orthonormal
    frame (and a UFF node's system is one), so the stated axes of a triax stay orthogonal.
    The setup states the error levels as its ``geometry_uncertainty`` (what a user would write
    from the digitizer's and jig's accuracy); the gross errors are not stated. The chosen channels
    and inputs are :func:`gross_errors`' answer.
    """
    if (
        errors.position_m == 0
        and errors.orientation_deg == 0
        and errors.line_of_action_deg == 0
        and errors.mismounted_channels == 0
        and errors.bad_impacts == 0
    ):
        return true_setup
    rng = np.random.default_rng([seed, 31])
    node_err: dict[int, tuple[FloatArray, FloatArray]] = {}
    responses = []
    for c in true_setup.responses:
        if c.node not in node_err:
            node_err[c.node] = (
                rng.normal(scale=errors.position_m, size=3),
                _small_rotation(rng, errors.orientation_deg),
            )
        dp, R = node_err[c.node]
        d = R @ np.asarray(c.direction_gcs)
        responses.append(
            ResponseChannel(
                node=c.node,
                direction=c.direction,
                position_m=tuple(float(x) for x in np.asarray(c.position_m) + dp),  # type: ignore[arg-type]
                direction_gcs=tuple(float(x) for x in d / np.linalg.norm(d)),  # type: ignore[arg-type]
                label=c.label,
            )
        )
    inputs = []
    for e in true_setup.excitations:
        dp = rng.normal(scale=errors.position_m, size=3)
        d = _small_rotation(rng, errors.line_of_action_deg) @ np.asarray(e.direction_gcs)
        inputs.append(
            Excitation(
                node=e.node,
                direction=e.direction,
                position_m=tuple(float(x) for x in np.asarray(e.position_m) + dp),  # type: ignore[arg-type]
                direction_gcs=tuple(float(x) for x in d / np.linalg.norm(d)),  # type: ignore[arg-type]
                label=e.label,
            )
        )
    bad_ch, bad_in = gross_errors(true_setup, errors, seed)
    grng = np.random.default_rng([seed, 37])
    for k in bad_ch:  # drawn here too, so that the bad inputs' draws stay as they were
        _turn_normal(np.asarray(responses[k].direction_gcs), errors.mismount_deg, grng)
    for j in bad_in:
        e = inputs[j]
        d = _turn_normal(np.asarray(e.direction_gcs), errors.bad_impact_deg, grng)
        s = grng.normal(size=3)
        p = np.asarray(e.position_m) + errors.bad_impact_shift_m * s / np.linalg.norm(s)
        inputs[j] = e.model_copy(
            update={
                "direction_gcs": tuple(float(x) for x in d),
                "position_m": tuple(float(x) for x in p),
            }
        )
    stated = GeometryUncertainty(
        sensor_position_m=errors.position_m,
        sensor_orientation_deg=errors.orientation_deg,
        input_position_m=errors.position_m,
        line_of_action_deg=errors.line_of_action_deg,
        source="stated",
    )
    return true_setup.model_copy(
        update={
            "responses": tuple(responses),
            "excitations": tuple(inputs),
            "geometry_uncertainty": stated,
        }
    )


def mismounted_truth(true_setup: TestSetup, errors: ErrorsSpec, seed: int) -> TestSetup:
    """The true geometry with the ``mismounted_channels`` of :func:`gross_errors`: each such axis
    measures along a direction ``mismount_deg`` from the one its triax has (turned about an axis
    normal to it; the same seeded draws as before this error moved from the stated to the true
    geometry). What the stated setup says of it is its triax's frame (:func:`nominal_setup`)."""
    bad_ch, _ = gross_errors(true_setup, errors, seed)
    if not bad_ch:
        return true_setup
    grng = np.random.default_rng([seed, 37])
    responses = list(true_setup.responses)
    for k in bad_ch:
        c = responses[k]
        d = _turn_normal(np.asarray(c.direction_gcs), errors.mismount_deg, grng)
        responses[k] = c.model_copy(update={"direction_gcs": tuple(float(x) for x in d)})
    return true_setup.model_copy(update={"responses": tuple(responses)})


def gross_errors(
    true_setup: TestSetup, errors: ErrorsSpec, seed: int
) -> tuple[tuple[int, ...], tuple[int, ...]]:
    """Indices of the mis-mounted response channels and of the bad inputs :func:`nominal_setup`
    makes for ``seed`` (responses and excitations in setup order); the truth a test compares
    data selection against."""
    rng = np.random.default_rng([seed, 41])
    n_ch, n_in = len(true_setup.responses), len(true_setup.excitations)
    if errors.mismounted_channels > n_ch or errors.bad_impacts > n_in:
        raise SetupError(
            f"errors: {errors.mismounted_channels} mis-mounted channels / {errors.bad_impacts} bad "
            f"impacts asked of a setup with {n_ch} channels / {n_in} inputs; give fewer"
        )
    ch = rng.choice(n_ch, size=errors.mismounted_channels, replace=False)
    inp = rng.choice(n_in, size=errors.bad_impacts, replace=False)
    return tuple(sorted(int(k) for k in ch)), tuple(sorted(int(j) for j in inp))


def _turn_normal(d: FloatArray, angle_deg: float, rng: np.random.Generator) -> FloatArray:
    """``d`` turned by ``angle_deg`` about a random axis normal to it (unit result)."""
    a = rng.normal(size=3)
    a -= (a @ d) * d
    a /= np.linalg.norm(a)
    out = Rotation.from_rotvec(np.deg2rad(angle_deg) * a).apply(d)
    return np.asarray(out / np.linalg.norm(out), dtype=np.float64)


def build_scenario(spec: Scenario | str | Path, seed: int | None = None) -> BuiltScenario:
    """Make a scenario concrete: the true article and the nominal setup, for ``seed`` (default:
    the scenario's own)."""
    scn = spec if isinstance(spec, Scenario) else load_scenario(spec)
    s = scn.seed if seed is None else int(seed)
    if s < 0:
        raise SetupError(f"seed = {s}; give an integer ≥ 0")
    model = _article(scn.article, s)
    setup = nominal_setup(model.setup, scn.errors, s)
    model = replace(model, setup=mismounted_truth(model.setup, scn.errors, s))
    setup = setup.model_copy(update={"name": scn.name})
    unknown = set(scn.analysis.exclude_nodes) - {c.node for c in setup.responses}
    if unknown:
        raise SetupError(
            f"scenario {scn.name}: analysis.exclude_nodes lists {sorted(unknown)}, which carry no "
            "response; give response nodes of the article"
        )
    return BuiltScenario(scn, s, replace(model, setup=model.setup), setup)
