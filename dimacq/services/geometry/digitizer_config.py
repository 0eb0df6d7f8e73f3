"""The digitizer's configuration files: ``config/digitizer/array.toml`` and ``jig.toml``.

Pydantic models with ``schema_version``, read and validated with errors that name the field.
"""

from __future__ import annotations

import os
import tomllib
from pathlib import Path
from typing import Any, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator

from dimacq.errors import SetupError
from dimacq.pipeline.digitizing.orientation import JigDefinition
from dimacq.pipeline.digitizing.triangulation import DigitizerGeometry, QualityLimits

__all__ = [
    "SCHEMA_VERSION",
    "ArrayConfig",
    "JigConfig",
    "config_dir",
    "load_array_config",
    "load_jig",
]

SCHEMA_VERSION = 1


def config_dir() -> Path:
    """``$DIMACQ_CONFIG_DIR`` or the repository's ``config/`` folder."""
    base = os.environ.get("DIMACQ_CONFIG_DIR")
    return Path(base) if base else Path(__file__).resolve().parents[3] / "config"


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class _ArraySection(_Model):
    name: str = "sonic array"
    microphones_m: list[tuple[float, float, float]] = Field(min_length=3)
    facing: tuple[float, float, float] = (0.0, 0.0, 1.0)


class _CounterSection(_Model):
    clock_hz: float = Field(gt=0)
    delay_counts: int = Field(ge=0)
    bits: int = Field(default=24, ge=8, le=32)


class _BarSection(_Model):
    length_m: float = Field(gt=0)


class _ProbeSection(_Model):
    emitter_spacing_m: float = Field(gt=0)
    tip_length_m: float


class _QualitySection(_Model):
    max_range_residual_m: float = Field(default=1.0e-3, gt=0)
    spacing_tolerance_m: float = Field(default=1.5e-3, gt=0)
    bar_spread_tolerance_m: float = Field(default=1.0e-3, gt=0)
    speed_min_m_s: float = 300.0
    speed_max_m_s: float = 380.0
    point_outlier_m: float = Field(default=1.0e-3, gt=0)


class _AccuracySection(_Model):
    # 1σ per coordinate of a digitized point (the accepted shots of one point combined): the
    # array's stated accuracy. The simulator's selftest measures 0.16 mm 3-D RMS (0.09 mm per
    # coordinate); 0.3 mm is what a sonic array keeps over a lab's temperature drift and probe
    # tilts. It sets the registration limit (with the reference nodes' accuracy) and the
    # geometry uncertainty a digitized setup states.
    point_m: float = Field(default=3.0e-4, gt=0, le=0.05)


class _VolumeSection(_Model):
    min_m: tuple[float, float, float]
    max_m: tuple[float, float, float]


class ArrayConfig(_Model):
    """``config/digitizer/array.toml``."""

    schema_version: Literal[1]
    array: _ArraySection
    counter: _CounterSection
    bar: _BarSection
    probe: _ProbeSection
    quality: _QualitySection = _QualitySection()
    accuracy: _AccuracySection = _AccuracySection()
    volume: _VolumeSection | None = None

    def geometry(self) -> DigitizerGeometry:
        return DigitizerGeometry(
            microphones_m=np.asarray(self.array.microphones_m, dtype=float),
            facing=np.asarray(self.array.facing, dtype=float),
            bar_length_m=self.bar.length_m,
            delay_s=self.counter.delay_counts / self.counter.clock_hz,
            clock_hz=self.counter.clock_hz,
            emitter_spacing_m=self.probe.emitter_spacing_m,
            tip_length_m=self.probe.tip_length_m,
        )

    def limits(self) -> QualityLimits:
        return QualityLimits(**self.quality.model_dump())


class _JigPoint(_Model):
    label: str
    rod: Literal["X", "Y", "Z"]
    local_m: tuple[float, float, float]


class JigConfig(_Model):
    """``config/digitizer/jig.toml``: calibrated indentation coordinates, 3 rods."""

    schema_version: Literal[1]
    name: str = "orientation jig"
    pitch_m: float = Field(default=0.0254, gt=0)
    first_indentation_m: float = 0.030
    points: list[_JigPoint]

    @field_validator("points")
    @classmethod
    def _three_rods(cls, points: list[_JigPoint]) -> list[_JigPoint]:
        labels = [p.label for p in points]
        dup = sorted({x for x in labels if labels.count(x) > 1})
        if dup:
            raise ValueError(f"duplicate indentation labels {dup}")
        for rod in "XYZ":
            n = sum(p.rod == rod for p in points)
            if n < 2:
                raise ValueError(
                    f"rod {rod} has {n} indentation(s); the jig has three rods, give each rod's "
                    "calibrated points (8 per rod at 25.4 mm pitch)"
                )
        return points

    def definition(self) -> JigDefinition:
        return JigDefinition(
            points_local_m=np.array([p.local_m for p in self.points], dtype=float),
            rod=np.array(["XYZ".index(p.rod) for p in self.points], dtype=np.int64),
            labels=tuple(p.label for p in self.points),
        )


def _read_toml(path: Path, what: str) -> dict[str, Any]:
    try:
        return tomllib.loads(Path(path).read_text())
    except OSError as err:
        raise SetupError(
            f"{what} {path}: cannot read ({err.strerror}); give an existing file"
        ) from err
    except tomllib.TOMLDecodeError as err:
        raise SetupError(f"{what} {path}: not valid TOML ({err}); fix the syntax") from err


def _validation_message(err: ValidationError) -> str:
    return "; ".join(
        f"{'.'.join(str(p) for p in e['loc']) or 'file'}: {e['msg']}" for e in err.errors()
    )


def load_array_config(path: Path | str | None = None) -> ArrayConfig:
    """Read and validate the array configuration (default ``config/digitizer/array.toml``)."""
    p = Path(path) if path else config_dir() / "digitizer" / "array.toml"
    try:
        return ArrayConfig.model_validate(_read_toml(p, "digitizer array config"))
    except ValidationError as err:
        raise SetupError(f"digitizer array config {p}: {_validation_message(err)}") from err


def load_jig(path: Path | str | None = None) -> JigDefinition:
    """Read and validate a jig file (default ``config/digitizer/jig.toml``)."""
    p = Path(path) if path else config_dir() / "digitizer" / "jig.toml"
    try:
        return JigConfig.model_validate(_read_toml(p, "jig file")).definition()
    except ValidationError as err:
        raise SetupError(f"jig file {p}: {_validation_message(err)}") from err
