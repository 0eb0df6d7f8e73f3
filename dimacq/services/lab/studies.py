"""Studies: the thesis's Monte Carlo sensitivity study on the cube model, run as a queued job:
whichever service sharing the database claims it first runs it, exactly once
(:mod:`dimacq.persistence.queue`)."""

from __future__ import annotations

import uuid
from dataclasses import dataclass, replace
from typing import Any

from pydantic import BaseModel, ConfigDict, Field

from dimacq.persistence import Database
from dimacq.persistence import models as m
from dimacq.persistence.queue import enqueue_job
from dimacq.services.lab.common import iso, json_safe
from dimacq.services.lab.jobs import JobContext, JobManager

__all__ = ["CubeStudyParams", "StoredStudy", "StudyService"]


class CubeStudyParams(BaseModel):
    """The cube study (:func:`dimacq.pipeline.sensitivity.cube_study`): half the cube's edge,
    how many triaxes are rotated, the largest rotation, Monte Carlo trials and the seed."""

    model_config = ConfigDict(extra="forbid")

    half_size_m: float = Field(ge=1e-3, le=1000, allow_inf_nan=False)
    sensors: int = Field(default=1, ge=1, le=8)
    max_angle_deg: float = Field(ge=1e-6, le=90, allow_inf_nan=False)
    trials: int = Field(default=500, ge=1, le=10_000)
    seed: int = Field(default=0, ge=0, le=2**32 - 1)


@dataclass(frozen=True)
class StoredStudy:
    """A study: its parameters and, once its job finished, its result."""

    id: int
    params: dict[str, Any]
    result: dict[str, Any] | None
    job_id: str | None = None  # given when it is created
    created_at: str | None = None  # ISO 8601, UTC


class StudyService:
    def __init__(self, db: Database, jobs: JobManager, stand: str = "") -> None:
        self.db = db
        self.jobs = jobs
        self.stand = stand
        jobs.handlers["sensitivity"] = self._job

    def start_sensitivity(self, params: CubeStudyParams) -> StoredStudy:
        """A sensitivity study (thesis cube model) as a queued job; returns the study and job
        ids. This service claims it at once if it has room; otherwise another one does."""
        with self.db.session() as s:
            row = m.SensitivityStudy(params=params.model_dump())
            s.add(row)
            s.flush()
            sid = int(row.id)
        job_id = uuid.uuid4().hex[:12]
        enqueue_job(
            self.db,
            job_id,
            "sensitivity",
            {**params.model_dump(), "study_id": sid},
            created_by=self.stand,
        )
        self.jobs.claim_queued()
        got = self.sensitivity(sid)
        assert got is not None
        return replace(got, job_id=job_id)

    def _job(self, doc: dict[str, Any]) -> Any:
        """The job function of a claimed study (its parameters from the queue)."""
        from dimacq.pipeline.sensitivity import cube_study

        sid = int(doc["study_id"])
        params = CubeStudyParams.model_validate({k: v for k, v in doc.items() if k != "study_id"})

        def work(ctx: JobContext) -> dict[str, Any]:
            ctx.progress(0.0, "running Monte Carlo trials")
            res = cube_study(
                params.half_size_m,
                n_sensors=params.sensors,
                max_angle_deg=params.max_angle_deg,
                n_trials=params.trials,
                seed=params.seed,
            )
            with self.db.session() as s2:
                r = s2.get(m.SensitivityStudy, sid)
                assert r is not None
                r.result = json_safe(res.to_json())
            return {"study_id": sid, "stand": self.stand}

        return work

    def sensitivity(self, study_id: int) -> StoredStudy | None:
        with self.db.session() as s:
            r = s.get(m.SensitivityStudy, study_id)
            if r is None:
                return None
            return StoredStudy(r.id, r.params, r.result, created_at=iso(r.created_at))
