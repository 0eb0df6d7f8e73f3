"""Request and response bodies of the REST API (pydantic). Unknown fields are refused (422)."""

from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, FiniteFloat, field_validator

from dimacq.model.impact import ImpactOverrides
from dimacq.model.setup import KnownProperties, LoadCell, NodeNumber
from dimacq.services.lab.solving import SolveOptions
from dimacq.services.lab.studies import CubeStudyParams

__all__ = [
    "MAX_ID",
    "AcquisitionRequest",
    "DbId",
    "ErrorBody",
    "FromGeometryRequest",
    "HitDecision",
    "JobInfo",
    "LineOfActionRequest",
    "Number",
    "OrientationRequest",
    "PointRequest",
    "RegistrationRequest",
    "RigText",
    "SolveRequest",
]

Vec3 = tuple[float, float, float]

#: The largest id or node number the API accepts: the range of a SQL ``INTEGER`` on every
#: database backend (PostgreSQL's is 32-bit; SQLite's 64-bit) and of a UFF node number (I10).
#: Larger values never reach the database (they used to overflow it: a 500 and a reset connection).
MAX_ID = 2**31 - 1

#: A stored item's id in a request body (1..MAX_ID; out of range → 422 naming the field). Path
#: ids use :data:`dimacq.api.deps.IdPath` (out of range → 404).
DbId = Annotated[int, Field(ge=1, le=MAX_ID)]
#: A patch index in a request body (0..MAX_ID); node numbers are :data:`NodeNumber`.
Number = Annotated[int, Field(ge=0, le=MAX_ID)]
FiniteVec3 = tuple[FiniteFloat, FiniteFloat, FiniteFloat]


class _Body(BaseModel):
    model_config = ConfigDict(extra="forbid")


class ErrorBody(BaseModel):
    """Every error: a message naming the item and the fix, and the field when there is one."""

    detail: str
    field: str | None = None
    errors: list[dict[str, Any]] = Field(default_factory=list)


Coord = Annotated[float, Field(ge=-100.0, le=100.0)]


class SimProbe(_Body):
    """Simulation only: where the simulated probe tip is (array coordinates, within ±100 m) and
    its axis."""

    tip_m: tuple[Coord, Coord, Coord]
    axis: tuple[Coord, Coord, Coord] = (0.0, 0.0, 1.0)

    @field_validator("axis")
    @classmethod
    def _axis_non_zero(cls, v: tuple[float, float, float]) -> tuple[float, float, float]:
        if not any(v):
            raise ValueError("give a non-zero direction of the probe")
        return v


class PointRequest(_Body):
    label: str = Field(min_length=1, max_length=200)
    shots: int | None = Field(default=None, ge=1, le=100)
    sim_probe: SimProbe | None = None


class ShotsRequest(_Body):
    n: int = Field(default=1, ge=1, le=100)
    sim_probe: SimProbe | None = None


class PatchRequest(_Body):
    name: str | None = Field(default=None, max_length=200)


class ReferenceNodesRequest(_Body):
    nodes: dict[str, FiniteVec3] = Field(description="label → known GCS position, metres")


class ReferenceNodeRequest(_Body):
    position_m: FiniteVec3 = Field(description="known GCS position of the node, metres")


class NewTestRequest(_Body):
    name: str | None = Field(default=None, max_length=200)


class RegistrationRequest(_Body):
    patch: Number | None = None
    method: Literal["rigid", "similarity", "affine"] = "rigid"
    labels: list[str] | None = None
    limit_m: float | None = Field(
        default=None,
        gt=0,
        le=1.0,
        description="largest accepted residual of one node, m (default: the "
        "registration_limit_m setting); above it the registration is refused",
    )


class OrientationRequest(_Body):
    node: NodeNumber
    prefix: str | None = Field(default=None, max_length=100)
    method: Literal["rigid", "affine", "cross"] = "rigid"


class LineOfActionRequest(_Body):
    node: NodeNumber
    input_label: str = Field(min_length=1, max_length=200)
    labels: list[str] = Field(min_length=2)
    method: Literal["svd", "eq13"] = "svd"


