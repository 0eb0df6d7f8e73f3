"""What the acquisition service keeps and returns: an acquisition's averages and state
(frozen dataclasses), the states it ends in, and the per-input summaries built from them."""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from dimacq.config import Settings
from dimacq.model.setup import TestSetup
from dimacq.services.lab.acquisition_views import LiveReview

if TYPE_CHECKING:
    from dimacq.persistence import ArrayStore, Database
    from dimacq.persistence.queue import Outbox
    from dimacq.services.lab.devices import DeviceService
    from dimacq.services.lab.store import TestStore


#: Builds the acquisition rig (:class:`dimacq.services.acquisition.rig.Rig`) for a setup and a request.
RigFactory = Callable[[Settings, TestSetup, Mapping[str, Any]], Any]

#: Where an acquisition keeps its raw blocks (an HDF5 file, given the acquisition's id); None:
#: not kept (its averages are kept whatever this says).
RawBlocks = Callable[[int], Path | None]


@dataclass(frozen=True)
class AverageInfo:
    """One completed average: accepted or rejected (with the reason), and its array file."""

    number: int
    input_index: int
    accepted: bool
    reason: str
    path: str


@dataclass(frozen=True)
class AcquisitionInfo:
    """State, progress (0..1) and every completed average of an acquisition.

    ``accepted_per_input`` counts the accepted averages of each input index; ``min_averages`` is
    the minimum applied (capped at ``averages_per_input``) and ``incomplete_inputs`` the input
    indices below it once the acquisition is over (finished or failed).
    """

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
    averages: list[AverageInfo]
    min_averages: int
    incomplete_inputs: list[int]
    progress: float
    stand: str = ""  # the test stand that runs it (its raw data are on that stand's disk)
    #: the hit waiting for the operator's decision (review mode): ``number``, ``input_index``,
    #: ``reasons`` (the automatic checks'); None when nothing waits
    pending_review: dict[str, Any] | None = None
    #: mean ordinary coherence (over lines and accelerometer outputs) of each input whose FRFs
    #: are estimated (this run; None: not yet, or one average)
    input_coherence: list[float | None] = field(default_factory=list)
    #: the setup's input indices this acquisition strikes (all of them when the request named none)
    inputs: list[int] = field(default_factory=list)
    created_at: str | None = None  # ISO 8601, UTC
    updated_at: str | None = None  # the last change of state, message, job or FRF set
    #: every hit waits for the operator's decision (switchable while it runs: set_review)
    review: bool = False
    #: per struck input (:func:`input_states`): its name, accepted / rejected averages, the
    #: strikes lost to DAQ gaps with their reasons, and its state
    input_states: list[dict[str, Any]] = field(default_factory=list)


#: The end states whose inputs can be short of their averages: "incomplete" is the end of an
#: acquisition that stored FRFs for some inputs but not all (never "succeeded").
ENDED_WITH_INPUTS = ("succeeded", "incomplete", "failed")


#: One average's record: ``"force"`` (1, n) N and ``"outputs"`` (n_outputs, n).
Record = Mapping[str, NDArray[np.float64]]

#: An acquisition that ended before all its averages were in: its kept averages can be
#: finished (FRFs of its complete inputs) or resumed (a new acquisition strikes the missing).
ENDED_SHORT = ("interrupted", "cancelled", "failed")
#: ... and one finished with inputs short of min_averages can be resumed too.
RESUMABLE = (*ENDED_SHORT, "incomplete")
#: The settings that shape a record and its FRFs: a resumed acquisition keeps its ended one's.
RECORD_SETTINGS = (
    "record_samples",
    "pretrigger_samples",
    "trigger_level_n",
    "averages_per_input",
    "min_averages",
    "force_window_samples",
    "exponential_tau_s",
    "estimator",
)
#: Keys of an acquisition's config the service writes (never taken from a request).
INTERNAL_KEYS = ("applied", "resume_of", "kept_per_input")


