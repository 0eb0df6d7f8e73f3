"""Acquisitions: impact tests run as jobs; every completed average is kept.

Every completed average (accepted or rejected) is written to its own HDF5 file and committed to
the database before the next strike, so a crash loses none of them; after a restart the files
written but not yet committed are registered (:meth:`AcquisitionService.recover`). When all
inputs have their averages the FRFs are estimated and stored as an FRF set.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray
from sqlalchemy import select

from dimacq.config import Settings
from dimacq.errors import DataError, DeviceNotFoundError, DeviceStateError, DimacqError
from dimacq.model.setup import TestSetup
from dimacq.persistence import ArrayStore, Database
from dimacq.persistence import models as m
from dimacq.services.jobs import JobContext, JobManager
from dimacq.services.lab.common import json_safe
from dimacq.services.lab.devices import DeviceService
from dimacq.services.lab.store import TestStore

__all__ = ["AcquisitionInfo", "AcquisitionService", "AverageInfo", "RigFactory"]

log = logging.getLogger(__name__)

#: Builds the acquisition rig (:class:`dimacq.services.rig.Rig`) for a setup and a request.
RigFactory = Callable[[Settings, TestSetup, Mapping[str, Any]], Any]


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
    """State, progress (0..1) and every completed average of an acquisition."""

    id: int
    setup_id: int | None
    config: dict[str, Any]
    state: str
    message: str
    job_id: str | None
    frf_id: int | None
    averages_accepted: int
    averages_rejected: int
    averages: list[AverageInfo]
    progress: float


class AcquisitionService:
    """Start, follow and stop impact acquisitions.

    Parameters
    ----------
    settings, db, arrays, jobs, devices, store
        The lab's parts this service uses.
    rig_factory : callable (settings, setup, config) -> Rig, optional
        Default :func:`dimacq.services.rig.build_rig` on the configured devices (which must
        be connected).
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
    ) -> None:
        self.settings = settings
        self.db = db
        self.arrays = arrays
        self.jobs = jobs
        self.devices = devices
        self.store = store
        self._rig_factory = rig_factory

    def recover(self) -> None:
        """After a restart: running acquisitions are interrupted; orphan average files (written
        but not yet committed when the service died) are registered."""
        with self.db.session() as s:
            for acq in s.scalars(select(m.Acquisition)):
                if acq.state in ("running", "configured-running"):
                    acq.state = "interrupted"
                    acq.message = (
                        "the service stopped during the acquisition; completed averages are kept"
                    )
            known = set(s.scalars(select(m.Average.path)))
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
        cfg = dict(config)
        setup_id = int(cfg["setup_id"])
        setup = self.store.require_setup(setup_id)
        if self.jobs.running("acquisition"):
            raise DeviceStateError("an acquisition is already running; stop it or wait for it")
        rig = self._build_rig(setup, cfg)  # raises DeviceError if the devices are not there
        with self.db.session() as s:
            row = m.Acquisition(setup_id=setup_id, config=json_safe(cfg), state="running")
            s.add(row)
            s.flush()
            acq_id = int(row.id)
        try:
            job = self.jobs.submit(
                "acquisition",
                lambda ctx: self._run(ctx, acq_id, setup_id, setup, cfg, rig),
            )
        except DimacqError:
            rig.close()
            self._set(acq_id, state="failed")
            raise
        self._set(acq_id, job_id=job.id)
        out = self.get(acq_id)
        assert out is not None
        return out

    def _set(self, acq_id: int, **values: Any) -> None:
        with self.db.session() as s:
            r = s.get(m.Acquisition, acq_id)
            assert r is not None
            for k, v in values.items():
                setattr(r, k, v)

    def _build_rig(self, setup: TestSetup, cfg: Mapping[str, Any]) -> Any:
        from dimacq.services import rig as rig_builder

        if self._rig_factory is not None:
            return self._rig_factory(self.settings, setup, cfg)
        for name in ("daq", "loadcell"):
            info = self.devices.require(name)
            if not info.connected:
                raise DeviceNotFoundError(
                    f"{name} is not connected ({info.error or 'closed'}); connect it first"
                )
        return rig_builder.build_rig(self.settings, setup, cfg)

    def _run(
        self,
        ctx: JobContext,
        acq_id: int,
        setup_id: int,
        setup: TestSetup,
        cfg: Mapping[str, Any],
        rig: Any,
    ) -> dict[str, Any]:
        from dimacq.services.rig import run_impact_test

        def on_average(
            input_index: int,
            average_index: int,
            accepted: bool,
            reasons: Sequence[str],
            record: Mapping[str, NDArray[np.float64]],
        ) -> None:
            number = average_index + 1
            rel = f"acquisitions/{acq_id:06d}/avg-{number:05d}.h5"
            reason = "; ".join(reasons)
            attrs = {
                "acquisition_id": acq_id,
                "input_index": input_index,
                "number": number,
                "accepted": accepted,
                "reason": reason,
            }
            self.arrays.write(rel, record, attrs)
            with self.db.session() as s:
                s.add(
                    m.Average(
                        acquisition_id=acq_id,
                        input_index=input_index,
                        number=number,
                        accepted=accepted,
                        reason=reason,
                        path=rel,
                    )
                )

        def on_progress(fraction: float, message: str) -> None:
            ctx.progress(fraction, message)
            ctx.check_cancelled()  # raising here stops the session; its finally stops the devices

        state, message = "failed", ""
        try:
            frf = run_impact_test(rig, setup, cfg, on_average=on_average, on_progress=on_progress)
            fid = self.store.save_frf(
                frf, setup_id, name=f"acquisition {acq_id}", acquisition_id=acq_id
            )
            state, message = "finished", f"FRFs stored as FRF set {fid}"
            self._set(acq_id, frf_id=fid)
            return {"acquisition_id": acq_id, "frf_id": fid}
        except DimacqError as err:
            state = "cancelled" if ctx.cancelled else "failed"
            message = str(err)
            raise
        finally:
            rig.close()
            self._set(acq_id, state=state, message=message)

    # ------------------------------------------------------------------ read and stop
    def all(self) -> list[AcquisitionInfo]:
        with self.db.session() as s:
            ids = list(s.scalars(select(m.Acquisition.id).order_by(m.Acquisition.id)))
        return [a for a in (self.get(i) for i in ids) if a is not None]

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
            row = (r.id, r.setup_id, r.config, r.state, r.message, r.job_id, r.frf_id)
        acq, setup_id, config, state, message, job_id, frf_id = row
        snap = self.jobs.snapshot(job_id) if job_id else None
        return AcquisitionInfo(
            id=acq,
            setup_id=setup_id,
            config=config,
            state=state,
            message=message,
            job_id=job_id,
            frf_id=frf_id,
            averages_accepted=sum(1 for a in avgs if a.accepted),
            averages_rejected=sum(1 for a in avgs if not a.accepted),
            averages=avgs,
            progress=snap["progress"] if snap else (1.0 if state == "finished" else 0.0),
        )

    def stop(self, acq_id: int) -> AcquisitionInfo | None:
        """Cancel a running acquisition (completed averages are kept)."""
        cur = self.get(acq_id)
        if cur is None:
            return None
        if cur.job_id and cur.state == "running":
            self.jobs.cancel(cur.job_id)
        return self.get(acq_id)
