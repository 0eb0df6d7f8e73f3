"""The job that runs an acquisition: the impact session's callbacks (:class:`RunHooks`: the
operator's review of each hit, each average made durable before the next strike, strikes lost,
each input's coherence, the job's progress), the FRFs stored after the averages (retried while
the database is away, else kept in a file) and the acquisition's end state
(:class:`AcquisitionRun`, a part of :class:`~dimacq.services.lab.acquisitions.AcquisitionService`)."""

from __future__ import annotations

import logging
import queue
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from dimacq.errors import DatabaseUnavailableError, DataError, DimacqError
from dimacq.model.setup import TestSetup
from dimacq.persistence import models as m
from dimacq.services.acquisition.impact_result import unusable_reasons
from dimacq.services.lab.acquisition_records import Record, ServiceParts, lost_note
from dimacq.services.lab.acquisition_views import Decision, LiveReview, hit_view, merge_frfs
from dimacq.services.lab.jobs import JobContext
from dimacq.services.lab.ownership import Claim
from dimacq.services.lab.store import frf_to_arrays

log = logging.getLogger("dimacq.services.lab.acquisitions")


class AcquisitionRun(ServiceParts):
    """Methods of :class:`~dimacq.services.lab.acquisitions.AcquisitionService` (its state: see
    there)."""

    def _run(
        self,
        ctx: JobContext,
        acq_id: int,
        setup_id: int,
        setup: TestSetup,
        struck: TestSetup,
        cfg: Mapping[str, Any],
        rig: Any,
        live: LiveReview,
        claim: Claim | None = None,
        prior: Sequence[Sequence[Record]] | None = None,
    ) -> dict[str, Any]:
        from dimacq.services.acquisition.rig import raw_writer, run_impact_test

        names: list[str] = list(cfg["input_names"])
        hooks = RunHooks(
            self,
            ctx,
            acq_id,
            list(cfg["inputs"]),
            names,
            live.sample_rate_hz,
            len(setup.responses),
            live,
        )
        state, message = "failed", ""
        raw = self.raw_blocks(acq_id) if self.raw_blocks is not None else None
        try:
            with raw_writer(rig, raw) as writer:
                frf = run_impact_test(
                    rig,
                    struck,
                    cfg,
                    on_average=hooks.on_average,
                    on_progress=hooks.on_progress,
                    writer=writer,
                    review=hooks.review,  # always: the operator may switch review on or off
                    should_finish=live.finish.is_set,
                    on_input=hooks.on_input,
                    on_event=self.devices.on_acquisition_event,
                    prior=prior,
                    on_lost=hooks.on_lost,
                )
            fid = self._store_run_frf(ctx, acq_id, setup_id, setup, cfg, frf)
            state, message = outcome(frf, fid, cfg)
            message += lost_note(names, live.lost)
            return {"acquisition_id": acq_id, "frf_id": fid}
        except DimacqError as err:
            state = "cancelled" if ctx.cancelled else "failed"
            message = str(err) + lost_note(names, live.lost)
            raise
        finally:
            self._end_run(acq_id, rig, claim, live, state, message)

    def _store_run_frf(
        self,
        ctx: JobContext,
        acq_id: int,
        setup_id: int,
        setup: TestSetup,
        cfg: Mapping[str, Any],
        frf: Any,
    ) -> int:
        """Store the run's FRFs (merged into ``merge_frf_id`` when given) after its averages,
        retrying while the database is away; its FRF set id.

        Raises
        ------
        DatabaseUnavailableError
            The database stayed away: the FRFs are kept in a file named in the message.
        """

        def wait(msg: str) -> None:
            ctx.progress(1.0, msg)

        def store_frf(frf: Any) -> int:
            self.outbox.flush(self.db)  # the averages first
            merge_id = cfg.get("merge_frf_id")
            if merge_id is not None:
                base = self.store.frf(int(merge_id))
                if base is None:
                    raise DataError(f"FRF set {merge_id} was deleted during the acquisition")
                frf = merge_frfs(base[0], frf, setup)
            fid = self.store.save_frf(
                frf, setup_id, name=f"acquisition {acq_id}", acquisition_id=acq_id
            )
            self._set(acq_id, frf_id=fid)
            return fid

        try:
            return self.db.retry(
                lambda: store_frf(frf),
                what="store the FRFs",
                timeout_s=self.settings.database_retry_s,
                on_wait=wait,
            )
        except DatabaseUnavailableError as err:
            rel = self.arrays.write(
                f"frfs/unsaved-acquisition-{acq_id:06d}.h5", *frf_to_arrays(frf)
            )
            raise DatabaseUnavailableError(
                f"{err}; the FRFs are kept in {self.arrays.path(rel)} and every average in "
                f"{self.arrays.path(f'acquisitions/{acq_id:06d}')} (import the FRFs when "
                "the database is back)"
            ) from err

    def _end_run(
        self,
        acq_id: int,
        rig: Any,
        claim: Claim | None,
        live: LiveReview,
        state: str,
        message: str,
    ) -> None:
        """Close the rig, free the devices, drop the waiting hit and store the acquisition's
        end state (through the outbox when the database is away)."""
        rig.close()
        if claim is not None:  # the devices are free for the next job
            self.devices.owners.release(claim)
        live.pending = live.pending_view = None

        def final(s: Any) -> None:
            r = s.get(m.Acquisition, acq_id)
            assert r is not None
            r.state, r.message = state, message

        if not self.outbox.write(self.db, f"acquisition {acq_id} {state}", final):
            log.warning(
                "acquisition %d %s; its state is stored when the database is back",
                acq_id,
                state,
            )


