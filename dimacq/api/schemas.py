"""Request and response bodies of the REST API (pydantic). Unknown fields are refused (422)."""

from __future__ import annotations

import datetime
import math
from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, field_validator

from dimacq.model.impact import ImpactOverrides
from dimacq.model.setup import KnownProperties, LoadCell, Name, NodeNumber
from dimacq.model.types import Coordinate, Finite, FreeText, OneLine
from dimacq.services.lab.plans import PlanParams
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

Vec3 = tuple[Coordinate, Coordinate, Coordinate]

#: The largest id or node number the API accepts: the range of a SQL ``INTEGER`` on every
#: database backend (PostgreSQL's is 32-bit; SQLite's 64-bit) and of a UFF node number (I10).
#: Larger values never reach the database (they used to overflow it: a 500 and a reset connection).
MAX_ID = 2**31 - 1

#: A stored item's id in a request body (1..MAX_ID; out of range → 422 naming the field). Path
#: ids use :data:`dimacq.api.deps.IdPath` (out of range → 404).
DbId = Annotated[int, Field(ge=1, le=MAX_ID)]
#: A patch index in a request body (0..MAX_ID); node numbers are :data:`NodeNumber`.
Number = Annotated[int, Field(ge=0, le=MAX_ID)]
FiniteVec3 = tuple[Coordinate, Coordinate, Coordinate]


class _Body(BaseModel):
    model_config = ConfigDict(extra="forbid")


class ErrorBody(BaseModel):
    """Every error: a message naming the item and the fix, and the field when there is one."""

    detail: str
    field: str | None = None
    errors: list[dict[str, Any]] = Field(default_factory=list)


Coord = Annotated[Finite, Field(ge=-100.0, le=100.0)]


#: A point or node label: one line of printable text (:data:`dimacq.model.types.OneLine`: no
#: NUL, which PostgreSQL cannot store, no line breaks or Unicode line separators), 1..200
#: characters.
LABEL_PATTERN = r"^[^\x00-\x1f\x7f-\x9f\u2028\u2029]+$"
Label = Annotated[
    OneLine,
    Field(
        min_length=1,
        max_length=200,
        description="one line of printable text",
        json_schema_extra={"pattern": LABEL_PATTERN},
    ),
]

#: The shortest simulated probe axis accepted, m (any unit direction is normalised from it).
MIN_AXIS_LENGTH = 1e-6


class PhotoGeometryStored(BaseModel):
    """What ``POST /api/digitizer/photo-geometry`` stored."""

    orientations: int = Field(description="triax orientation records stored")
    lines_of_action: int = Field(description="line-of-action records stored")
    verdict: str | None = Field(default=None, description="the photographed geometry's verdict")


class SimProbe(_Body):
    """Simulation only: where the simulated probe tip is (array coordinates, within ±100 m) and
    its axis."""

    tip_m: tuple[Coord, Coord, Coord]
    axis: tuple[Coord, Coord, Coord] = (0.0, 0.0, 1.0)

    @field_validator("axis")
    @classmethod
    def _axis_non_zero(cls, v: tuple[float, float, float]) -> tuple[float, float, float]:
        if not math.hypot(*v) >= MIN_AXIS_LENGTH:
            raise ValueError(
                f"has length {math.hypot(*v):.3g}; give a direction of the probe at least "
                f"{MIN_AXIS_LENGTH:g} long"
            )
        return v


class PointRequest(_Body):
    label: Label
    shots: int | None = Field(default=None, ge=1, le=100)
    sim_probe: SimProbe | None = None


class ShotsRequest(_Body):
    n: int = Field(default=1, ge=1, le=100)
    sim_probe: SimProbe | None = None


class PatchRequest(_Body):
    name: Name | None = None


class ReferenceNodesRequest(_Body):
    nodes: dict[Label, FiniteVec3] = Field(description="label → known GCS position, metres")


