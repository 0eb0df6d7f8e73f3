"""The test setup: where every transducer and input is, and which way it points.

Coordinates are in the global coordinate system (GCS) of the structure, in metres. A setup file
(TOML or JSON, see :mod:`dimacq.io.setup_file`) holds one :class:`TestSetup`.

Conventions
-----------
- A response channel measures the projection of the acceleration of its point on its GCS unit
  direction ``d``: ``q = dᵀ ü(r)``.
- An excitation is a force of magnitude ``f`` (the FRF's denominator) along the unit line of action
  ``d`` applied at ``r``.
- A 6-DOF load cell at ``r_c`` with local-to-global rotation ``R`` (``x_G = R x_L``; the columns of ``R``
  are the cell's local axes in the GCS) measures ``[f_L; m_L]`` about its own origin. ``sign`` states
  what that is: ``"on_structure"`` — the force and moment the support exerts on the structure
  (the DIM convention, used as is) — or ``"on_support"`` — the force the structure exerts on the
  support, which dimacq negates.
- UFF directions: ``+1 .. +3`` = local +x, +y, +z of the node's displacement coordinate system,
  ``+4 .. +6`` the rotations / moments; a negative value is the opposite direction.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from typing import Annotated, Any, Literal

import numpy as np
from numpy.typing import NDArray
from pydantic import (
    AfterValidator,
    AliasChoices,
    BaseModel,
    ConfigDict,
    Field,
    field_validator,
    model_validator,
)

from dimacq.model.types import Coordinate, Finite, StrictInt, check_one_line

__all__ = [
    "LENGTH_UNITS",
    "PARAMETERS",
    "Excitation",
    "GeometryUncertainty",
    "KnownProperties",
    "LoadCell",
    "NodeNumber",
    "ResponseChannel",
    "TestSetup",
    "TransducerUncertainty",
    "Vec3",
    "direction_label",
]

log = logging.getLogger(__name__)

#: A position or direction: three finite numbers (strict: no strings, no booleans), each within
#: ±COORDINATE_LIMIT.
Vec3 = tuple[Coordinate, Coordinate, Coordinate]
#: A node number: a UFF node label (I10 field, positive), 1..2³¹−1.
NodeNumber = Annotated[StrictInt, Field(ge=1, le=2**31 - 1)]

#: Longest name of a setup or label of a channel, characters.
MAX_NAME_CHARS = 200


def one_line(value: str) -> str:
    """``value`` if it is one line of printable text (:func:`dimacq.model.types.check_one_line`);
    names and labels are written verbatim into exported files (UFF 2420 part names and labels, a
    UFF 58 header line), where a line break ends the record and corrupts the file."""
    return check_one_line(value)


#: A name or label: one line of printable text, at most :data:`MAX_NAME_CHARS` characters.
Name = Annotated[
    str,
    Field(
        max_length=MAX_NAME_CHARS,
        json_schema_extra={"pattern": "^[^\\x00-\\x1f\\x7f-\\x9f\\u2028\\u2029]*$"},
    ),
    AfterValidator(one_line),
]

#: Metres per unit for the length units the solver can work in.
LENGTH_UNITS: dict[str, float] = {"m": 1.0, "cm": 0.01, "mm": 0.001}

_UNIT_TOL = 1e-6


def direction_label(direction: int) -> str:
    """UFF direction ``±1..±6`` as a label: ``+X``, ``-Y``, ``+RZ``."""
    axis = ("X", "Y", "Z", "RX", "RY", "RZ")[abs(direction) - 1]
    return ("+" if direction > 0 else "-") + axis


def _fmt(v: NDArray[np.float64]) -> str:
    return "(" + ", ".join(f"{x:.6g}" for x in v) + ")"


def _check_unit(value: Vec3, what: str) -> Vec3:
    n = float(np.linalg.norm(value))
    if not np.all(np.isfinite(value)):
        raise ValueError(f"{what} has a non-finite component {value}; give three finite numbers")
    if abs(n - 1.0) > _UNIT_TOL:
        raise ValueError(
            f"{what} {tuple(value)} has length {n:.6g}, not 1; give a unit vector "
            f"(e.g. {_fmt(np.asarray(value) / n) if n > 0 else '(1, 0, 0)'})"
        )
    return value


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class ResponseChannel(_Model):
    """One accelerometer axis.

    Attributes
    ----------
    node : int
        Node number (as in UFF).
    direction : int
        UFF direction of the axis in the node's own coordinate system, ``±1..±3``.
    position_m : (3,) float
        Position of the measurement point in the GCS, metres.
    direction_gcs : (3,) float
        Unit vector of the measured direction in the GCS.
    label : str
        Free text, e.g. ``"1103+Y"``.
    """

    node: NodeNumber
    direction: StrictInt = Field(ge=-3, le=3)
    position_m: Vec3
    direction_gcs: Vec3
    label: Name = ""

    @field_validator("direction")
    @classmethod
    def _nonzero(cls, v: int) -> int:
        if v == 0:
            raise ValueError("direction 0 is not a UFF direction; use ±1, ±2 or ±3")
        return v

    @model_validator(mode="after")
    def _unit(self) -> ResponseChannel:
        _check_unit(
            self.direction_gcs,
            f"response {self.node}{direction_label(self.direction)}: direction_gcs",
        )
        return self

    @property
    def name(self) -> str:
        return self.label or f"{self.node}{direction_label(self.direction)}"


class Excitation(_Model):
    """One input: a force along a unit line of action at a point.

    Attributes
    ----------
    node : int
        Input node.
    direction : int
        UFF reference direction ``±1..±3`` in the node's system.
    position_m : (3,) float
        Point of application in the GCS, metres.
    direction_gcs : (3,) float
        Unit line of action in the GCS (the direction of a positive force on the structure).
    """

    node: NodeNumber
    direction: StrictInt = Field(default=1, ge=-3, le=3)
    position_m: Vec3
    direction_gcs: Vec3 | None = None
    label: Name = ""

    @model_validator(mode="after")
    def _unit(self) -> Excitation:
        name = f"input {self.node}{direction_label(self.direction) if self.direction else ''}"
        if self.direction_gcs is None:
            raise ValueError(f"{name} has no line of action; give direction_gcs as a unit vector")
        _check_unit(self.direction_gcs, f"{name}: direction_gcs")
        return self

    @property
    def name(self) -> str:
        return self.label or f"{self.node}{direction_label(self.direction)}"


class LoadCell(_Model):
    """A 6-DOF load cell between the structure and a support.

    Attributes
    ----------
    node : int
        Node number of the cell (its UFF records use directions 1–6 = Fx, Fy, Fz, Mx, My, Mz in
        the cell's local system).
    position_m : (3,) float
        Origin of the cell's measuring system in the GCS, metres.
    rotation : (3, 3) float
        Local-to-global rotation ``R`` (``x_G = R x_L``): column k is local axis k in the GCS.
    sign : {"on_structure", "on_support"}
        What the cell's outputs are: the load the support exerts on the structure, or the load the
        structure exerts on the support (negated by dimacq).
    """

    node: NodeNumber
    position_m: Vec3
    rotation: tuple[Vec3, Vec3, Vec3] = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))
    sign: Literal["on_structure", "on_support"] = "on_structure"
    label: Name = ""

    @model_validator(mode="after")
    def _orthonormal(self) -> LoadCell:
        r = np.asarray(self.rotation, dtype=float)
        err = float(np.max(np.abs(r.T @ r - np.eye(3))))
        if not np.all(np.isfinite(r)) or err > 1e-6 or np.linalg.det(r) < 0:
            raise ValueError(
                f"load cell {self.node}: rotation is not a proper rotation (max |RᵀR − I| = {err:.3g}, "
                f"det = {np.linalg.det(r):.3g}); give the cell's local axes as orthonormal columns, right-handed"
            )
        return self

    @property
    def rotation_matrix(self) -> NDArray[np.float64]:
        return np.asarray(self.rotation, dtype=float)

    @property
    def sign_factor(self) -> float:
        return 1.0 if self.sign == "on_structure" else -1.0

    @property
    def name(self) -> str:
        return self.label or f"LC{self.node}"


class GeometryUncertainty(_Model):
    """The stated uncertainty of the geometry the solver is told (standard uncertainties, 1σ).

    The DIM takes the sensor positions and directions and the inputs' points and lines of action
    as exact; they are not. These values say how far each may be off, per item and independently:
    they widen the 95 % intervals (geometry propagated through the solve), act as priors where the
    geometry is refined from the data, and enter the verdict. Defaults describe a careful test with
    a sonic digitizer and the orientation jig (method.md §1–3); a digitized setup writes its own
    (digitizer and jig fit residuals, registration residual).

    Attributes
    ----------
    sensor_position_m : float
        1σ of each coordinate of each triax position, m.
    sensor_orientation_deg : float
        1σ of each triax's small rotation about each axis, degrees (all axes of a node together).
    input_position_m : float
        1σ of each coordinate of each input point, m.
    line_of_action_deg : float
        1σ of each input's direction about each axis normal to it, degrees.
    load_cell_position_m : float
        1σ of each coordinate of each load cell's point (where its reactions are resolved), m.
        A cell is placed from the rig's drawing or measured like a sensor; the output-error
        refinement moves it within this prior, so that reactions whose moment arms are off do
        not pull the sensors and inputs instead (``dimacq.pipeline.output_error``).
    load_cell_orientation_deg : float
        1σ of each load cell's small rotation about each axis, degrees.
    registration_rms_m : float, optional
        RMS residual of the registration of the digitizer array into the GCS over its reference
        nodes, m (``None``: the geometry was not digitized here, or not recorded).
    registration_limit_m : float, optional
        The residual limit the registration was accepted against, m.
    source : {"default", "stated", "digitized"}
        Where the values come from: these defaults, the user's statement, or the digitizing chain.
    """

    sensor_position_m: Finite = Field(default=0.002, ge=0, le=0.5)
    sensor_orientation_deg: Finite = Field(default=0.5, ge=0, le=45)
    input_position_m: Finite = Field(default=0.002, ge=0, le=0.5)
    line_of_action_deg: Finite = Field(default=1.0, ge=0, le=45)
    load_cell_position_m: Finite = Field(default=0.002, ge=0, le=0.5)
    load_cell_orientation_deg: Finite = Field(default=0.5, ge=0, le=45)
    registration_rms_m: Finite | None = Field(default=None, ge=0, le=1.0)
    registration_limit_m: Finite | None = Field(default=None, gt=0, le=1.0)
    source: Literal["default", "stated", "digitized"] = "default"


class TransducerUncertainty(_Model):
    """The stated calibration uncertainty of the transducers (relative standard uncertainties, 1σ).

    FRFs are scaled by the sensitivities the calibration certificates give, which are off by a
    certificate's uncertainty. A response channel whose sensitivity is off by ``ε`` reports
    ``(1 + ε) dᵀu``; a force transducer off by ``η`` scales every acceleration and reaction FRF by
    ``1/(1 + η)``, so mass and inertia come out ``(1 + η)``-scaled (less where load cells measure
    part of the force) whatever the data: no
    redundancy in the test can find it (only a known mass, ``--scale-to-mass``, can). These values
    enter the 95 % intervals with the geometry (:func:`dimacq.pipeline.uncertainty.geometry_spread`).

    Attributes
    ----------
    accel_sensitivity_rel : float
        1σ relative error of each accelerometer axis's certificate sensitivity (independent per
        axis). Default 0.005 (a back-to-back calibration, ±1 % at k = 2).
    force_sensitivity_rel : float
        1σ relative error of the force transducer's (hammer's) sensitivity, one value common to
        every input struck with it. Default 0.005.
    loadcell_matrix_rel : float
        1σ relative error of each load cell's calibration matrix (its certificate), per output
        component. Default 0.01 (a six-axis cell's certificate, ±2 % at k = 2). The output-error
        fit weighs the lines where the reactions carry much of the force by it
        (:func:`dimacq.pipeline.output_error.noise.line_weights`).
    source : {"default", "stated", "chain"}
        ``chain``: the force term is a chain calibration's (:mod:`dimacq.pipeline.chain_calibration`).
    """

    accel_sensitivity_rel: Finite = Field(default=0.005, ge=0, le=0.5)
    force_sensitivity_rel: Finite = Field(default=0.005, ge=0, le=0.5)
    loadcell_matrix_rel: Finite = Field(default=0.01, ge=0, le=0.5)
    source: Literal["default", "stated", "chain"] = "default"


#: Order of the ten DIM parameters (method.md §6): mass, CG (solved as s = m·c), inertia about P.
PARAMETERS: tuple[str, ...] = ("m", "cx", "cy", "cz", "Ixx", "Ixy", "Ixz", "Iyy", "Iyz", "Izz")


#: Keys of ``known`` before the one vocabulary (read, with a deprecation message).
_OLD_KNOWN_KEYS = ("mass_kg", "cg_m", "inertia_kgm2")


def _known_from_old_keys(data: Mapping[str, Any]) -> dict[str, Any]:
    """``mass_kg`` / ``cg_m`` (a list or a table ``{x, y, z}``) / ``inertia_kgm2`` as parameter
    names (``m``, ``cx``..``cz``, ``Ixx``..``Izz``)."""
    out = {k: v for k, v in data.items() if k not in _OLD_KNOWN_KEYS}
    if data.get("mass_kg") is not None:
        out["m"] = data["mass_kg"]
    cg = data.get("cg_m")
    if isinstance(cg, Mapping):
        extra = set(cg) - {"x", "y", "z"}
        if extra:
            raise ValueError(f"cg_m has unknown key(s) {sorted(extra)}; use cx, cy and/or cz")
        cg = [cg.get(a) for a in "xyz"]
    if cg is not None:
        if not isinstance(cg, list | tuple) or len(cg) != 3:
            raise ValueError("cg_m: give three values (null for unknown); better: cx, cy, cz")
        out.update({k: v for k, v in zip(("cx", "cy", "cz"), cg, strict=True) if v is not None})
    inertia = data.get("inertia_kgm2") or {}
    if not isinstance(inertia, Mapping):
        raise ValueError("inertia_kgm2: give a table of Ixx..Izz; better: Ixx = … directly")
    out.update(inertia)
    return out


_KNOWN_DOC = {
    "m": "mass, kg (> 0)",
    "cx": "CG x in the GCS, m",
    "cy": "CG y in the GCS, m",
    "cz": "CG z in the GCS, m",
} | {
    k: f"{k} about the reference point P, kg·m² (tensor element"
    + (", > 0)" if k[1] == k[2] else ": products carry the tensor sign, −∫ x y dm)")
    for k in ("Ixx", "Ixy", "Ixz", "Iyy", "Iyz", "Izz")
}


class KnownProperties(_Model):
    """Properties known beforehand (any subset), keyed by the ten parameter names
    (:data:`PARAMETERS`): ``m`` (kg), ``cx``, ``cy``, ``cz`` (the CG in the GCS, m) and
    ``Ixx`` .. ``Izz`` (tensor elements about the reference point P, kg·m²; products of inertia
    carry their tensor sign, ``Ixy = −∫ x y dm``) — the names of ``known`` in ``dimacq solve``,
    the API and a solution's ``uncertainty``.

    The keys of the first setup files (``mass_kg``, ``cg_m``, ``inertia_kgm2``) are still read,
    with a deprecation message in the log.
    """

    m: Finite | None = Field(default=None, gt=0, description=_KNOWN_DOC["m"])
    cx: Finite | None = Field(default=None, description=_KNOWN_DOC["cx"])
    cy: Finite | None = Field(default=None, description=_KNOWN_DOC["cy"])
    cz: Finite | None = Field(default=None, description=_KNOWN_DOC["cz"])
    Ixx: Finite | None = Field(default=None, gt=0, description=_KNOWN_DOC["Ixx"])
    Ixy: Finite | None = Field(default=None, description=_KNOWN_DOC["Ixy"])
    Ixz: Finite | None = Field(default=None, description=_KNOWN_DOC["Ixz"])
    Iyy: Finite | None = Field(default=None, gt=0, description=_KNOWN_DOC["Iyy"])
    Iyz: Finite | None = Field(default=None, description=_KNOWN_DOC["Iyz"])
    Izz: Finite | None = Field(default=None, gt=0, description=_KNOWN_DOC["Izz"])

    @model_validator(mode="before")
    @classmethod
    def _old_keys(cls, data: Any) -> Any:
        if isinstance(data, Mapping) and any(k in data for k in _OLD_KNOWN_KEYS):
            old = [k for k in _OLD_KNOWN_KEYS if k in data]
            log.warning(
                "known: %s are the old keys (read as such); write the parameter names m, cx, "
                "cy, cz, Ixx, Ixy, Ixz, Iyy, Iyz, Izz instead (e.g. known = {m = 12.5, cz = "
                "0.15, Ixy = 0.0})",
                ", ".join(old),
            )
            return _known_from_old_keys(data)
        return data

    def as_dict(self) -> dict[str, float]:
        """Known values keyed by parameter name (``m``, ``cx``, ..., ``Izz``)."""
        return {k: float(v) for k in PARAMETERS if (v := getattr(self, k)) is not None}

    @property
    def empty(self) -> bool:
        return not self.as_dict()

    # the grouped views of the first vocabulary, for Python callers
    @property
    def mass_kg(self) -> float | None:
        return self.m

    @property
    def cg_m(self) -> tuple[float | None, float | None, float | None]:
        return (self.cx, self.cy, self.cz)

    @property
    def inertia_kgm2(self) -> dict[str, float]:
        return {k: v for k, v in self.as_dict().items() if k.startswith("I")}


class TestSetup(_Model):
    """Everything the solver needs besides the FRFs.

    Attributes
    ----------
    schema_version : int
        Version of the setup file format (1).
    reference_point_m : (3,) float
        The point P about which forces and motion are condensed and the inertia reported.
    length_unit : {"m", "cm", "mm"}
        Length unit the solver works in (weights moment rows against force rows; thesis Table 15).
    responses, excitations, load_cells
        The transducers and inputs.
    known : KnownProperties
        Optional known properties.
    geometry_uncertainty : GeometryUncertainty
        How far the stated positions and directions may be off (1σ); defaults for a careful test.
    transducer_uncertainty : TransducerUncertainty
        How far the certificate sensitivities may be off (relative 1σ).
    """

    __test__ = False  # not a pytest test class

    schema_version: Literal[1] = 1
    name: Name = ""
    reference_point_m: Vec3 = (0.0, 0.0, 0.0)
    length_unit: Literal["m", "cm", "mm"] = "m"
    responses: tuple[ResponseChannel, ...]
    # "inputs" in files and the API; "excitations", the first name, is still read
    excitations: tuple[Excitation, ...] = Field(
        validation_alias=AliasChoices("inputs", "excitations"),
        serialization_alias="inputs",
        description="the inputs (one per node/direction): point of application and line of "
        "action; the key was 'excitations' in the first setup files",
    )
    load_cells: tuple[LoadCell, ...] = ()
    known: KnownProperties = KnownProperties()
    geometry_uncertainty: GeometryUncertainty = GeometryUncertainty()
    transducer_uncertainty: TransducerUncertainty = TransducerUncertainty()

    @model_validator(mode="after")
    def _unique(self) -> TestSetup:
        seen: set[tuple[int, int]] = set()
        for ch in self.responses:
            key = (ch.node, ch.direction)
            if key in seen:
                raise ValueError(f"response {ch.name} appears twice; give each node/direction once")
            seen.add(key)
        seen_in: set[tuple[int, int]] = set()
        for ex in self.excitations:
            key = (ex.node, ex.direction)
            if key in seen_in:
                raise ValueError(f"input {ex.name} appears twice; give each node/direction once")
            seen_in.add(key)
        nodes = [lc.node for lc in self.load_cells]
        if len(set(nodes)) != len(nodes):
            raise ValueError("two load cells share a node number; give each cell its own node")
        if not self.responses:
            raise ValueError("responses is empty; a DIM test needs at least 6 response channels")
        if not self.excitations:
            raise ValueError("inputs is empty; give at least one input")
        return self

    # Array views ---------------------------------------------------------------------------
    @property
    def response_positions(self) -> NDArray[np.float64]:
        """(n_responses, 3) GCS positions, metres."""
        return np.array([c.position_m for c in self.responses], dtype=float).reshape(-1, 3)

    @property
    def response_directions(self) -> NDArray[np.float64]:
        """(n_responses, 3) GCS unit directions."""
        return np.array([c.direction_gcs for c in self.responses], dtype=float).reshape(-1, 3)

    @property
    def input_positions(self) -> NDArray[np.float64]:
        return np.array([e.position_m for e in self.excitations], dtype=float).reshape(-1, 3)

    @property
    def input_directions(self) -> NDArray[np.float64]:
        return np.array([e.direction_gcs for e in self.excitations], dtype=float).reshape(-1, 3)

    @property
    def reference_point(self) -> NDArray[np.float64]:
        return np.asarray(self.reference_point_m, dtype=float)
