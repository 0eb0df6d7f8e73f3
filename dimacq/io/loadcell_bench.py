"""The dead-weight calibration bench: ``config/loadcell_bench.toml`` (schema_version 1).

What a static calibration needs to know about the bench, beside the rig file's load cell entry
(which amplifier, which calibration file): the cell's rated loads, the loading arm's geometry
(nominal, and the digitized positions of its hanger points in the cell frame), the weights' step,
the stated uncertainties of the reference loads and the timing of the readings.

.. code-block:: toml

    schema_version = 1
    rated_load = [500.0, 500.0, 1000.0, 50.0, 50.0, 50.0]   # Fx Fy Fz in N, Mx My Mz in N*m
    arm_m = 0.1                    # hanger points at ±arm_m off the cell's axis
    height_m = 0.05                # height of the arm above the cell's origin
    levels = [0.5, 1.0]            # load steps of a series, fractions of its mass
    mass_step_kg = 0.5             # the weight set's smallest step
    plan = "standard"              # standard (22 series) | minimal (14)
    mass_rel_uncertainty = 5e-5    # standard uncertainties of the reference loads
    position_uncertainty_m = 5e-6
    gravity_uncertainty_rad = 1e-4

    [[points]]                     # digitized hanger points, cell frame, m (override nominal)
    name = "arm +x"
    position_m = [0.10001, 0.0, 0.04998]

    [timing]
    sample_rate_hz = 20            # amplifier rate on its own clock
    settle_s = 20.0                # after the operator has placed a load
    average_s = 5.0                # one averaging window
    max_wait_s = 120.0             # give up waiting for creep to stop (reading flagged)
    creep_tolerance = 2e-5         # drift per window allowed, fraction of the reading's change

    [inertial]                     # the inertial bench and the circular check (optional)
    setup_file = "calibration_mass_setup.toml"  # the calibration mass on the cell: responses,
                                   # impact points (struck on the cell's support side for the
                                   # calibration, on the mass for the check), the load cell, and
                                   # [known] its certified mass, CG and inertia (all ten)
    check_setup_file = "calibration_mass_on_cell.toml"  # the mass standing on the cell for the
                                   # circular check (default: setup_file; hung on the cell the
                                   # cell carries too little of the force: inconclusive)
    band_hz = [5.0, 800.0]         # band of the calibration fit
    check_band_hz = [20.0, 400.0]  # DIM band of the circular check
    averages_per_input = 5
    check_tolerance_pct = 0.5      # the circular check passes within this mass error, %

Files are refused item by item (the message names the item and what to give).
"""

from __future__ import annotations

import tomllib
from pathlib import Path
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from dimacq.errors import SetupError
from dimacq.io.validation import refuse
from dimacq.model.types import Finite, OneLine, RelativePath, StrictInt
from dimacq.pipeline.loadcell_calibration import LoadPlan, standard_load_plan

__all__ = ["BenchFile", "load_bench_file"]


