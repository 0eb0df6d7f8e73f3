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
``lab.calibrations``      :class:`~dimacq.services.lab.calibrations.CalibrationService`:
                          documents, and calibration runs as jobs (``.runs``)
``lab.plans``             :class:`~dimacq.services.lab.plans.PlanService`: pre-test plans (jobs)
``lab.photos``            :class:`~dimacq.services.lab.photo_jobs.PhotoGeometryService`: photo
                          folders, geometry from photographs (jobs)
``lab.studies``           :class:`~dimacq.services.lab.studies.StudyService`: sensitivity
``lab.rig_map``           :class:`~dimacq.services.lab.rig_map.RigMapService`: the rig file
                          (channel map, sensitivities): read, check, replace
``lab.jobs``              :class:`~dimacq.services.lab.jobs.JobManager`
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

import logging
import os
import shutil
import sys
import tempfile
import time
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from dimacq.config import Settings
from dimacq.errors import DatabaseUnavailableError, DimacqError
from dimacq.persistence import ArrayStore, Database, open_database
from dimacq.persistence import stands as stand_lease
from dimacq.persistence.queue import DbJobStore, Outbox
from dimacq.services.lab.acquisitions import AcquisitionService, RawBlocks, RigFactory
from dimacq.services.lab.calibrations import CalibrationService
from dimacq.services.lab.common import package_version
from dimacq.services.lab.devices import DeviceService
from dimacq.services.lab.geometry import GeometryService
from dimacq.services.lab.jobs import JobManager, Ticker
from dimacq.services.lab.lab_tests import LabTestService
from dimacq.services.lab.photo_jobs import PhotoGeometryService
from dimacq.services.lab.plans import PlanService
from dimacq.services.lab.rig_map import RigMapService
from dimacq.services.lab.solving import AnalysisService
from dimacq.services.lab.store import TestStore
from dimacq.services.lab.studies import StudyService

__all__ = ["Lab", "LabStatus"]

log = logging.getLogger(__name__)


def confine_files(data_dir: Path) -> Path:
    """Keep the service's own files under ``data_dir``: temporary files (upload spools, UFF
    reads) in ``<data_dir>/tmp/<pid>``, this process's own folder, and matplotlib's
    configuration and font cache in ``<data_dir>/cache/matplotlib`` (set before matplotlib is
    first imported: a process that imported it already keeps its folder). Returns the
    temporary folder.

    Several processes may share one data folder (the demo's chain check runs a second service
    on it): each empties only what no live process owns — the folders of processes that have
    ended (a spool left by a killed service goes) and loose files of older versions — never
    another running service's spool."""
    root = data_dir / "tmp"
    root.mkdir(mode=0o700, parents=True, exist_ok=True)
    for entry in root.iterdir():
        if entry.name.isdigit() and entry.is_dir() and _alive(int(entry.name)):
            continue
        if entry.is_dir() and not entry.is_symlink():
            shutil.rmtree(entry, ignore_errors=True)
        else:
            entry.unlink(missing_ok=True)
    spool = root / str(os.getpid())
    shutil.rmtree(spool, ignore_errors=True)  # a reused pid's leftovers
    spool.mkdir(mode=0o700)
    tempfile.tempdir = str(spool)
    mpl = data_dir / "cache" / "matplotlib"
    mpl.mkdir(mode=0o700, parents=True, exist_ok=True)
    if "matplotlib" not in sys.modules:
        os.environ["MPLCONFIGDIR"] = str(mpl)
    return spool


def _alive(pid: int) -> bool:
    """Whether process ``pid`` runs (signal 0: the check, no signal sent)."""
    if pid == os.getpid():
        return False  # this process's old folder (a second Lab in it): emptied anew
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True  # another user's process
    except OSError:
        return False
    return True