@dataclass(frozen=True)
class Resume:
    """What a resumed acquisition continues: the ended one and its accepted averages, per
    struck input (in its ``inputs`` order, oldest first)."""

    acq_id: int
    kept: list[list[Record]]


#: What an impact acquisition holds while it runs (:class:`~dimacq.services.lab.ownership.DeviceOwners`).
ACQUISITION_DEVICES = ("daq", "loadcell")


def accepted_per_input(avgs: Sequence[AverageInfo]) -> list[int]:
    """Accepted averages per input index (0 for inputs struck without success)."""
    n = 1 + max((a.input_index for a in avgs), default=-1)
    out = [0] * n
    for a in avgs:
        if a.accepted:
            out[a.input_index] += 1
    return out


def count(per_input: Sequence[int], j: int) -> int:
    return per_input[j] if 0 <= j < len(per_input) else 0


def lost_note(names: Sequence[str], lost: Sequence[Sequence[str]]) -> str:
    """``"; strikes lost to DAQ sample gaps (asked again): 101+X 2 (DAQ samples lost (FIFO
    overflow))"``, or "" when none was lost."""
    parts = [
        f"{names[k]} {len(why)} ({'; '.join(sorted(set(why)))})"
        for k, why in enumerate(lost)
        if why and k < len(names)
    ]
    return f"; strikes lost to DAQ sample gaps (asked again): {', '.join(parts)}" if parts else ""


def input_states(
    state: str,
    struck: Sequence[int],
    names: Sequence[str] | None,
    avgs: Sequence[AverageInfo],
    need: int,
    live: LiveReview | None,
) -> list[dict[str, Any]]:
    """Per struck input (setup index ``input_index``): ``name`` ("101+X"), ``accepted``,
    ``rejected`` (and ``reasons``, distinct), ``lost`` strikes (DAQ samples lost while waiting for
    the strike; ``lost_reasons``; this service's run only: not stored) and ``state``:
    ``complete`` (at least ``min_averages`` accepted), ``incomplete`` (the acquisition ended
    short of them) or ``open`` (running, or cancelled / interrupted)."""
    ended = state in ENDED_WITH_INPUTS
    out = []
    for k, j in enumerate(struck):
        mine = [a for a in avgs if a.input_index == j]
        acc = sum(1 for a in mine if a.accepted)
        lost = list(live.lost[k]) if live is not None and k < len(live.lost) else []
        out.append(
            {
                "input_index": j,
                "name": names[k] if names is not None and k < len(names) else f"input {j + 1}",
                "accepted": acc,
                "rejected": len(mine) - acc,
                "reasons": sorted({a.reason for a in mine if not a.accepted and a.reason}),
                "lost": len(lost),
                "lost_reasons": sorted(set(lost)),
                "state": "complete" if acc >= need else ("incomplete" if ended else "open"),
            }
        )
    return out


class ServiceParts:
    """What the parts of :class:`~dimacq.services.lab.acquisitions.AcquisitionService`
    (:mod:`~dimacq.services.lab.acquisition_review`, :mod:`~dimacq.services.lab.acquisition_recovery`,
    :mod:`~dimacq.services.lab.acquisition_run`) use of its state and of each other; declared for
    the type checker only (empty at run time)."""

    if TYPE_CHECKING:
        db: Database
        store: TestStore
        arrays: ArrayStore
        settings: Settings
        stand: str
        outbox: Outbox
        devices: DeviceService
        raw_blocks: RawBlocks | None
        _live: dict[int, LiveReview]

        def get(self, acq_id: int) -> AcquisitionInfo | None: ...
        def _set(self, acq_id: int, **values: Any) -> None: ...
        def _stand_url(self, name: str) -> str: ...
        def _start(
            self, config: Mapping[str, Any], resume: Resume | None = None
        ) -> AcquisitionInfo: ...
        def _chain(self, acq_id: int) -> list[int]: ...
        def _require_live(self, acq_id: int) -> LiveReview: ...
        def _supersede(self, acq_id: int, input_index: int) -> None: ...