class ReferenceNodeRequest(_Body):
    position_m: FiniteVec3 = Field(description="known GCS position of the node, metres")


class NewTestRequest(_Body):
    name: Name | None = None


class RegistrationRequest(_Body):
    patch: Number | None = None
    method: Literal["rigid", "similarity", "affine"] = "rigid"
    labels: list[Label] | None = None
    limit_m: float | None = Field(
        default=None,
        gt=0,
        le=1.0,
        description="largest accepted residual of one node, m (default: the "
        "registration_limit_m setting); above it the registration is refused",
    )


class OrientationRequest(_Body):
    node: NodeNumber
    prefix: Annotated[OneLine, Field(max_length=100)] | None = None
    method: Literal["rigid", "affine", "cross"] = "rigid"


class LineOfActionRequest(_Body):
    node: NodeNumber
    input_label: Label
    labels: list[Label] = Field(min_length=2)
    method: Literal["svd", "eq13"] = "svd"


class FromGeometryRequest(_Body):
    name: Name = ""
    reference_point_m: Vec3 = (0.0, 0.0, 0.0)
    length_unit: Literal["m", "cm", "mm"] = "m"
    triaxes: list[NodeNumber] | None = None
    inputs: list[NodeNumber] | None = None
    load_cells: list[LoadCell] = Field(default_factory=list)
    known: KnownProperties = KnownProperties()
    test_id: DbId | None = Field(default=None, description="the test the setup belongs to")


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
        description="accept (kept if the checks passed; a hit the checks rejected answers 409 "
        "naming them unless override is true), reject (strike again), redo (drop this input's "
        "averages and strike it again)"
    )
    override: bool = Field(
        default=False,
        description="with accept: keep the hit although the checks rejected it (double hit, "
        "overload, clock drift; pending_review.accept is 'override'); a hit with samples lost "
        "cannot be accepted (pending_review.accept 'no')",
    )


class AcquisitionPatch(BaseModel):
    """What the operator may change while an acquisition runs."""

    model_config = ConfigDict(extra="forbid")

    review: bool = Field(
        description="review every hit: true, the next hit waits for the operator's decision; "
        "false, the checks decide from now on (the hit waiting too)"
    )


class SensitivityRequest(CubeStudyParams):
    """A sensitivity study on the thesis's cube model (:class:`CubeStudyParams`)."""


class PlanRequest(PlanParams):
    """A pre-test plan (``dimacq plan``, :class:`PlanParams`)."""


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
    updated_at: str | None = Field(
        default=None,
        description="last change of state, progress or message (null: a job of another stand "
        "still running, whose progress times are not stored)",
    )
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
    lost: str = Field(
        default="",
        description="why the code using the device (an acquisition, the digitizing session) "
        "last saw it lost, e.g. the DAQ dropped off the bus; empty while it works",
    )


class StatusOut(BaseModel):
    service: str
    version: str
    schema_version: int
    stand: str = ""
    database: dict[str, Any] = {}
    uptime_s: float
    devices: dict[str, dict[str, Any]]
    jobs_running: list[dict[str, Any]]


_CREATED = "when it was stored (ISO 8601, UTC); stored items are never changed, so no updated_at"


class PointOut(BaseModel):
    """A digitized point: array coordinates (DACS) and, once its patch is registered, GCS, m."""

    label: str
    patch: int
    position_array_m: list[float]
    spread_m: list[float]
    n_shots: int
    n_used: int
    id: int | None = None
    position_m: list[float] | None = None
    seqs: list[int] | None = None
    created_at: str | None = Field(default=None, description=_CREATED)


class SetupOut(BaseModel):
    """A stored setup: counts and the setup document (the setup-file keys)."""

    id: int
    name: str
    n_responses: int
    n_inputs: int
    n_load_cells: int
    setup: dict[str, Any]
    stand: str = Field(default="", description="the test stand that stored it")
    created_at: str | None = Field(default=None, description=_CREATED)
    test_id: int | None = Field(default=None, description="the test it belongs to")