@dataclass(frozen=True)
class LabStatus:
    """Cheap in-memory status: version, stand, the database's health, uptime, each device's
    state, running jobs."""

    service: str
    version: str
    schema_version: int
    uptime_s: float
    devices: dict[str, dict[str, Any]]
    jobs_running: list[dict[str, Any]]
    stand: str = ""
    database: dict[str, Any] | None = None

    def to_json(self) -> dict[str, Any]:
        return {
            "service": self.service,
            "version": self.version,
            "schema_version": self.schema_version,
            "stand": self.stand,
            "database": self.database or {},
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
        Builds the acquisition rig (:class:`dimacq.services.acquisition.rig.Rig`); default
        :func:`dimacq.services.acquisition.rig.build_rig` on the configured device backends.
    raw_blocks : callable (acquisition id) -> Path or None, optional
        Where each acquisition keeps its raw blocks (:class:`AcquisitionService`); default none.
    """

    def __init__(
        self,
        settings: Settings,
        *,
        open_devices: bool = True,
        rig_factory: RigFactory | None = None,
        raw_blocks: RawBlocks | None = None,
    ) -> None:
        self.settings = settings
        settings.check_data_dir()
        self._spool = confine_files(settings.data_dir)
        self.db: Database = open_database(
            settings.db_url, timeout_s=min(20.0, settings.database_retry_s)
        )
        self.arrays = ArrayStore(settings.data_dir / "arrays")
        # one service per stand on a shared database (refused while another one is alive)
        self.stand = stand_lease.StandIdentity(
            settings.stand_name, api_url=f"http://{settings.host}:{settings.port}"
        )
        stand_lease.claim_stand(self.db, self.stand)
        self.outbox = Outbox()  # database writes waiting for the database (data kept locally)
        self.job_store = DbJobStore(self.db, self.stand.name, self.stand.instance)
        self.jobs = JobManager(store=self.job_store)
        name = self.stand.name
        self.started_monotonic = time.monotonic()
        self.version = package_version()
        self.devices = DeviceService(settings, lambda driver: self.geometry.open_session(driver))
        self.geometry = GeometryService(self.db, self.devices)
        self.store = TestStore(self.db, self.arrays, name)
        self.tests = LabTestService(self.db, name)
        self.analysis = AnalysisService(self.store)
        self.acquisitions = AcquisitionService(
            settings,
            self.db,
            self.arrays,
            self.jobs,
            self.devices,
            self.store,
            rig_factory,
            stand=name,
            outbox=self.outbox,
            raw_blocks=raw_blocks,
        )
        self.calibrations = CalibrationService(
            self.db, name, jobs=self.jobs, settings=settings, owners=self.devices.owners
        )
        self.studies = StudyService(self.db, self.jobs, name)
        self.plans = PlanService(self.jobs)
        self.photos = PhotoGeometryService(
            self.jobs, self.geometry, self.store, settings.data_dir / "photos"
        )
        self.rig_map = RigMapService(
            settings, self._daq_inputs, self._reopen_rig_devices if open_devices else lambda: None
        )
        self.job_store.interrupt_stale()  # this stand's jobs that ran when it stopped
        self.acquisitions.recover()
        self.ticker = Ticker(f"dimacq-ticker-{name}")
        self.ticker.add("queued jobs", 0.5, self.jobs.claim_queued)
        self.ticker.add("waiting writes", 1.0, lambda: self.outbox.flush(self.db))
        self.ticker.add("stand heartbeat", 5.0, self._heartbeat)
        self.ticker.start()
        if open_devices:
            self.devices.connect_all()

    def _daq_inputs(self) -> int | None:
        """The DAQ's number of analogue inputs, as it told when last opened (None: not opened,
        or a DAQ whose identity does not say)."""
        info = self.devices.get("daq")
        n = info.identity.get("n_channels") if info is not None and info.connected else None
        return n if isinstance(n, int) and not isinstance(n, bool) and n > 0 else None

    def _reopen_rig_devices(self) -> None:
        """Open the DAQ and the load cells again with the rig file just written (each outcome in
        the device list: a cell a bad file left disconnected is connected again once the file
        is right). A device a job holds keeps its state; the job's next build reads the file."""
        for name in ("daq", "loadcell"):
            try:
                self.devices.connect(name)
            except DimacqError as err:
                log.info("rig file written: %s not reopened: %s", name, err)

    def close(self) -> None:
        """Cancel jobs, close devices, give the stand up, close the database."""
        self.ticker.stop()
        self.jobs.shutdown()
        self.devices.disconnect_all()
        if tempfile.tempdir == str(self._spool):
            tempfile.tempdir = None  # back to the environment's choice
        try:
            self.outbox.flush(self.db)
            stand_lease.release_stand(self.db, self.stand)
        except DatabaseUnavailableError as err:
            log.warning(
                "closing with the database unreachable (%s): %d writes not stored; "
                "their files are re-registered at the next start",
                err,
                len(self.outbox),
            )
        self.db.close()

    def _heartbeat(self) -> None:
        if not stand_lease.heartbeat(self.db, self.stand):
            log.error(
                "stand %s has been taken over by another service; this one should be stopped",
                self.stand.name,
            )

    def stands(self) -> list[dict[str, Any]]:
        """The stands sharing this database (name, host, API address, last heartbeat)."""
        return stand_lease.stands(self.db)

    def status(self) -> LabStatus:
        """Cheap in-memory status (no I/O): devices, running jobs, uptime.

        Each device's state is what the code using it last saw (:meth:`DeviceService.mark`),
        never a probe made for the status: ``connected`` false with ``error`` saying why from
        the moment the acquisition sees the DAQ gone (a re-enumeration at its next read, a DAQ
        that stopped answering after three reads timed out: 3 × the rig's USB ``timeout_s``) or
        the digitizing session a lost port, until it is found again; ``since`` is when that
        state began. A device nobody uses is not looked at: its state is the last one seen (at
        start, its last use, or ``POST /api/devices/{name}/connect``).
        """
        return LabStatus(
            service="dimacq",
            version=self.version,
            schema_version=self.db.schema_version,
            stand=self.stand.name,
            database={
                "backend": self.db.backend,
                **self.db.health.as_dict(),
                "writes_waiting": len(self.outbox),
            },
            uptime_s=time.monotonic() - self.started_monotonic,
            devices={
                d.name: {
                    "connected": d.connected and not d.lost,
                    "simulated": d.simulated,
                    "error": d.lost or d.error,
                    "since": datetime.fromtimestamp(d.since, UTC).isoformat(),
                }
                for d in self.devices.all()
            },
            jobs_running=[
                {"id": j.id, "kind": j.kind, "progress": j.progress, "message": j.message}
                for j in self.jobs.running()
            ],
        )
