"""Plans: ``dimacq plan`` as a job of the lab service (``POST /api/plans``): the choice of triaxes
and inputs from a candidate setup, the predicted 95 % bounds and, with ``trials``, the Monte Carlo
of default solves, with progress (solves done) and cancel between solves. The trials run in the
job's thread (in-process); the command line's ``--scheduler`` spreads them over a Dask cluster.
The result is the JSON of ``dimacq plan --json`` (:func:`dimacq.services.solve.planning.make_plan`)."""

from __future__ import annotations

from typing import Annotated, Any, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from dimacq.errors import SetupError
from dimacq.io.setup_file import parse_setup
from dimacq.model.properties import RigidBodyProperties
from dimacq.services.lab.jobs import Job, JobContext, JobManager

__all__ = ["ExpectedProperties", "PlanParams", "PlanService"]

Coord = Annotated[float, Field(ge=-1e4, le=1e4, allow_inf_nan=False)]
Inertia = Annotated[float, Field(ge=-1e12, le=1e12, allow_inf_nan=False)]
InertiaRow = tuple[Inertia, Inertia, Inertia]


class ExpectedProperties(BaseModel):
    """The expected properties (the keys of a truth file): mass (kg), CG in the GCS (m), inertia
    tensor about the CG (tensor elements, kg·m²)."""

    model_config = ConfigDict(extra="forbid")

    mass_kg: float = Field(ge=1e-6, le=1e9, allow_inf_nan=False)
    cg_m: tuple[Coord, Coord, Coord]
    inertia_cg_kgm2: tuple[InertiaRow, InertiaRow, InertiaRow]


class PlanParams(BaseModel):
    """A plan: the candidate setup (setup-file keys: ``responses``, ``inputs``, optional
    ``geometry_uncertainty``, ``transducer_uncertainty``), the expected properties, how many
    triaxes and inputs to choose, Monte Carlo solves, seed and FRF noise."""

    model_config = ConfigDict(extra="forbid")

    setup: dict[str, Any] = Field(description="the candidate setup, as a setup file's keys")
    properties: ExpectedProperties
    triaxes: int = Field(ge=1, le=500)
    inputs: int = Field(ge=1, le=1000)
    trials: int = Field(default=0, ge=0, le=200)
    seed: int = Field(default=0, ge=0, le=2**32 - 1)
    noise: float = Field(default=0.01, ge=1e-6, le=1, allow_inf_nan=False)
    noise_model: Literal["channel", "relative"] = "channel"


class PlanService:
    def __init__(self, jobs: JobManager) -> None:
        self.jobs = jobs

    def start(self, params: PlanParams) -> Job:
        """Check the request (setup, properties, counts) and start the plan as a job."""
        setup = parse_setup(params.setup, "setup")
        p = params.properties
        inertia = np.asarray(p.inertia_cg_kgm2, float)
        props = RigidBodyProperties(p.mass_kg, np.asarray(p.cg_m, float), inertia)
        with np.errstate(all="ignore"):
            lam = np.linalg.eigvalsh(props.inertia_cg_kgm2)
        if not lam.min() > 0:
            raise SetupError(
                "properties.inertia_cg_kgm2: not positive definite; give the tensor about the CG "
                "(tensor elements, Ixy = −∫xy dm)"
            )
        nodes = {c.node for c in setup.responses}
        if params.triaxes > len(nodes):
            raise SetupError(
                f"triaxes {params.triaxes}: the setup has {len(nodes)} response nodes; give at "
                "most that"
            )
        if params.inputs > len(setup.excitations):
            raise SetupError(
                f"inputs {params.inputs}: the setup has {len(setup.excitations)} inputs; give at "
                "most that"
            )

        def work(ctx: JobContext) -> dict[str, Any]:
            from dimacq.services.solve.planning import make_plan

            ctx.progress(0.0, "choosing the layout")

            def progress(done: int, total: int, _left: float) -> None:
                ctx.check_cancelled()
                ctx.progress(done / total, f"{done}/{total} solves")

            return make_plan(
                setup,
                props,
                params.triaxes,
                params.inputs,
                noise=params.noise,
                noise_model=params.noise_model,
                trials=params.trials,
                seed=params.seed,
                scheduler="none",
                progress=progress,
            )

        return self.jobs.submit("plan", work)