class FromGeometryRequest(_Body):
    name: str = ""
    reference_point_m: Vec3 = (0.0, 0.0, 0.0)
    length_unit: Literal["m", "cm", "mm"] = "m"
    triaxes: list[NodeNumber] | None = None
    inputs: list[NodeNumber] | None = None
    load_cells: list[LoadCell] = Field(default_factory=list)
    known: KnownProperties = KnownProperties()


class SolveRequest(SolveOptions):
    """Solve the FRF set ``frf_id`` with the options (:class:`SolveOptions`)."""

    frf_id: DbId


class AcquisitionRequest(ImpactOverrides):
    """An impact test of every input of the setup. The impact settings are
    :class:`dimacq.model.impact.ImpactOverrides`; values left out (null) come from the rig file's
    ``[acquisition]`` table, then the built-in defaults."""

    setup_id: DbId
    seed: int | None = Field(default=None, ge=0, le=2**31 - 1)
    review: bool = Field(
        default=False,
        description="the operator accepts, rejects or redoes (the whole input) every hit "
        "(POST /api/acquisitions/{id}/review); false: the automatic checks decide",
    )
    inputs: list[Annotated[int, Field(ge=0, le=10_000)]] | None = Field(
        default=None,
        max_length=10_000,
        description="indices of the setup's inputs to strike (redo one input, append inputs); "
        "null: all of them",
    )
    merge_frf_id: DbId | None = Field(
        default=None,
        description="an FRF set of the same setup: the new FRF set is this one with the struck "
        "inputs replaced (redo) or added (append)",
    )


class RigText(BaseModel):
    """A rig file (``rig.toml``) as text."""

    model_config = ConfigDict(extra="forbid")

    text: str = Field(max_length=1_000_000, description="the whole rig.toml")


class HitDecision(BaseModel):
    """The operator's decision on the hit waiting for review."""

    model_config = ConfigDict(extra="forbid")

    number: DbId = Field(description="the hit (pending_review.number of the acquisition)")
    decision: Literal["accept", "reject", "redo"] = Field(
        description="accept (kept if the checks passed), reject (strike again), redo (drop "
        "this input's averages and strike it again)"
    )


class SensitivityRequest(CubeStudyParams):
    """A sensitivity study on the thesis's cube model (:class:`CubeStudyParams`)."""


class JobInfo(BaseModel):
    id: str
    kind: str
    state: Literal["pending", "running", "succeeded", "failed", "cancelled", "interrupted"]
    progress: float
    message: str
    result: dict[str, Any] | None = None
    error: str | None = None
    created_at: str
    finished_at: str | None = None
    version: int = 0
    stand: str = ""


class DeviceOut(BaseModel):
    name: str
    kind: str
    address: str
    simulated: bool
    connected: bool
    identity: dict[str, Any]
    error: str


class StatusOut(BaseModel):
    service: str
    version: str
    schema_version: int
    stand: str = ""
    database: dict[str, Any] = {}
    uptime_s: float
    devices: dict[str, dict[str, Any]]
    jobs_running: list[dict[str, Any]]


class PointOut(BaseModel):
    label: str
    patch: int
    position_array_m: list[float]
    spread_m: list[float]
    n_shots: int
    n_used: int
    id: int | None = None
    position_m: list[float] | None = None
    seqs: list[int] | None = None


class SetupOut(BaseModel):
    id: int
    name: str
    n_responses: int
    n_excitations: int
    n_load_cells: int
    setup: dict[str, Any]
    stand: str = ""  # the test stand that stored it


class ImportOut(BaseModel):
    setup_id: int
    frf_id: int | None = None


class FrfOut(BaseModel):
    id: int
    setup_id: int
    acquisition_id: int | None = None
    name: str
    n_lines: int
    n_outputs: int
    n_inputs: int
    f_min_hz: float
    f_max_hz: float
    stand: str = ""  # the test stand that stored it


class SolutionOut(BaseModel):
    id: int
    frf_id: int
    options: dict[str, Any]
    result: dict[str, Any]
