"""Acquisitions: impact tests run as jobs; every completed average is kept.

Every completed average (accepted or rejected) is written to its own HDF5 file and committed to
the database before the next strike, so a crash loses none of them; after a restart the files
written but not yet committed are registered (:meth:`AcquisitionService.recover`). When all
inputs have their averages the FRFs are estimated and stored as an FRF set; an input left with
fewer than ``min_averages`` accepted averages is incomplete: it gets no FRF and the acquisition
names it (``incomplete_inputs``, ``input_states``, its message) and ends ``incomplete``, never
``succeeded`` (``failed`` when no input has its averages).

While a hit waits for the operator (review) the session drains the DAQ; a strike lost to a DAQ
gap is asked again and reported per input (``input_states``: ``lost``, ``lost_reasons``; kept in
memory for this service's run, summed up in the final message). A hit the checks rejected is
accepted only with ``override`` (never one with samples lost); review can be switched on or off
while the acquisition runs (:meth:`AcquisitionService.set_review`).

After a crash (or a stop, or a failure) the kept averages are not lost work:
:meth:`AcquisitionService.finish` estimates the FRFs of the complete inputs from their files,
with the live run's estimator (state ``succeeded`` only when no input is missing, else
``incomplete`` naming them), and :meth:`AcquisitionService.resume` starts a new acquisition
whose session begins each input with its kept accepted averages and strikes only the missing
ones; the ended acquisition becomes ``resumed`` (config ``resume_of`` links them, and a chain
of resumes counts every link's averages).

On a shared database every acquisition belongs to the stand that runs it: only that stand
stops or recovers it, and the raw time data stay on its disk (:meth:`average_data`). While the
database is unreachable the averages go on to the disk and their rows wait in the outbox
(:class:`dimacq.persistence.queue.Outbox`); the FRFs are stored with retry and backoff.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from typing import Any

import numpy as np
from sqlalchemy import func, select

from dimacq.config import Settings
from dimacq.errors import (
    DataError,
    DeviceNotFoundError,
    DeviceStateError,
    SetupError,
)
from dimacq.model.channels import input_name
from dimacq.model.impact import ImpactSettings
from dimacq.model.setup import TestSetup
from dimacq.persistence import ArrayStore, Database
from dimacq.persistence import models as m
from dimacq.persistence import stands as stand_lease
from dimacq.persistence.queue import Outbox
from dimacq.services.lab.acquisition_records import (
    ACQUISITION_DEVICES,
    ENDED_WITH_INPUTS,
    INTERNAL_KEYS,
    RESUMABLE,
    AcquisitionInfo,
    AverageInfo,
    RawBlocks,
    Record,
    Resume,
    RigFactory,
    accepted_per_input,
    count,
    input_states,
)
from dimacq.services.lab.acquisition_recovery import AcquisitionRecovery
from dimacq.services.lab.acquisition_review import AcquisitionReview
from dimacq.services.lab.acquisition_run import AcquisitionRun
from dimacq.services.lab.acquisition_views import LiveReview
from dimacq.services.lab.common import iso, json_safe
from dimacq.services.lab.devices import DeviceService
from dimacq.services.lab.jobs import JobManager
from dimacq.services.lab.store import Page, TestStore

__all__ = [
    "AcquisitionInfo",
    "AcquisitionService",
    "AverageInfo",
    "RawBlocks",
    "RigFactory",
]

log = logging.getLogger(__name__)


class AcquisitionService(AcquisitionReview, AcquisitionRecovery, AcquisitionRun):
    """Start, follow and stop impact acquisitions.

    Parameters
    ----------
    settings, db, arrays, jobs, devices, store
        The lab's parts this service uses.
    rig_factory : callable (settings, setup, config) -> Rig, optional
        Default :func:`dimacq.services.acquisition.rig.build_rig` on the configured devices (which must
        be connected).
    raw_blocks : callable (acquisition id) -> Path or None, optional
        Where an acquisition keeps every raw block it reads (an HDF5 file,
        :func:`dimacq.services.acquisition.rig.raw_writer`); None (default): not kept.
    """

    def __init__(
        self,
        settings: Settings,
        db: Database,
        arrays: ArrayStore,
        jobs: JobManager,
        devices: DeviceService,
        store: TestStore,
        rig_factory: RigFactory | None = None,
        *,
        stand: str = "",
        outbox: Outbox | None = None,
        raw_blocks: RawBlocks | None = None,
    ) -> None:
        self.settings = settings
        self.raw_blocks = raw_blocks
        self.stand = stand
        self.outbox = outbox if outbox is not None else Outbox()
        self.db = db
        self.arrays = arrays
        self.jobs = jobs
        self.devices = devices
        self.store = store
        self._rig_factory = rig_factory
        self._live: dict[int, LiveReview] = {}

    def recover(self) -> None:
        """After a restart: this stand's running acquisitions are interrupted (other stands'
        are theirs); orphan average files (written but not yet committed when the service died,
        or while the database was unreachable) are registered."""
        mine = [self.stand, ""]
        with self.db.session() as s:
            for acq in s.scalars(select(m.Acquisition).where(m.Acquisition.stand.in_(mine))):
                if acq.state in ("running", "configured-running"):
                    acq.state = "interrupted"
                    acq.message = (
                        "the service stopped during the acquisition; completed averages are kept"
                    )
            known = set(s.scalars(select(m.Average.path).where(m.Average.stand.in_(mine))))
            for rel in self.arrays.orphans("acquisitions", known):
                try:
                    _, attrs = self.arrays.read(rel)
                    s.add(
                        m.Average(
                            acquisition_id=int(attrs["acquisition_id"]),
                            input_index=int(attrs["input_index"]),
                            number=int(attrs["number"]),
                            accepted=bool(attrs["accepted"]),
                            reason=str(attrs.get("reason", "")),
                            path=rel,
                            stand=self.stand,
                        )
                    )
                    log.info("recovered average file %s", rel)
                except (OSError, KeyError, DataError) as err:
                    log.warning("average file %s is unreadable (%s); left in place", rel, err)

    # ------------------------------------------------------------------ start and run
    def start(self, config: Mapping[str, Any]) -> AcquisitionInfo:
        """Configure and start an impact acquisition as a job; returns the acquisition.

        ``config``: ``setup_id`` and the impact settings of
        :class:`dimacq.api.schemas.AcquisitionRequest` (None: from the rig).
        """
        return self._start(config)

    def _start(self, config: Mapping[str, Any], resume: Resume | None = None) -> AcquisitionInfo:
        """:meth:`start`; with ``resume`` the new acquisition continues an ended one: its
        inputs start with the accepted averages kept (``resume.kept``) and the ended one is
        marked ``resumed`` when the new one exists (one step, the devices held)."""
        cfg = {k: v for k, v in config.items() if k not in INTERNAL_KEYS}
        setup_id = int(cfg["setup_id"])
        setup = self.store.require_setup(setup_id)
        inputs = self._struck_inputs(cfg, setup_id, setup)
        struck = setup.model_copy(
            update={"excitations": tuple(setup.excitations[j] for j in inputs)}
        )
        claim, rig, applied = self._claim_rig(struck, cfg)
        prior = self._complete_config(cfg, applied, inputs, struck, resume)
        acq_id = self._insert(setup_id, cfg, resume, prior, rig, claim)
        self.devices.owners.rename(claim, f"acquisition {acq_id}")
        live = LiveReview(
            review=bool(cfg.get("review")),
            n_inputs=len(inputs),
            sample_rate_hz=float(getattr(rig.daq, "sample_rate_hz", 0.0) or 0.0),
            coherence=[None] * len(inputs),
            lost=[[] for _ in inputs],
        )
        self._live[acq_id] = live
        LiveReview.keep_newest_views(self._live)
        try:
            job = self.jobs.submit(
                "acquisition",
                lambda ctx: self._run(
                    ctx, acq_id, setup_id, setup, struck, cfg, rig, live, claim, prior
                ),
            )
        except BaseException:
            rig.close()
            self.devices.owners.release(claim)
            self._live.pop(acq_id, None)
            self._set(acq_id, state="failed")
            raise
        self.devices.owners.rename(claim, f"acquisition {acq_id} (job {job.id})")
        self._set(acq_id, job_id=job.id)
        out = self.get(acq_id)
        assert out is not None
        return out

    def _struck_inputs(self, cfg: dict[str, Any], setup_id: int, setup: TestSetup) -> list[int]:
        """The setup indices of the inputs to strike (``cfg["inputs"]``, default all; written
        back), and the FRF set to merge into checked to be of this setup.

        Raises
        ------
        SetupError
            Indices out of range or repeated; a merge set that does not exist or belongs to
            another setup.
        """
        n_ex = len(setup.excitations)
        inputs = cfg.get("inputs")
        if inputs is None:
            inputs = list(range(n_ex))
        inputs = [int(j) for j in inputs]
        bad = [j for j in inputs if not 0 <= j < n_ex]
        if bad or not inputs or len(set(inputs)) != len(inputs):
            raise SetupError(
                f"inputs {inputs}: give distinct indices of setup {setup_id}'s inputs, "
                f"0..{n_ex - 1}"
            )
        cfg["inputs"] = inputs
        merge_id = cfg.get("merge_frf_id")
        if merge_id is not None:
            merged = self.store.frf(int(merge_id))
            if merged is None:
                raise SetupError(
                    f"merge_frf_id {merge_id} does not exist; give an FRF set of setup {setup_id}"
                )
            if merged[1] != setup:
                raise SetupError(
                    f"merge_frf_id {merge_id} belongs to another setup; give an FRF set of "
                    f"setup {setup_id} (its inputs are replaced or appended)"
                )
        return inputs

    def _claim_rig(
        self, struck: TestSetup, cfg: dict[str, Any]
    ) -> tuple[Any, Any, ImpactSettings | None]:
        """Claim the DAQ and the load cells, build the rig of the struck inputs, complete the
        average counts of ``cfg`` (:meth:`_fill_counts`) and check the settings as applied; on
        any failure the rig is closed and the claim released.

        Returns
        -------
        claim, rig, applied
        """
        # The DAQ and the load cells are this acquisition's from here until its job ends: the
        # check and the claim are one step (three requests sent together: one starts).
        claim = self.devices.owners.claim(ACQUISITION_DEVICES, "an acquisition being started")
        try:
            if self.jobs.running("acquisition"):  # another stand's process, same service
                raise DeviceStateError("an acquisition is already running; stop it or wait for it")
            rig = self._build_rig(struck, cfg)  # raises DeviceError if the devices are not there
        except BaseException:
            self.devices.owners.release(claim)
            raise
        try:
            self._fill_counts(cfg, rig)
            # every setting as applied (request < rig file < rig), before any job starts
            applied = self._check(rig, struck, cfg)
        except BaseException:
            rig.close()
            self.devices.owners.release(claim)
            raise
        return claim, rig, applied

    def _fill_counts(self, cfg: dict[str, Any], rig: Any) -> None:
        """Write into ``cfg`` the averages per input and the minimum of accepted ones the
        acquisition runs with and is stored with: the request's, else the rig file's
        ``[acquisition]``, else the service's ``min_averages`` setting (and the built-in count)."""
        defaults: Mapping[str, Any] = getattr(rig, "defaults", {})
        if cfg.get("min_averages") is None:
            cfg["min_averages"] = defaults.get("min_averages", self.settings.min_averages)
        if cfg.get("averages_per_input") is None:
            cfg["averages_per_input"] = defaults.get(
                "averages_per_input", ImpactSettings().averages_per_input
            )

    def _complete_config(
        self,
        cfg: dict[str, Any],
        applied: ImpactSettings | None,
        inputs: list[int],
        struck: TestSetup,
        resume: Resume | None,
    ) -> list[list[Record]] | None:
        """Write into ``cfg`` what the acquisition is stored with (the applied settings, what
        it resumes, the inputs' names); the kept averages it starts from."""
        # the settings the FRFs are estimated with: a finish after a crash estimates them alike
        cfg["applied"] = json_safe(applied.model_dump()) if applied is not None else None
        prior: list[list[Record]] | None = None
        if resume is not None:
            cfg["resume_of"] = resume.acq_id
            cfg["kept_per_input"] = {
                str(j): len(r) for j, r in zip(inputs, resume.kept, strict=True)
            }
            prior = resume.kept
        # the struck inputs by point and direction ("101+X"): what the operator strikes
        cfg["input_names"] = [input_name(e) for e in struck.excitations]
        return prior

    def _insert(
        self,
        setup_id: int,
        cfg: Mapping[str, Any],
        resume: Resume | None,
        prior: list[list[Record]] | None,
        rig: Any,
        claim: Any,
    ) -> int:
        """Store the new acquisition (running) and mark the one it resumes ``resumed``, in one
        transaction; its id. On failure the rig is closed and the claim released.

        Raises
        ------
        DeviceStateError
            The acquisition to resume was deleted or resumed meanwhile.
        """
        try:
            with self.db.session() as s:
                old = None
                if resume is not None:  # still resumable (nobody resumed it meanwhile)
                    old = s.get(m.Acquisition, resume.acq_id)
                    if old is None or old.state not in RESUMABLE:
                        raise DeviceStateError(
                            f"acquisition {resume.acq_id} is "
                            f"{'deleted' if old is None else old.state}: it cannot be resumed"
                        )
                row = m.Acquisition(
                    setup_id=setup_id, config=json_safe(cfg), state="running", stand=self.stand
                )
                s.add(row)
                s.flush()
                acq_id = int(row.id)
                if old is not None:
                    old.state = "resumed"
                    old.message = (
                        f"resumed by acquisition {acq_id} (its {sum(map(len, prior or []))} "
                        "accepted averages are used there; the missing ones are struck)"
                    )
        except BaseException:
            rig.close()
            self.devices.owners.release(claim)
            raise
        return acq_id

    def _check(self, rig: Any, setup: TestSetup, cfg: Mapping[str, Any]) -> ImpactSettings | None:
        from dimacq.services.acquisition.rig import check_impact_test

        return check_impact_test(rig, setup, cfg)

    def _set(self, acq_id: int, **values: Any) -> None:
        with self.db.session() as s:
            r = s.get(m.Acquisition, acq_id)
            assert r is not None
            for k, v in values.items():
                setattr(r, k, v)

    def _build_rig(self, setup: TestSetup, cfg: Mapping[str, Any]) -> Any:
        from dimacq.services.acquisition import rig as rig_builder

        if self._rig_factory is not None:
            return self._rig_factory(self.settings, setup, cfg)
        for name in ("daq", "loadcell"):
            info = self.devices.require(name)
            if not info.connected:
                raise DeviceNotFoundError(
                    f"{name} is not connected ({info.error or 'closed'}); connect it first"
                )
        rig = rig_builder.build_rig(self.settings, setup, cfg)
        for name in ("daq", "loadcell"):  # opened and identified: there
            self.devices.mark(name, "")
        return rig

    # ------------------------------------------------------------------ read and stop
    def all(self, limit: int | None = None, offset: int = 0) -> Page[AcquisitionInfo]:
        """Acquisitions in id order: ``limit`` of them (None: all) after ``offset``."""
        with self.db.session() as s:
            total = int(s.scalar(select(func.count()).select_from(m.Acquisition)) or 0)
            ids = list(
                s.scalars(
                    select(m.Acquisition.id).order_by(m.Acquisition.id).offset(offset).limit(limit)
                )
            )
        return Page([a for a in (self.get(i) for i in ids) if a is not None], total)

    def delete(self, acq_id: int) -> bool | None:
        """Delete an acquisition that is not running: its averages (rows and, on this stand,
        their raw-data files); its FRF set stays. None if it does not exist."""
        cur = self.get(acq_id)
        if cur is None:
            return None
        if cur.state == "running":
            raise DeviceStateError(
                f"acquisition {acq_id} is running: stop it first "
                f"(POST /api/acquisitions/{acq_id}/stop)"
            )
        if cur.state == "resumed":  # its averages are part of the one that resumed it
            with self.db.session() as s:
                later = [
                    int(a.id)
                    for a in s.scalars(select(m.Acquisition).where(m.Acquisition.id > acq_id))
                    if (a.config or {}).get("resume_of") == acq_id
                ]
            if later:
                raise DeviceStateError(
                    f"acquisition {acq_id} was resumed by acquisition {later[0]}, which uses its "
                    f"averages; delete acquisition {later[0]} first"
                )
        with self.db.session() as s:
            files = []
            for a in s.scalars(select(m.Average).where(m.Average.acquisition_id == acq_id)):
                if a.stand in (self.stand, ""):
                    files.append(a.path)
                s.delete(a)
            s.flush()
            row = s.get(m.Acquisition, acq_id)
            if row is not None:
                s.delete(row)
        for rel in files:
            self.arrays.path(rel).unlink(missing_ok=True)
        return True

    def get(self, acq_id: int) -> AcquisitionInfo | None:
        """State, progress and every completed average of an acquisition."""
        with self.db.session() as s:
            r = s.get(m.Acquisition, acq_id)
            if r is None:
                return None
            avgs = [
                AverageInfo(a.number, a.input_index, a.accepted, a.reason, a.path)
                for a in s.scalars(
                    select(m.Average)
                    .where(m.Average.acquisition_id == acq_id)
                    .order_by(m.Average.number)
                )
            ]
            row = (r.id, r.setup_id, r.config, r.state, r.message, r.job_id, r.frf_id, r.stand)
            times = (iso(r.created_at), iso(r.updated_at or r.created_at))
        acq, setup_id, config, state, message, job_id, frf_id, stand = row
        # one word for a job that ended well, as the jobs say it (rows before schema 4: finished)
        state = "succeeded" if state == "finished" else state
        snap = self.jobs.snapshot(job_id) if job_id else None
        cfg = config or {}
        per_input = accepted_per_input(avgs)
        for j, n in (cfg.get("kept_per_input") or {}).items():  # a resumed one: those kept
            j = int(j)
            per_input += [0] * (j + 1 - len(per_input))
            per_input[j] += int(n)
        live = self._live.get(acq)
        struck = cfg.get("inputs")
        need = min(int(cfg.get("min_averages") or 1), int(cfg.get("averages_per_input") or 10**6))
        struck_inputs = list(struck) if struck is not None else list(range(len(per_input)))
        review = live.review if live is not None else bool(cfg.get("review"))
        return AcquisitionInfo(
            id=acq,
            setup_id=setup_id,
            config=config,
            state=state,
            message=message,
            job_id=job_id,
            frf_id=frf_id,
            averages_accepted=sum(1 for a in avgs if a.accepted),
            accepted_per_input=per_input,
            averages_rejected=sum(1 for a in avgs if not a.accepted),
            averages=avgs,
            min_averages=need,
            incomplete_inputs=[j for j in struck_inputs if count(per_input, j) < need]
            if state in ENDED_WITH_INPUTS
            else [],
            progress=snap["progress"] if snap else (1.0 if state == "succeeded" else 0.0),
            stand=stand,
            pending_review=dict(live.pending) if live and live.pending else None,
            input_coherence=list(live.coherence) if live else [],
            inputs=struck_inputs,
            review=review,
            input_states=input_states(
                state, struck_inputs, cfg.get("input_names"), avgs, need, live
            ),
            created_at=times[0],
            updated_at=times[1],
        )

    # ------------------------------------------------------------------ the operator's decisions

    def stop(self, acq_id: int) -> AcquisitionInfo | None:
        """Cancel a running acquisition (completed averages are kept)."""
        cur = self.get(acq_id)
        if cur is None:
            return None
        if cur.state == "running" and cur.stand not in (self.stand, ""):
            raise DeviceStateError(
                f"acquisition {acq_id} runs on stand {cur.stand!r}: only that stand drives its "
                f"devices; stop it through its API ({self._stand_url(cur.stand)})"
            )
        if cur.job_id and cur.state == "running":
            self.jobs.cancel(cur.job_id)
        return self.get(acq_id)

    def _stand_url(self, name: str) -> str:
        for st in stand_lease.stands(self.db):
            if st["name"] == name:
                return st["api_url"] or "address unknown"
        return "address unknown"

    def average_data(self, acq_id: int, number: int) -> dict[str, Any] | None:
        """Raw time data of one average: it lives on the disk of the stand that acquired it, so
        only that stand serves it (another stand raises DeviceStateError with its address)."""
        with self.db.session() as s:
            acq = s.get(m.Acquisition, acq_id)
            if acq is None or not -(2**31) <= number < 2**31:
                return None
            avg = s.scalars(
                select(m.Average).where(
                    m.Average.acquisition_id == acq_id, m.Average.number == number
                )
            ).first()
            if avg is None:
                return None
            where, rel = avg.stand, avg.path
        if where not in (self.stand, ""):
            raise DeviceStateError(
                f"average {number} of acquisition {acq_id}: its raw time data are on stand "
                f"{where!r}; ask that stand's API ({self._stand_url(where)})"
            )
        arrays, attrs = self.arrays.read(rel)
        return {
            "acquisition_id": acq_id,
            "number": number,
            "stand": self.stand,
            "path": rel,
            "attrs": attrs,
            "arrays": {k: json_safe(np.asarray(v)) for k, v in arrays.items()},
            "shapes": {k: list(np.shape(v)) for k, v in arrays.items()},
        }
