"""Finishing and resuming an acquisition that ended short (a crash, a stop, a failure): the
FRFs of its complete inputs from the averages kept on disk, and a new acquisition that strikes
only what is missing (:class:`AcquisitionRecovery`, a part of
:class:`~dimacq.services.lab.acquisitions.AcquisitionService`; the API and ``dimacq acquire
--resume`` both resume through it).

The resume rule (:func:`kept_averages`): every struck input starts with its accepted averages,
oldest first, and only the ones it is short of ``averages_per_input`` are struck (the session's
``prior``: :class:`~dimacq.services.acquisition.session.ImpactSession`). Rejected averages and
averages of inputs not struck now are left out.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Generic, TypeVar

import numpy as np
from sqlalchemy import select

from dimacq.errors import (
    DataError,
    DeviceStateError,
)
from dimacq.model.channels import input_name
from dimacq.model.impact import ImpactSettings
from dimacq.persistence import models as m
from dimacq.services.lab.acquisition_records import (
    ENDED_SHORT,
    INTERNAL_KEYS,
    RECORD_SETTINGS,
    RESUMABLE,
    AcquisitionInfo,
    Record,
    Resume,
    ServiceParts,
)
from dimacq.services.lab.acquisition_views import merge_frfs

log = logging.getLogger("dimacq.services.lab.acquisitions")

T = TypeVar("T")
R = TypeVar("R")


@dataclass(frozen=True)
class KeptAverages(Generic[R]):
    """The accepted averages kept, per struck input (in the order of ``inputs``, oldest first)."""

    per_input: list[list[R]]

    def missing(self, averages_per_input: int) -> list[int]:
        """Averages still to strike per input: ``max(0, N - kept_k)`` with N ``averages_per_input``."""
        return [max(0, averages_per_input - len(r)) for r in self.per_input]

    def nothing_to_strike(self, averages_per_input: int) -> bool:
        """True when every input has its ``averages_per_input`` accepted averages."""
        return not any(self.missing(averages_per_input))


def kept_averages(
    averages: Iterable[tuple[int, bool, T]], inputs: Sequence[int], load: Callable[[T], R]
) -> KeptAverages[R]:
    """Group the accepted averages of an ended acquisition by struck input.

    Parameters
    ----------
    averages : iterable of (input index, accepted, item)
        Every average decided, oldest first; ``input index`` as in the setup's excitations.
    inputs : sequence of int
        The setup's input indices struck, in their striking order.
    load : callable (item) -> record
        Reads an average kept; called only for the accepted averages of ``inputs``, in order
        (its errors name the average that cannot be read).

    Returns
    -------
    KeptAverages
        ``per_input[k]``: the records of input ``inputs[k]``, oldest first.
    """
    where = {j: k for k, j in enumerate(inputs)}
    kept: list[list[R]] = [[] for _ in inputs]
    for j, accepted, item in averages:
        if accepted and j in where:
            kept[where[j]].append(load(item))
    return KeptAverages(kept)


class AcquisitionRecovery(ServiceParts):
    """Methods of :class:`~dimacq.services.lab.acquisitions.AcquisitionService` (its state: see
    there)."""

    def finish(self, acq_id: int) -> AcquisitionInfo | None:
        """Stop striking and keep the accepted averages: FRFs of the inputs that reached
        ``min_averages`` are estimated and stored (the others are incomplete).

        A running acquisition stops striking (its job stores the FRFs). One that ended short
        (``interrupted`` by a crash of the service, ``cancelled``, ``failed``) and has no FRF
        set gets its FRFs here, from the raw averages kept on disk, estimated exactly as the
        live run does (:func:`~dimacq.services.acquisition.session.input_frf`): state ``succeeded``
        when every input is complete, else ``incomplete`` with the missing inputs named in
        the message (:meth:`resume` strikes them).

        Raises
        ------
        DeviceStateError
            Not running and not ended short, already with an FRF set, run by another stand,
            or no input has ``min_averages`` accepted averages.
        DataError
            A kept average's file is missing or unreadable.
        """
        cur = self.get(acq_id)
        if cur is None:
            return None
        if cur.state not in ENDED_SHORT or cur.frf_id is not None:
            try:
                live = self._require_live(acq_id)
            except KeyError:
                return None
            except DeviceStateError as err:
                raise DeviceStateError(
                    f"acquisition {acq_id} is {cur.state}"
                    + (f" with FRF set {cur.frf_id}" if cur.frf_id is not None else "")
                    + ": finish stops a running acquisition of this stand, or estimates the FRFs "
                    "of one interrupted, cancelled or failed without them from its kept averages"
                ) from err
            live.finish.set()
            return self.get(acq_id)
        self._require_own(cur, "finish")
        return self._finish_kept(cur)

    def _require_own(self, cur: AcquisitionInfo, what: str) -> None:
        if cur.stand not in (self.stand, ""):
            raise DeviceStateError(
                f"acquisition {cur.id} ran on stand {cur.stand!r}: its raw averages are on that "
                f"stand's disk; {what} it through its API ({self._stand_url(cur.stand)})"
            )

    def _finish_kept(self, cur: AcquisitionInfo) -> AcquisitionInfo | None:
        from dimacq.services.acquisition.session import records_frf

        acq_id, cfg = cur.id, cur.config
        assert cur.setup_id is not None
        setup = self.store.require_setup(cur.setup_id)
        inputs = [int(j) for j in cfg["inputs"]]
        struck = setup.model_copy(
            update={"excitations": tuple(setup.excitations[j] for j in inputs)}
        )
        held, fs = self._kept(acq_id, inputs)
        kept = held.per_input
        applied = self._applied(cfg)
        need = min(applied.min_averages, applied.averages_per_input)
        short = [
            f"{input_name(e)} ({len(r)} of {applied.averages_per_input})"
            for e, r in zip(struck.excitations, kept, strict=True)
            if len(r) < need
        ]
        if len(short) == len(inputs):
            raise DeviceStateError(
                f"acquisition {acq_id}: no input has {need} accepted averages (inputs "
                f"{', '.join(short)}): no FRF to estimate; resume it "
                f"(POST /api/acquisitions/{acq_id}/resume) to strike them"
            )
        frf = records_frf(kept, fs, applied, struck, meta={"source": "dimacq impact acquisition"})
        merge_id = cfg.get("merge_frf_id")
        if merge_id is not None:
            base = self.store.frf(int(merge_id))
            if base is None:
                raise DataError(
                    f"FRF set {merge_id} (merge_frf_id of acquisition {acq_id}) was deleted; "
                    "nothing to merge into"
                )
            frf = merge_frfs(base[0], frf, setup)
        fid = self.store.save_frf(
            frf, cur.setup_id, name=f"acquisition {acq_id}", acquisition_id=acq_id
        )
        message = (
            f"finished from the averages kept after it was {cur.state}: FRFs stored as FRF set "
            f"{fid}"
        )
        if short:
            state = "incomplete"
            message += (
                f"; inputs {', '.join(short)} incomplete (fewer than {need} accepted averages): "
                f"no FRF; resume it (POST /api/acquisitions/{acq_id}/resume) to strike them"
            )
        else:
            state = "succeeded"
        self._set(acq_id, frf_id=fid, state=state, message=message)
        log.info("acquisition %d finished from kept averages: %s", acq_id, message)
        return self.get(acq_id)

    def resume(self, acq_id: int) -> AcquisitionInfo | None:
        """A new acquisition that strikes only what an ended one is missing: the inputs short
        of ``averages_per_input`` accepted averages, each for its missing ones (input 7 had 2
        of 5: 3 more, its FRFs from the 5). Every input's FRFs come from the kept and the new
        averages together, and are merged like ``merge_frf_id`` into the ended one's FRF set
        (its :meth:`finish`) or, without one, into its own ``merge_frf_id``: the new FRF set
        covers every input. The ended one becomes ``resumed`` (naming the new one). Started
        like :meth:`start`: it holds the DAQ and the load cells. None: no such acquisition.

        Raises
        ------
        DeviceStateError
            Not resumable (running, succeeded, already resumed), another stand's, nothing is
            missing, or the devices are in use.
        """
        cur = self.get(acq_id)
        if cur is None:
            return None
        if cur.state not in RESUMABLE:
            hint = {
                "running": "finish or stop it first",
                "resumed": "resume the acquisition that resumed it (see its message)",
                "succeeded": "every input has its FRFs; to redo inputs start an acquisition "
                "with inputs and merge_frf_id",
            }.get(cur.state, "")
            raise DeviceStateError(
                f"acquisition {acq_id} is {cur.state}: only one interrupted, cancelled, failed "
                f"or incomplete can be resumed" + (f"; {hint}" if hint else "")
            )
        self._require_own(cur, "resume")
        cfg = dict(cur.config)
        inputs = [int(j) for j in cfg["inputs"]]
        wanted = int(cfg["averages_per_input"])
        kept, _fs = self._kept(acq_id, inputs)
        if kept.nothing_to_strike(wanted):
            raise DeviceStateError(
                f"acquisition {acq_id}: every input has its {wanted} accepted averages, nothing "
                f"to strike; finish it (POST /api/acquisitions/{acq_id}/finish) for its FRFs"
            )
        applied = cfg.get("applied") or {}
        # the settings the kept averages were taken with (whatever the rig file says now)
        pinned = {k: applied[k] for k in RECORD_SETTINGS if applied.get(k) is not None}
        new = {**{k: v for k, v in cfg.items() if k not in INTERNAL_KEYS}, **pinned}
        new["merge_frf_id"] = cur.frf_id if cur.frf_id is not None else cfg.get("merge_frf_id")
        return self._start(new, Resume(acq_id, kept.per_input))

    def _chain(self, acq_id: int) -> list[int]:
        """The acquisition and the ones it resumes, oldest first."""
        ids: list[int] = []
        at: int | None = acq_id
        with self.db.session() as s:
            while at is not None and at not in ids:
                r = s.get(m.Acquisition, at)
                if r is None:
                    break
                ids.append(at)
                nxt = (r.config or {}).get("resume_of")
                at = None if nxt is None else int(nxt)
        return ids[::-1]

    def _kept(self, acq_id: int, inputs: Sequence[int]) -> tuple[KeptAverages[Record], float]:
        """The accepted averages of an acquisition and of those it resumes, per struck input
        (``inputs`` order; oldest first; :func:`kept_averages`),
        read from this stand's disk; and the sample rate.

        Raises
        ------
        DeviceStateError
            An average is on another stand's disk.
        DataError
            An average's file is missing or unreadable (named).
        """
        ids = self._chain(acq_id)
        with self.db.session() as s:
            rows = [
                (a.acquisition_id, a.number, a.input_index, a.path, a.stand)
                for a in s.scalars(
                    select(m.Average).where(
                        m.Average.acquisition_id.in_(ids), m.Average.accepted.is_(True)
                    )
                )
            ]
        rows.sort(key=lambda r: (ids.index(r[0]), r[1]))
        fs = 0.0

        def load(row: tuple[int, int, int, str, str]) -> Record:
            nonlocal fs
            aid, number, _j, rel, stand = row
            if stand not in (self.stand, ""):
                raise DeviceStateError(
                    f"average {number} of acquisition {aid} is on stand {stand!r}'s disk; "
                    f"finish or resume it there ({self._stand_url(stand)})"
                )
            try:
                arrays, attrs = self.arrays.read(rel)
                rec = {
                    "force": np.asarray(arrays["force"], dtype=np.float64),
                    "outputs": np.asarray(arrays["outputs"], dtype=np.float64),
                }
                fs = float(attrs["sample_rate_hz"])
            except (OSError, KeyError, DataError) as err:
                raise DataError(
                    f"average {number} of acquisition {aid} ({self.arrays.path(rel)}): {err}; "
                    "restore the file, or delete the average's row to go on without it"
                ) from err
            return rec

        # every row is an accepted average (the query's condition)
        kept = kept_averages(((r[2], True, r) for r in rows), inputs, load)
        return kept, fs

    def _applied(self, cfg: Mapping[str, Any]) -> ImpactSettings:
        """The impact settings an acquisition ran with: as stored when it started, else (older
        rows) its request over the rig file's ``[acquisition]`` table as it is now."""
        if cfg.get("applied"):
            return ImpactSettings.model_validate(cfg["applied"])
        from dimacq.io.rig_file import load_rig_file

        defaults = load_rig_file(self.settings.rig_path).acquisition.given()
        return ImpactSettings.layered(defaults, cfg)
