"""The lab: a thin object composing one small service per resource.

:class:`Lab` opens the database and the array files, starts the job manager and composes the
services the REST API (and anything else) drives:

========================  ===================================================================
``lab.devices``           :class:`~dimacq.services.lab.devices.DeviceService`: digitizer, DAQ,
                          load cells (state, connect, identify)
``lab.geometry``          :class:`~dimacq.services.lab.geometry.GeometryService`: digitized
                          points, patches, registration, orientations, lines of action, a setup
                          from that geometry
``lab.store``             :class:`~dimacq.services.lab.store.TestStore`: setups, FRF sets,
                          solutions (import/export)
``lab.analysis``          :class:`~dimacq.services.lab.solving.AnalysisService`: solve, the
                          figure of a stored solution
``lab.acquisitions``      :class:`~dimacq.services.lab.acquisitions.AcquisitionService`: impact
                          tests as jobs, every average kept
``lab.calibrations``      :class:`~dimacq.services.lab.calibrations.CalibrationService`
``lab.studies``           :class:`~dimacq.services.lab.studies.StudyService`: sensitivity
``lab.jobs``              :class:`~dimacq.services.jobs.JobManager`
========================  ===================================================================

The chain of a DIM test: digitize points and register each array position (geometry), orient
each triax and take each input's line of action (geometry), build the setup from that geometry
or import one (store), acquire (acquisitions) or import FRFs (store), solve (analysis).

Every result is stored as soon as it exists; services return dataclasses (or pydantic models)
and take inputs already validated where they came in (the API's request schemas). No HTTP here;
errors are :mod:`dimacq.errors` exceptions naming the item and the fix. Lookups of unknown ids
return ``None`` (the API's 404).
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

from sqlalchemy import select

from dimacq.config import Settings
from dimacq.persistence import ArrayStore, Database, open_database
from dimacq.persistence import models as m
from dimacq.services.jobs import FINAL_STATES, JobManager
from dimacq.services.lab.acquisitions import AcquisitionService, RigFactory
from dimacq.services.lab.calibrations import CalibrationService
from dimacq.services.lab.common import package_version
from dimacq.services.lab.devices import DeviceService
from dimacq.services.lab.geometry import GeometryService
from dimacq.services.lab.solving import AnalysisService
from dimacq.services.lab.store import TestStore
from dimacq.services.lab.studies import StudyService

__all__ = ["Lab", "LabStatus"]


@dataclass(frozen=True)
class LabStatus:
    """Cheap in-memory status: version, uptime, each device's state, running jobs."""

    service: str
    version: str
    schema_version: int
    uptime_s: float
    devices: dict[str, dict[str, Any]]
    jobs_running: list[dict[str, Any]]

    def to_json(self) -> dict[str, Any]:
        return {
            "service": self.service,
            "version": self.version,
            "schema_version": self.schema_version,
            "uptime_s": self.uptime_s,
            "devices": self.devices,
            "jobs_running": self.jobs_running,
        }


class Lab:
    """The lab: configuration, database, array files, jobs, and the services over them.

    Parameters
    ----------
    settings : Settings
    open_devices : bool
        Open the configured devices now (:meth:`DeviceService.connect_all`); failures are
        recorded in the device list, not raised, so the service starts without hardware.
    rig_factory : callable (settings, setup, config) -> Rig, optional
        Builds the acquisition rig (:class:`dimacq.services.rig.Rig`); default
        :func:`dimacq.services.rig.build_rig` on the configured device backends.
    """

    def __init__(
        self,
        settings: Settings,
        *,
        open_devices: bool = True,
        rig_factory: RigFactory | None = None,
    ) -> None:
        self.settings = settings
        settings.data_dir.mkdir(parents=True, exist_ok=True)
        self.db: Database = open_database(settings.db_url)
        self.arrays = ArrayStore(settings.data_dir / "arrays")
        self.jobs = JobManager(persist=self._persist_job)
        self.started_monotonic = time.monotonic()
        self.version = package_version()
        self.devices = DeviceService(settings, lambda driver: self.geometry.open_session(driver))
        self.geometry = GeometryService(self.db, self.devices)
        self.store = TestStore(self.db, self.arrays)
        self.analysis = AnalysisService(self.store)
        self.acquisitions = AcquisitionService(
            settings, self.db, self.arrays, self.jobs, self.devices, self.store, rig_factory
        )
        self.calibrations = CalibrationService(self.db)
        self.studies = StudyService(self.db, self.jobs)
        self._recover_jobs()
        self.acquisitions.recover()
        if open_devices:
            self.devices.connect_all()

    def close(self) -> None:
        """Cancel jobs, close devices and the database."""
        self.jobs.shutdown()
        self.devices.disconnect_all()
        self.db.close()

    def status(self) -> LabStatus:
        """Cheap in-memory status (no I/O): devices, running jobs, uptime."""
        return LabStatus(
            service="dimacq",
            version=self.version,
            schema_version=self.db.schema_version,
            uptime_s=time.monotonic() - self.started_monotonic,
            devices={
                d.name: {"connected": d.connected, "error": d.error} for d in self.devices.all()
            },
            jobs_running=[
                {"id": j.id, "kind": j.kind, "progress": j.progress, "message": j.message}
                for j in self.jobs.running()
            ],
        )

    # ------------------------------------------------------------------ jobs in the database
    def _recover_jobs(self) -> None:
        """After a restart: jobs that were running are interrupted; every job is listed again."""
        with self.db.session() as s:
            for row in s.scalars(select(m.JobRow)):
                if row.state not in FINAL_STATES:
                    row.state = "interrupted"
                    row.message = "the service stopped while this job ran; completed work is kept"
                    row.finished_at = m.utcnow()
                self.jobs.adopt(
                    {
                        "id": row.id,
                        "kind": row.kind,
                        "state": row.state,
                        "progress": row.progress,
                        "message": row.message,
                        "result": row.result,
                        "error": row.error,
                        "created_at": row.created_at,
                        "finished_at": row.finished_at,
                    }
                )

    def _persist_job(self, snap: dict[str, Any]) -> None:
        with self.db.session() as s:
            row = s.get(m.JobRow, snap["id"])
            if row is None:
                row = m.JobRow(id=snap["id"], kind=snap["kind"], state=snap["state"])
                s.add(row)
            row.state = snap["state"]
            row.progress = float(snap["progress"])
            row.message = snap["message"]
            row.result = snap["result"]
            row.error = snap["error"]
            if snap["finished_at"]:
                row.finished_at = m.utcnow()