class ImportOut(SetupOut):
    """The imported setup; ``frf_id`` is the FRF set a whole-test UFF also held."""

    frf_id: int | None = None


class FrfOut(BaseModel):
    """A stored FRF set (its values: ``GET /api/frfs/{frf_id}/data``)."""

    id: int
    setup_id: int
    acquisition_id: int | None = None
    name: str
    n_lines: int
    n_responses: int
    n_inputs: int
    f_min_hz: float
    f_max_hz: float
    stand: str = Field(default="", description="the test stand that stored it")
    created_at: str | None = Field(default=None, description=_CREATED)


class FrfChannelOut(BaseModel):
    """A response channel or an input: node and UFF direction (±1..±3 translations, ±4..±6
    rotations; a load cell's 1..6 are Fx..Mz in the cell's axes); for a response its kind and
    the unit of its FRF."""

    node: int
    direction: int
    kind: Literal["acceleration", "reaction", "input"] = "input"
    unit: str = Field(default="N", description="unit of the FRF's numerator / of the input")


class FrfDataOut(BaseModel):
    """FRF values of the chosen responses × inputs over the chosen band."""

    frf_id: int
    layout: str = Field(
        description="index order of real, imag and coherence: [line][response][input]"
    )
    frequencies_hz: list[float]
    responses: list[FrfChannelOut]
    inputs: list[FrfChannelOut]
    real: list[Any] = Field(description="Re H, shape (n_lines, n_responses, n_inputs)")
    imag: list[Any] = Field(description="Im H, same shape")
    coherence: list[Any] | None = Field(
        description="multiple coherence of each response, same shape; null entries where it is "
        "undefined (no more averages than inputs), null when the set has none"
    )


class FrfEnvelopeOut(BaseModel):
    """The |H| envelope of the chosen responses × inputs: the lines in the band split into at most
    ``points`` groups of consecutive lines, each group's largest and smallest |H| (what a plot of
    every line shows, resonances and antiresonances kept), and the mean coherence of each pair
    over those lines (what a data-quality table shows)."""

    frf_id: int
    layout: str = Field(description="index order of magnitude_max / _min: [point][response][input]")
    n_lines: int = Field(description="lines in the band")
    lines_per_point: int = Field(description="lines in the largest group")
    frequencies_hz: list[float] = Field(description="centre of each group's range, Hz")
    f_lo_hz: list[float] = Field(description="each group's first line, Hz")
    f_hi_hz: list[float] = Field(description="each group's last line, Hz")
    responses: list[FrfChannelOut]
    inputs: list[FrfChannelOut]
    magnitude_max: list[Any] = Field(
        description="largest |H| of each group, shape (n_points, n_responses, n_inputs), in each "
        "response's unit"
    )
    magnitude_min: list[Any] = Field(description="smallest |H| of each group, same shape")
    coherence_mean: list[Any] | None = Field(
        description="mean multiple coherence over the band's lines, shape (n_responses, "
        "n_inputs); null entries where undefined, null when the set has none"
    )


class SolutionOut(BaseModel):
    """A DIM solution: the options it was solved with and the result (the keys of
    ``dimacq solve --json``: ``mass_kg``, ``cg_m``, ``inertia_p_kgm2``, ``uncertainty.<p>.ci95``,
    ``verdict``, ``verdict_reasons``, …)."""

    id: int
    frf_id: int
    options: dict[str, Any]
    result: dict[str, Any]
    stand: str = Field(default="", description="the test stand that solved it")
    created_at: str | None = Field(default=None, description=_CREATED)


class AverageOut(BaseModel):
    number: int
    input_index: int
    accepted: bool
    reason: str
    path: str


