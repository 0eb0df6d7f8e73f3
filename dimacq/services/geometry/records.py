"""The geometry service's results (:mod:`dimacq.services.lab.geometry`): points, patches and
their registrations, reference nodes, triax orientations and lines of action, as stored (JSON)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

__all__ = [
    "LineOfAction",
    "NewTest",
    "Orientation",
    "PatchInfo",
    "ReferenceNode",
    "RegisteredPatch",
    "Registration",
    "Shot",
    "Shots",
    "StoredPoint",
    "vec",
]


def vec(v: Sequence[float] | NDArray[np.floating]) -> list[float]:
    """A vector as a list of Python floats (JSON)."""
    return [float(x) for x in np.asarray(v, dtype=float).reshape(-1)]


@dataclass(frozen=True)
class Shot:
    """One raw shot: its sequence number, triangulated tip (array coordinates) and verdict
    (null numbers: the shot could not be triangulated)."""

    seq: int
    tip_array_m: list[float | None]
    speed_of_sound_m_s: float | None
    accepted: bool


@dataclass(frozen=True)
class Shots:
    """Raw shots and the median speed of sound measured on the calibration bar."""

    shots: list[Shot]
    speed_of_sound_m_s: float | None  # null: no shot reached the calibration bar

    def to_json(self) -> dict[str, Any]:
        return asdict(self)


@dataclass(frozen=True)
class StoredPoint:
    """A digitized point as stored; ``position_m`` (GCS) once its patch is registered."""

    id: int
    label: str
    patch: int
    position_array_m: list[float]
    spread_m: list[float]
    n_shots: int
    n_used: int
    position_m: list[float] | None
    created_at: str | None = None  # ISO 8601, UTC (a point is never changed: digitize it again)


@dataclass(frozen=True)
class Registration:
    """``x_G = matrix · x_A + offset_m`` of one patch, with the fit's quality (stored JSON)."""

    matrix: list[list[float]]
    offset_m: list[float]
    method: str
    scale: float
    labels: list[str]
    residual_norm_m: list[float]
    rms_m: float
    planarity: float
    # the check against the limit and the map's uncertainty
    # (:func:`dimacq.services.geometry.geometry_trust.judge_registration`); None in records stored before
    verdict: str | None = None
    reasons: list[str] = field(default_factory=list)
    limit_m: float | None = None
    worst_node: str | None = None
    worst_residual_m: float | None = None
    suspect: str | None = None
    leave_one_out_rms_m: list[float | None] | None = None
    sigma_m: float | None = None
    sigma_used_m: float | None = None
    rotation_uncertainty_deg: float | None = None
    centroid_m: list[float] | None = None
    rotation_normal_inv: list[list[float]] | None = None

    @classmethod
    def from_json(cls, body: Mapping[str, Any]) -> Registration:
        return cls(**body)

    def to_json(self) -> dict[str, Any]:
        return asdict(self)

    def apply(self, position_array_m: Sequence[float]) -> list[float]:
        a = np.asarray(self.matrix, float)
        return vec(a @ np.asarray(position_array_m, float) + np.asarray(self.offset_m, float))


@dataclass(frozen=True)
class PatchInfo:
    """An array position and its registration (None until registered)."""

    index: int
    name: str
    registration: Registration | None
    #: the digitizing test (reference nodes, orientations, lines of action) it belongs to
    test: int = 0

    def to_json(self) -> dict[str, Any]:
        return asdict(self)


@dataclass(frozen=True)
class NewTest:
    """A new digitizing test: its number, its first patch and how many stored items of the
    previous test were cleared (reference nodes, orientations, lines of action)."""

    test: int
    patch: PatchInfo
    cleared: dict[str, int]

    def to_json(self) -> dict[str, Any]:
        return asdict(self)


@dataclass(frozen=True)
class RegisteredPatch:
    index: int
    registration: Registration

    def to_json(self) -> dict[str, Any]:
        return asdict(self)


@dataclass(frozen=True)
class ReferenceNode:
    """A node with known GCS coordinates (metres)."""

    label: str
    position_m: list[float]


@dataclass(frozen=True)
class Orientation:
    """Orientation of the triax at ``node``: ``rotation`` has the sensor axes as columns (GCS);
    ``orthogonality`` and ``max_off_diagonal`` only from the affine fit."""

    node: int
    rotation: list[list[float]]
    origin_m: list[float]
    method: str
    rods: list[int]
    n_points: int
    residual_rms_m: float
    angle_std_deg: list[float]
    uncertainty_deg: float
    orthogonality: list[list[float]] | None = None
    max_off_diagonal: float | None = None
    # ``uncertainty_deg`` = jig fit ⊕ registration (RMS misorientation, degrees) and the
    # origin's 1σ per coordinate (:func:`dimacq.services.geometry.geometry_trust.orientation_uncertainty`);
    # None in records stored before
    jig_uncertainty_deg: float | None = None
    registration_uncertainty_deg: float | None = None
    origin_std_m: float | None = None

    @classmethod
    def from_json(cls, body: Mapping[str, Any]) -> Orientation:
        return cls(**body)

    def to_json(self) -> dict[str, Any]:
        out = asdict(self)
        for k in (
            "orthogonality",
            "max_off_diagonal",
            "jig_uncertainty_deg",
            "registration_uncertainty_deg",
            "origin_std_m",
        ):
            if out[k] is None:
                del out[k]
        return out


@dataclass(frozen=True)
class LineOfAction:
    """Line of action of the input at ``node``: unit ``direction`` through ``point_m`` (GCS)."""

    node: int
    direction: list[float]
    point_m: list[float]
    method: str
    perpendicular_rms_m: float
    angle_std_deg: float
    # ``angle_std_deg`` = fit ⊕ registration and the input point's 1σ per coordinate
    # (:func:`dimacq.services.geometry.geometry_trust.line_of_action_uncertainty`); None in records stored
    # before
    fit_angle_std_deg: float | None = None
    registration_uncertainty_deg: float | None = None
    point_std_m: float | None = None

    @classmethod
    def from_json(cls, body: Mapping[str, Any]) -> LineOfAction:
        return cls(**body)

    def to_json(self) -> dict[str, Any]:
        out = asdict(self)
        for k in ("fit_angle_std_deg", "registration_uncertainty_deg", "point_std_m"):
            if out[k] is None:
                del out[k]
        return out