class _Model(BaseModel):
    """Numbers strict (no ``"1"`` or ``true``) and finite: :mod:`dimacq.model.types`."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


class BenchPoint(_Model):
    name: OneLine = Field(
        min_length=1, max_length=200, description="a hanger point of the plan, e.g. 'arm +x'"
    )
    position_m: tuple[Finite, Finite, Finite] = Field(description="[x, y, z] in the cell frame, m")


class BenchTiming(_Model):
    sample_rate_hz: StrictInt = Field(default=20, ge=1, le=10000, description="S/s (1–10000)")
    settle_s: Finite = Field(default=20.0, ge=0, le=3600, description="seconds, 0–3600")
    average_s: Finite = Field(default=5.0, ge=0.01, le=3600, description="seconds, 0.01–3600")
    max_wait_s: Finite = Field(default=120.0, ge=0.1, le=86400, description="seconds, 0.1–86400")
    creep_tolerance: Finite = Field(default=2e-5, gt=0, lt=0.1, description="a fraction (0–0.1)")


class InertialBench(_Model):
    setup_file: RelativePath = Field(
        description="the calibration mass's setup file (relative to the bench file, in its folder)"
    )
    check_setup_file: RelativePath | Literal[""] = Field(
        default="",
        description="the calibration mass standing on the cell for the circular check (relative "
        "to the bench file; empty: setup_file)",
    )
    band_hz: tuple[Finite, Finite] = Field(
        default=(5.0, 800.0), description="[lo, hi] Hz of the calibration fit, 0 ≤ lo < hi"
    )
    check_band_hz: tuple[Finite, Finite] = Field(
        default=(20.0, 400.0), description="[lo, hi] Hz of the circular check, 0 ≤ lo < hi"
    )
    averages_per_input: StrictInt = Field(default=5, ge=1, le=100, description="1–100")
    check_tolerance_pct: Finite = Field(
        default=0.5, gt=0, le=100, description="circular check: largest mass error, % (0–100)"
    )

    @model_validator(mode="after")
    def _bands(self) -> InertialBench:
        for name in ("band_hz", "check_band_hz"):
            lo, hi = getattr(self, name)
            if not 0 <= lo < hi:
                raise ValueError(f"{name} = [{lo}, {hi}]: give 0 ≤ lo < hi in Hz")
        return self


class BenchFile(_Model):
    """The dead-weight bench (see the module docstring)."""

    schema_version: Literal[1] = Field(description="schema_version = 1")
    rated_load: tuple[Finite, Finite, Finite, Finite, Finite, Finite] = Field(
        description="six positive rated loads [Fx, Fy, Fz] N, [Mx, My, Mz] N*m"
    )
    arm_m: Finite = Field(default=0.1, gt=0, le=2, description="metres (0–2)")
    height_m: Finite = Field(default=0.05, ge=0, le=2, description="metres (0–2)")
    levels: tuple[Finite, ...] = Field(
        default=(0.5, 1.0), min_length=1, description="increasing fractions ending at 1.0"
    )
    mass_step_kg: Finite = Field(default=0.5, ge=1e-6, le=1e4, description="kilograms > 0")
    plan: Literal["standard", "minimal"] = Field(
        default="standard", description="standard or minimal"
    )
    mass_rel_uncertainty: Finite = Field(default=5e-5, ge=0, lt=0.01, description="fraction")
    position_uncertainty_m: Finite = Field(default=5e-6, ge=0, lt=0.01, description="metres")
    gravity_uncertainty_rad: Finite = Field(default=1e-4, ge=0, lt=0.1, description="radians")
    points: tuple[BenchPoint, ...] = Field(default=(), description="[[points]] entries")
    timing: BenchTiming = BenchTiming()
    inertial: InertialBench | None = Field(default=None, description="[inertial] table")
    #: the file read (relative paths of ``inertial.setup_file`` are from its folder)
    path: Path | None = Field(default=None, exclude=True)

    def inertial_setup_path(self) -> Path:
        """The calibration mass's setup file of ``[inertial]``.

        Raises
        ------
        SetupError
            No ``[inertial]`` table.
        """
        if self.inertial is None:
            raise SetupError(
                f"bench file {self.path}: no [inertial] table; add setup_file (the calibration "
                "mass on the cell, with its certified [known] properties) for the inertial "
                "calibration and the circular check"
            )
        return self._inside(self.inertial.setup_file, "inertial.setup_file")

    def check_setup_path(self) -> Path:
        """The circular check's setup file: ``[inertial] check_setup_file``, else the
        calibration's (:meth:`inertial_setup_path`)."""
        path = self.inertial_setup_path()
        assert self.inertial is not None
        if not self.inertial.check_setup_file:
            return path
        return self._inside(self.inertial.check_setup_file, "inertial.check_setup_file")

    def _inside(self, name: str, item: str) -> Path:
        """``name`` in the bench file's folder; :class:`SetupError` naming ``item`` if it
        resolves outside it (a symbolic link out of the folder)."""
        if self.path is None:
            return Path(name)
        folder = self.path.parent.resolve()
        p = self.path.parent / name
        if not p.resolve().is_relative_to(folder):
            raise SetupError(
                f"bench file {self.path.name}: item '{item}' = {name!r} leaves the bench file's "
                "folder; fix: keep the setup file in that folder or below it"
            )
        return p

    def load_plan(self) -> LoadPlan:
        return standard_load_plan(
            self.rated_load,
            arm_m=self.arm_m,
            height_m=self.height_m,
            levels=self.levels,
            mass_step_kg=self.mass_step_kg,
            minimal=self.plan == "minimal",
            points={p.name: p.position_m for p in self.points},
            mass_rel_uncertainty=self.mass_rel_uncertainty,
            position_uncertainty_m=self.position_uncertainty_m,
            gravity_uncertainty_rad=self.gravity_uncertainty_rad,
        )


def load_bench_file(path: str | Path) -> BenchFile:
    """Read and check a bench file; :class:`SetupError` naming the item otherwise."""
    p = Path(path)
    try:
        data = tomllib.loads(p.read_text(encoding="utf-8"))
    except OSError as err:
        raise SetupError(
            f"bench file {p.name}: cannot read it ({err.strerror}); give the dead-weight bench file "
            "(config/loadcell_bench.toml)"
        ) from err
    except tomllib.TOMLDecodeError as err:
        raise SetupError(f"bench file {p.name}: not valid TOML ({err})") from err
    try:
        bench = BenchFile.model_validate(data)
    except ValidationError as err:
        raise refuse(
            "bench file", p.name, err, BenchFile, "see dimacq/io/loadcell_bench.py"
        ) from err
    bench.load_plan()  # refuses geometry that overloads the cell or unknown points
    return bench.model_copy(update={"path": p})