class AcquisitionInputOut(BaseModel):
    """One struck input of an acquisition."""

    input_index: int = Field(description="the setup's input index")
    name: str = Field(description="point and direction, e.g. 101+X")
    accepted: int
    rejected: int
    reasons: list[str] = Field(default_factory=list, description="why averages were rejected")
    lost: int = Field(
        default=0,
        description="strikes lost while waiting for them (DAQ samples lost: FIFO overflow, "
        "transfer lost); asked again, not counted against the strike budget (this service's "
        "run only)",
    )
    lost_reasons: list[str] = Field(default_factory=list)
    state: Literal["open", "complete", "incomplete"] = Field(
        description="complete: min_averages accepted; incomplete: the acquisition ended short "
        "of them (no FRF); open: not yet"
    )


class AcquisitionOut(BaseModel):
    """An impact acquisition: state (running; succeeded: every input has its FRFs; incomplete:
    FRFs stored for some inputs, the others named in the message and ``incomplete_inputs`` (also
    after ``finish`` of an interrupted one); failed; cancelled; interrupted; resumed: ``resume``
    started the acquisition that strikes the rest), progress 0..1, and every completed average,
    accepted or rejected with its reason (a resumed one's ``accepted_per_input`` counts the kept
    ones)."""

    id: int
    setup_id: int | None
    config: dict[str, Any]
    state: str
    message: str
    job_id: str | None
    frf_id: int | None
    averages_accepted: int
    accepted_per_input: list[int]
    averages_rejected: int
    averages: list[AverageOut]
    min_averages: int
    incomplete_inputs: list[int]
    progress: float
    stand: str = ""
    pending_review: dict[str, Any] | None = Field(
        default=None,
        description="review mode: the hit waiting for the operator's decision (number, "
        "input_index, reasons); null when nothing waits",
    )
    input_coherence: list[float | None] = Field(
        default_factory=list,
        description="mean ordinary coherence of each input whose FRFs are estimated (this run)",
    )
    inputs: list[int] = Field(
        default_factory=list, description="the setup's input indices this acquisition strikes"
    )
    created_at: str | None = None
    updated_at: str | None = Field(
        default=None, description="the last change of state, message, job or FRF set"
    )
    review: bool = Field(
        default=False,
        description="every hit waits for the operator's decision (PATCH to switch it mid-run)",
    )
    input_states: list[AcquisitionInputOut] = Field(
        default_factory=list,
        description="per struck input: its name (point and direction), averages accepted and "
        "rejected, strikes lost to DAQ sample gaps with their reasons, and its state",
    )


class CalibrationOut(BaseModel):
    """A stored load cell calibration (the normalised document, SI)."""

    id: int
    serial_number: str
    calibration: dict[str, Any]
    created_at: str | None = Field(default=None, description=_CREATED)


class StudyOut(BaseModel):
    """A sensitivity study: its parameters and, once its job has succeeded, its result;
    ``job_id`` in the answer of the call that created it (follow it at /api/jobs/{job_id})."""

    id: int
    params: dict[str, Any]
    result: dict[str, Any] | None
    job_id: str | None = None
    created_at: str | None = Field(default=None, description=_CREATED)


class DiagnosticOut(BaseModel):
    """One plausibility or quality check of a solution, reported whatever its outcome."""

    code: str
    ok: bool
    severity: Literal["info", "warning", "error"]
    message: str


class DeletedOut(BaseModel):
    """How many items a bulk delete removed."""

    deleted: int


class StandOut(BaseModel):
    """A test stand sharing the database: its service's host, process, API address, start and
    last heartbeat (ISO 8601, UTC)."""

    name: str
    host: str
    pid: int
    api_url: str
    started_at: str
    heartbeat_at: str


Text200 = Name  # one line, at most 200 characters


class TestCreate(_Body):
    """A new test: the article's name, the operator, the test's date (default today) and notes."""

    __test__ = False  # not a pytest class

    article: Annotated[Name, Field(min_length=1)]
    operator: Text200 = ""
    date: datetime.date | None = None
    notes: Annotated[FreeText, Field(max_length=20_000)] = ""


