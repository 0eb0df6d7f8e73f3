"""DIM solutions: solve (options), list, result, delete, diagnostics, figures."""

from __future__ import annotations

from typing import Annotated, Any, Literal

from fastapi import APIRouter, Header, Query, Response, status

from dimacq.api.deps import CANONICAL_INT, IdPath, LabDep
from dimacq.api.routers._common import (
    LIST_RESPONSES,
    PageDep,
    body_openapi,
    deleted,
    found,
    paged,
    strict_body,
)
from dimacq.api.schemas import (
    MAX_ID,
    DiagnosticOut,
    SolutionOut,
    SolutionSpectrumOut,
    SolveRequest,
)
from dimacq.services.lab.solving import SolveOptions
from dimacq.services.lab.store import StoredSolution

router = APIRouter(prefix="/api/solutions", tags=["solutions"])


@router.post(
    "",
    response_model=SolutionOut,
    status_code=status.HTTP_201_CREATED,
    openapi_extra=body_openapi(SolveRequest),
)
def solve(
    lab: LabDep,
    body: Annotated[SolveRequest, strict_body(SolveRequest)],
    idempotency_key: Annotated[
        str | None,
        Header(
            alias="Idempotency-Key",
            min_length=1,
            max_length=200,
            pattern=r"^[\x21-\x7e]+$",
            description="the client's key for this request: sent again with the same body, the "
            "solution it stored comes back (nothing solved twice)",
        ),
    ] = None,
) -> StoredSolution:
    """Solve mass, CG and inertia from an FRF set; the result has the keys of ``dimacq solve
    --json``. The options are those of ``dimacq solve``: ``band_hz`` (``--band``), ``known``
    (``--known-*``, the ten parameter names), ``reference_point_m`` (``--reference-point``),
    ``length_unit`` (``--length-unit``), ``scale_to_mass_kg`` (``--scale-to-mass``), ``method``,
    the selections (``--no-select*``) and the estimators.

    One solution per request: an identical solve while one runs answers 409 naming it; a
    request sent again with the same ``Idempotency-Key`` gets the solution it stored."""
    options = SolveOptions.model_validate(body.model_dump(exclude={"frf_id"}))
    return found(
        lab.analysis.solve(body.frf_id, options, idempotency_key), f"FRF set {body.frf_id}"
    )


@router.get("", response_model=list[SolutionOut], responses=LIST_RESPONSES)
def list_solutions(
    lab: LabDep,
    page: PageDep,
    response: Response,
    frf_id: Annotated[
        int | None, CANONICAL_INT, Query(ge=1, le=MAX_ID, description="of this FRF set only")
    ] = None,
    test_id: Annotated[
        int | None,
        CANONICAL_INT,
        Query(ge=1, le=MAX_ID, description="of the FRF sets of this test only"),
    ] = None,
) -> list[StoredSolution]:
    return paged(response, lab.store.solutions(page.limit, page.offset, frf_id, test_id), page)


@router.get("/{solution_id:id}", response_model=SolutionOut)
def get_solution(solution_id: IdPath, lab: LabDep) -> StoredSolution:
    return found(lab.store.solution(solution_id), f"solution {solution_id}")


@router.delete("/{solution_id:id}", status_code=status.HTTP_204_NO_CONTENT)
def delete_solution(solution_id: IdPath, lab: LabDep) -> Response:
    return deleted(lab.store.delete_solution(solution_id), f"solution {solution_id}")


@router.get(
    "/{solution_id:id}/diagnostics", response_model=list[DiagnosticOut], responses=LIST_RESPONSES
)
def diagnostics(
    solution_id: IdPath, lab: LabDep, page: PageDep, response: Response
) -> list[dict[str, Any]]:
    """The plausibility and quality checks of the solution."""
    sol = found(lab.store.solution(solution_id), f"solution {solution_id}")
    return paged(response, list(sol.result.get("diagnostics", [])), page)


PARAMETERS = ["m", "cx", "cy", "cz", "Ixx", "Ixy", "Ixz", "Iyy", "Iyz", "Izz"]
UNITS = ["kg", "m", "m", "m", "kg m^2", "kg m^2", "kg m^2", "kg m^2", "kg m^2", "kg m^2"]


@router.get("/{solution_id:id}/spectrum", response_model=SolutionSpectrumOut)
def spectrum(solution_id: IdPath, lab: LabDep) -> dict[str, Any]:
    """The parameters against frequency behind a stored solution: ``per_line`` (n_lines × 10,
    layout ``parameters``, units ``units``; inertia about the reference point, CG in the GCS) over
    every line of its FRF set, from the channels and inputs the solution used; ``band_hz`` and
    ``headline`` (the stored estimate, same layout)."""
    from dimacq.services.lab.common import json_safe

    spec = found(lab.analysis.solution_spectrum(solution_id), f"solution {solution_id}")
    return {
        "solution_id": solution_id,
        "parameters": PARAMETERS,
        "units": UNITS,
        "frequencies_hz": json_safe(spec.frequencies_hz),
        "per_line": json_safe(spec.per_line),
        "band_hz": list(spec.band_hz),
        "headline": json_safe(spec.headline),
    }


@router.get(
    "/{solution_id:id}/figure",
    response_class=Response,
    responses={200: {"content": {"image/png": {}, "image/svg+xml": {}}}},
)
def figure(solution_id: IdPath, lab: LabDep, format: Literal["png", "svg"] = "png") -> Response:
    """Parameters against frequency with the band (thesis Fig. 25)."""
    data = found(lab.analysis.solution_figure(solution_id, format), f"solution {solution_id}")
    return Response(content=data, media_type="image/png" if format == "png" else "image/svg+xml")
