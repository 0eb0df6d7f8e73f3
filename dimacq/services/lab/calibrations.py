"""Load cell calibrations: JSON documents (:mod:`dimacq.io.loadcell_calibration`) in the
database, and calibration runs as jobs (:attr:`CalibrationService.runs`,
:class:`~dimacq.services.calibration.loadcell_calibration.CalibrationRuns`: static or inertial, simulated or
on the configured rig with the operator's prompts answered over the API)."""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

from sqlalchemy import select

from dimacq.io.loadcell_calibration import parse_calibration_json
from dimacq.persistence import Database
from dimacq.persistence import models as m
from dimacq.services.lab.common import iso

__all__ = ["CalibrationService", "StoredCalibration"]


@dataclass(frozen=True)
class StoredCalibration:
    """A stored calibration: its id, the cell's serial number and the normalised document."""

    id: int
    serial_number: str
    calibration: dict[str, Any]
    created_at: str | None = None  # ISO 8601, UTC (a calibration is never changed)

    @classmethod
    def of(cls, r: m.Calibration) -> StoredCalibration:
        return cls(
            id=r.id, serial_number=r.serial, calibration=r.body, created_at=iso(r.created_at)
        )


class CalibrationService:
    def __init__(
        self,
        db: Database,
        stand: str = "",
        *,
        jobs: Any = None,
        settings: Any = None,
        owners: Any = None,
    ) -> None:
        self.db = db
        self.stand = stand
        self.runs: Any = None
        if jobs is not None and settings is not None:
            from dimacq.services.lab.calibration_runs import CalibrationRuns

            self.runs = CalibrationRuns(
                jobs, settings, lambda doc: asdict(self.save(doc)), owners=owners
            )

    def save(self, document: Any) -> StoredCalibration:
        """Validate a calibration document (schema_version 1) and store it normalised (SI)."""
        cal = parse_calibration_json(document, "calibration")
        with self.db.session() as s:
            row = m.Calibration(serial=cal.serial_number, body=cal.to_json(), stand=self.stand)
            s.add(row)
            s.flush()
            return StoredCalibration.of(row)

    def all(self) -> list[StoredCalibration]:
        with self.db.session() as s:
            return [
                StoredCalibration.of(r)
                for r in s.scalars(select(m.Calibration).order_by(m.Calibration.id))
            ]

    def get(self, cal_id: int) -> StoredCalibration | None:
        with self.db.session() as s:
            r = s.get(m.Calibration, cal_id)
            return None if r is None else StoredCalibration.of(r)
