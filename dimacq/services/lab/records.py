"""What the test store returns: pages, summaries of setups and FRF sets, FRF values, stored
solutions (frozen dataclasses, built from database rows by their ``of``)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Generic, TypeVar

from dimacq.errors import SetupError
from dimacq.model.frf import Channel
from dimacq.persistence import models as m
from dimacq.services.lab.common import iso

T = TypeVar("T")


@dataclass(frozen=True)
class Page(Generic[T]):
    """One page of a collection: ``items`` and the ``total`` count of the collection."""

    items: list[T]
    total: int


@dataclass(frozen=True)
class SetupSummary:
    """A stored setup: counts and the setup document (setup-file keys)."""

    id: int
    name: str
    n_responses: int
    n_inputs: int
    n_load_cells: int
    setup: dict[str, Any]
    stand: str = ""  # the test stand that stored it
    created_at: str | None = None  # ISO 8601, UTC (a setup is never changed: no updated_at)
    test_id: int | None = None  # the test it belongs to

    @classmethod
    def of(cls, r: m.SetupRow) -> SetupSummary:
        return cls(
            id=r.id,
            name=r.name,
            n_responses=len(r.body.get("responses", [])),
            # rows stored before the one vocabulary call the inputs "excitations"
            n_inputs=len(r.body.get("inputs", r.body.get("excitations", []))),
            n_load_cells=len(r.body.get("load_cells", [])),
            setup=r.body,
            stand=r.stand,
            created_at=iso(r.created_at),
            test_id=r.test_id,
        )


@dataclass(frozen=True)
class Imported:
    """What an import stored: the setup, and the FRF set of a whole-test UFF."""

    setup_id: int
    frf_id: int | None = None


@dataclass(frozen=True)
class ExportedFile:
    content: bytes
    media_type: str


@dataclass(frozen=True)
class FrfSummary:
    """A stored FRF set (the arrays stay in their file)."""

    id: int
    setup_id: int
    acquisition_id: int | None
    name: str
    n_lines: int
    n_responses: int
    n_inputs: int
    f_min_hz: float
    f_max_hz: float
    stand: str = ""  # the test stand that stored it
    created_at: str | None = None  # ISO 8601, UTC (an FRF set is never changed)

    @classmethod
    def of(cls, r: m.FrfSet) -> FrfSummary:
        return cls(
            id=r.id,
            setup_id=r.setup_id,
            acquisition_id=r.acquisition_id,
            name=r.name,
            n_lines=r.n_lines,
            n_responses=r.n_outputs,
            n_inputs=r.n_inputs,
            f_min_hz=r.f_min_hz,
            f_max_hz=r.f_max_hz,
            stand=r.stand,
            created_at=iso(r.created_at),
        )


@dataclass(frozen=True)
class FrfValues:
    """FRF values of some responses × inputs over a band: ``real``/``imag``/``coherence`` have
    the shape (n_lines, n_responses, n_inputs) (``layout``). Each response names its ``kind``
    and the ``unit`` of its FRF; each input its unit (N)."""

    frf_id: int
    layout: str
    frequencies_hz: list[float]
    responses: list[dict[str, Any]]
    inputs: list[dict[str, Any]]
    real: list[Any]
    imag: list[Any]
    coherence: list[Any] | None


#: Unit of an FRF's numerator per response kind (inputs are forces, N); a load cell's
#: directions 4..6 are moments.
FRF_UNIT = {"acceleration": "(m/s²)/N", "reaction": "N/N"}


@dataclass(frozen=True)
class ChannelQuery:
    """Which channels of an FRF set: an ``index`` (0-based, in the set's order), or a ``node``
    with an optional UFF ``direction``; all when nothing is given."""

    index: int | None = None
    node: int | None = None
    direction: int | None = None
    #: several indices at once (``GET /api/frfs/{id}/envelope?input=0&input=1``), in this order
    indices: tuple[int, ...] = ()

    def pick(self, channels: Sequence[Channel], what: str) -> list[int]:
        n = len(channels)
        for i in self.indices:
            if not 0 <= i < n:
                raise SetupError(f"{what} index {i} is outside 0..{n - 1}")
        if self.indices:
            return list(self.indices)
        if self.index is not None:
            if not 0 <= self.index < n:
                raise SetupError(f"{what} index {self.index} is outside 0..{n - 1}")
            return [self.index]
        if self.node is None:
            if self.direction is not None:
                raise SetupError(f"{what}_direction needs {what}_node: give the node too")
            return list(range(n))
        got = [
            i
            for i, c in enumerate(channels)
            if c.node == self.node and (self.direction is None or c.direction == self.direction)
        ]
        if not got:
            have = sorted({f"{c.node}:{c.direction:+d}" for c in channels})
            raise SetupError(
                f"{what} node {self.node}"
                + ("" if self.direction is None else f" direction {self.direction:+d}")
                + f" is not in this FRF set; it has {', '.join(have[:40])}"
                + (" …" if len(have) > 40 else "")
            )
        return got


@dataclass(frozen=True)
class StoredSolution:
    """A DIM solution: the options it was solved with and the result document (the keys of
    ``dimacq solve --json``)."""

    id: int
    frf_id: int
    options: dict[str, Any]
    result: dict[str, Any]
    created_at: str | None = None  # ISO 8601, UTC (a solution is never changed)
    stand: str = ""  # the test stand that solved it

    @classmethod
    def of(cls, r: m.Solution) -> StoredSolution:
        return cls(
            id=r.id,
            frf_id=r.frf_id,
            options=r.options,
            result=r.result,
            created_at=iso(r.created_at),
            stand=r.stand,
        )