class TestUpdate(_Body):
    """The fields to change (those left out or null stay); ``archived: true`` archives the
    test, ``false`` reopens it."""

    __test__ = False

    article: Annotated[Name, Field(min_length=1)] | None = None
    operator: Text200 | None = None
    date: datetime.date | None = None
    notes: Annotated[FreeText, Field(max_length=20_000)] | None = None
    archived: bool | None = None


class TestOut(BaseModel):
    """A test and its setups (their acquisitions, FRF sets and solutions are the test's)."""

    __test__ = False

    id: int
    article: str
    operator: str
    date: str = Field(description="the day of the test, YYYY-MM-DD")
    notes: str
    archived: bool
    setup_ids: list[int]
    stand: str = ""
    created_at: str | None = None
    updated_at: str | None = Field(default=None, description="the last change of its fields")


class JigOut(BaseModel):
    """The orientation jig: indentation labels and positions in the sensor's axes, m."""

    labels: list[str]
    points_local_m: list[list[float]]


class ArticleOut(BaseModel):
    """Simulation only: the article's geometry as a setup file states it (GCS, m: responses,
    inputs with their lines of action, load cells), the scenario's recommended band and the
    orientation jig. The true inertia properties are not given."""

    scenario: str
    setup: dict[str, Any] = Field(description="setup-file keys (responses, inputs, load_cells)")
    band_hz: list[float]
    jig: JigOut


class SpeedOfSoundOut(BaseModel):
    speed_of_sound_m_s: float = Field(description="measured on the calibration bar, m/s")


class AverageDataOut(BaseModel):
    """Raw time data of one average (the stand's HDF5 file): ``arrays`` by name (``shapes``
    gives each one's shape; the channel order and units are in ``attrs``), NaN as null."""

    acquisition_id: int
    number: int
    stand: str
    path: str = Field(description="the file, relative to the stand's data folder")
    attrs: dict[str, Any]
    arrays: dict[str, Any]
    shapes: dict[str, list[int]]


class HitOut(BaseModel):
    """One hit as the operator sees it: the force and the strongest response over time and their
    spectra (dB re their peak), the automatic checks' reasons; ``pending`` when it waits for a
    decision (``POST /api/acquisitions/{id}/review``)."""

    model_config = ConfigDict(extra="allow")

    number: int = Field(description="the hit (average number, from 1)")
    pending: bool
    input_index: int | None = Field(default=None, description="the setup's input struck")
    reasons: list[str] = Field(default_factory=list, description="the checks' (empty: passed)")
    accepted: bool | None = None
    sample_rate_hz: float
    time_s: list[float | None]
    force_n: list[float | None] = Field(description="hammer force, N")
    response: int = Field(description="index of the strongest response channel shown")
    response_ms2: list[float | None] = Field(description="its acceleration, m/s²")
    frequencies_hz: list[float | None]
    force_db: list[float | None] = Field(description="force spectrum, dB re its peak")
    response_db: list[float | None] = Field(description="response spectrum, dB re its peak")
    peak_force_n: float


class RigOut(BaseModel):
    """The configured rig file: its ``path`` and ``text``, the parsed map ``rig`` (``daq``,
    ``hammers`` with any ``chain_calibration``, ``responses`` with ``sensitivity_mv_per_g``,
    ``load_cells``; null when invalid) and ``error`` ("" when valid)."""

    path: str = ""
    text: str = ""
    rig: dict[str, Any] | None
    error: str


class SolutionSpectrumOut(BaseModel):
    """Parameters against frequency behind a stored solution: ``per_line`` (n_lines × 10, layout
    ``parameters``, units ``units``; inertia about the reference point, CG in the GCS) over every
    line of its FRF set; ``band_hz`` and ``headline`` (the stored estimate, same layout)."""

    solution_id: int
    parameters: list[str]
    units: list[str]
    frequencies_hz: list[float | None]
    per_line: list[list[float | None]]
    band_hz: list[float]
    headline: list[float | None]