def outcome(frf: Any, fid: int, cfg: Mapping[str, Any]) -> tuple[str, str]:
    """The end state and message of a run whose FRFs are stored as set ``fid``: ``succeeded``,
    or ``incomplete`` when inputs are missing from the set (named, with the count they lack)."""
    state, message = "succeeded", f"FRFs stored as FRF set {fid}"
    if frf.meta.get("incomplete_inputs"):
        # not a success: inputs are missing from the set (state "incomplete")
        state = "incomplete"
        # the count the run held them to: min_averages capped at the averages asked
        need = min(int(cfg["min_averages"]), int(cfg.get("averages_per_input") or 10**6))
        message += (
            f"; inputs {frf.meta['incomplete_inputs']} incomplete (fewer than "
            f"{need} accepted averages): no FRF, strike them again "
            f"(append them into FRF set {fid})"
        )
    return state, message


@dataclass
class RunHooks:
    """The impact session's callbacks of one acquisition job: the operator's review of each
    hit, strikes lost, each input's coherence, each average stored, the job's progress.

    ``inputs`` and ``names`` are the struck inputs' setup indices and names (the session counts
    the struck inputs only); ``fraction`` is the job's last progress.
    """

    svc: AcquisitionRun
    ctx: JobContext
    acq_id: int
    inputs: list[int]
    names: list[str]
    fs: float
    n_resp: int
    live: LiveReview
    fraction: float = 0.0

    def review(
        self,
        j: int,
        average_index: int,
        reasons: tuple[str, ...],
        record: Mapping[str, NDArray[np.float64]],
        wait_s: float,
    ) -> Decision | None:
        live, inputs = self.live, self.inputs
        number = average_index + 1
        with live.lock:
            if not live.review:  # never on, or switched off: the checks decide this hit
                if live.pending is not None and live.pending["number"] == number:
                    live.pending = None
                    live.answered = number
                return "accept"
            announce = live.answered != number and (
                live.pending is None or live.pending["number"] != number
            )
            if announce:
                holes = unusable_reasons(reasons)
                live.pending_view = hit_view(record, self.fs, self.n_resp)
                live.pending = {
                    "number": number,
                    "input_index": inputs[j],
                    "input_name": self.names[j],
                    "reasons": list(reasons),
                    # accept: "yes" (the checks passed), "override" (only with override:
                    # true) or "no" (samples lost: the record has holes)
                    "accept": "no" if holes else ("override" if reasons else "yes"),
                }
        if announce:
            self.ctx.progress(
                self.fraction,
                f"hit {number} on input {inputs[j] + 1}: accept, reject or redo the input",
            )
        if live.finish.is_set():
            return "reject"
        self.ctx.check_cancelled()
        try:
            got, decision = live.decisions.get(timeout=wait_s)
        except queue.Empty:
            return None
        if got != number:  # a decision on a hit already decided: ignored
            return None
        if decision == "redo":
            self.svc._supersede(self.acq_id, inputs[j])
        return decision

    def on_lost(self, j: int, reason: str) -> None:
        self.live.lost[j].append(reason)

    def on_input(self, j: int, coherence: NDArray[np.float64]) -> None:
        c = coherence[:, : self.n_resp]
        self.live.coherence[j] = float(np.nanmean(c)) if np.isfinite(c).any() else None

    def on_average(
        self,
        input_index: int,
        average_index: int,
        accepted: bool,
        reasons: Sequence[str],
        record: Mapping[str, NDArray[np.float64]],
    ) -> None:
        live, svc, acq_id = self.live, self.svc, self.acq_id
        input_index = self.inputs[input_index]  # the session counts the struck inputs only
        live.last_view = (
            live.pending_view
            if live.pending_view is not None
            else hit_view(record, self.fs, self.n_resp)
        )
        live.last_view = {
            **live.last_view,
            "number": average_index + 1,
            "input_index": input_index,
            "accepted": accepted,
            "reasons": list(reasons),
        }
        live.pending_view = None
        number = average_index + 1
        rel = f"acquisitions/{acq_id:06d}/avg-{number:05d}.h5"
        reason = "; ".join(reasons)
        attrs = {
            "acquisition_id": acq_id,
            "input_index": input_index,
            "number": number,
            "accepted": accepted,
            "reason": reason,
            "sample_rate_hz": self.fs,
        }
        svc.arrays.write(rel, record, attrs)  # on this stand's disk first, always
        row = {
            "acquisition_id": acq_id,
            "input_index": input_index,
            "number": number,
            "accepted": accepted,
            "reason": reason,
            "path": rel,
            "stand": svc.stand,
        }
        if not svc.outbox.write(svc.db, rel, lambda s: s.add(m.Average(**row))):
            log.warning("average %s kept on disk; registered when the database is back", rel)

    def on_progress(self, fraction: float, message: str) -> None:
        self.fraction = fraction
        self.ctx.progress(fraction, message)
        self.ctx.check_cancelled()  # raising here stops the session; its finally stops the devices
