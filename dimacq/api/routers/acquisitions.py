"""Acquisitions: configure, start, stop, progress, averages accepted and rejected, delete."""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, Path, Request, Response, status

from dimacq.api.deps import IdPath, LabDep
from dimacq.api.routers._common import (
    LIST_RESPONSES,
    PageDep,
    body_openapi,
    deleted,
    found,
    json_object,
    paged,
    parse_strict,
    strict_body,
)
from dimacq.api.schemas import (
    AcquisitionOut,
    AcquisitionPatch,
    AcquisitionRequest,
    AverageDataOut,
    HitDecision,
    HitOut,
)
from dimacq.services.lab.acquisitions import AcquisitionInfo

router = APIRouter(prefix="/api/acquisitions", tags=["acquisitions"])


@router.post(
    "",
    response_model=AcquisitionOut,
    status_code=status.HTTP_202_ACCEPTED,
    openapi_extra=body_openapi(AcquisitionRequest),
)
def start_acquisition(
    lab: LabDep, body: Annotated[AcquisitionRequest, strict_body(AcquisitionRequest)]
) -> AcquisitionInfo:
    """Configure and start an impact acquisition (a job, ``job_id``); FRFs are stored when it
    succeeds (``frf_id``). The settings are checked here (422 naming the field), before
    anything starts."""
    return lab.acquisitions.start(body.model_dump())


@router.get("", response_model=list[AcquisitionOut], responses=LIST_RESPONSES)
def list_acquisitions(lab: LabDep, page: PageDep, response: Response) -> list[AcquisitionInfo]:
    return paged(response, lab.acquisitions.all(page.limit, page.offset), page)


@router.get("/{acq_id:id}", response_model=AcquisitionOut)
def get_acquisition(acq_id: IdPath, lab: LabDep) -> AcquisitionInfo:
    """State, progress and the averages accepted and rejected so far."""
    return found(lab.acquisitions.get(acq_id), f"acquisition {acq_id}")


@router.patch(
    "/{acq_id:id}", response_model=AcquisitionOut, openapi_extra=body_openapi(AcquisitionPatch)
)
async def patch_acquisition(acq_id: IdPath, lab: LabDep, request: Request) -> AcquisitionInfo:
    """Change a running acquisition: ``review`` switches "review every hit" (false: the checks
    decide from now on, the hit waiting too); 409 when it is not running on this stand. A
    malformed body is 422, then an unknown acquisition 404."""
    from starlette.concurrency import run_in_threadpool

    raw = await request.body()
    json_object(raw, '{"review": false}')
    found(await run_in_threadpool(lab.acquisitions.get, acq_id), f"acquisition {acq_id}")
    body = parse_strict(AcquisitionPatch, raw)
    return found(
        await run_in_threadpool(lab.acquisitions.set_review, acq_id, body.review),
        f"acquisition {acq_id}",
    )


@router.delete("/{acq_id:id}", status_code=status.HTTP_204_NO_CONTENT)
def delete_acquisition(acq_id: IdPath, lab: LabDep) -> Response:
    """Delete an acquisition that is not running and its raw averages (its FRF set stays);
    409 while it runs."""
    return deleted(lab.acquisitions.delete(acq_id), f"acquisition {acq_id}")


@router.post("/{acq_id:id}/stop", response_model=AcquisitionOut)
def stop_acquisition(acq_id: IdPath, lab: LabDep) -> AcquisitionInfo:
    """Cancel: the averages completed so far are kept in the record, no FRF set is stored
    (``finish`` stops striking and stores the FRFs of the accepted averages)."""
    return found(lab.acquisitions.stop(acq_id), f"acquisition {acq_id}")


@router.post(
    "/{acq_id:id}/review", response_model=AcquisitionOut, openapi_extra=body_openapi(HitDecision)
)
async def review_hit(acq_id: IdPath, lab: LabDep, request: Request) -> AcquisitionInfo:
    """The operator's accept / reject / redo of the hit waiting for review (``pending_review``
    of an acquisition reviewing its hits); 409 when that hit is not the one waiting, or when an
    accept is refused by the checks (the message names them: ``override: true`` accepts a double
    hit, an overload or a clock drift anyway; a hit with samples lost is never accepted).
    A malformed body is 422, then an unknown acquisition 404, then a bad decision 422."""
    from starlette.concurrency import run_in_threadpool

    raw = await request.body()
    json_object(raw, '{"number": 1, "decision": "accept"}')
    found(await run_in_threadpool(lab.acquisitions.get, acq_id), f"acquisition {acq_id}")
    body = parse_strict(HitDecision, raw)
    return await run_in_threadpool(_decide, lab, acq_id, body)


def _decide(lab: Any, acq_id: int, body: HitDecision) -> AcquisitionInfo:
    return found(
        lab.acquisitions.decide(acq_id, body.number, body.decision, body.override),
        f"acquisition {acq_id}",
    )


@router.post("/{acq_id:id}/finish", response_model=AcquisitionOut)
def finish_acquisition(acq_id: IdPath, lab: LabDep) -> AcquisitionInfo:
    """Stop striking and keep the accepted averages: the FRFs of the inputs that reached
    ``min_averages`` are stored (``stop`` cancels instead: no FRF set). On an acquisition
    ``interrupted`` (the service stopped during it), ``cancelled`` or ``failed`` without FRFs:
    the FRFs of its complete inputs are estimated from the raw averages kept on disk, as the
    live run would; state ``succeeded`` if every input is complete, else ``incomplete`` with
    the missing inputs named (``resume`` strikes them). 409 otherwise."""
    return found(lab.acquisitions.finish(acq_id), f"acquisition {acq_id}")


@router.post(
    "/{acq_id:id}/resume", response_model=AcquisitionOut, status_code=status.HTTP_202_ACCEPTED
)
def resume_acquisition(acq_id: IdPath, lab: LabDep) -> AcquisitionInfo:
    """A new acquisition (202; a job) that strikes only what an interrupted, cancelled, failed
    or incomplete one is missing, the missing averages of a partly struck input included, and
    ends with an FRF set of every input (the kept and the new averages together, merged into
    the ended one's FRF set). The ended one becomes ``resumed``. 409 when it is not resumable,
    nothing is missing or the devices are in use."""
    return found(lab.acquisitions.resume(acq_id), f"acquisition {acq_id}")


@router.get("/{acq_id:id}/hit", response_model=HitOut)
def get_hit(acq_id: IdPath, lab: LabDep) -> dict[str, Any]:
    """The hit waiting for review (``pending: true``), else the last decided one (this service's
    run only): force (N) and strongest response (m/s²) over time, their spectra in dB, the
    checks' reasons."""
    return found(lab.acquisitions.hit(acq_id), f"hit of acquisition {acq_id}")


@router.get("/{acq_id:id}/averages/{number:id}", response_model=AverageDataOut)
def get_average(
    acq_id: IdPath, number: Annotated[int, Path(ge=-(2**31), le=2**31 - 1)], lab: LabDep
) -> dict[str, Any]:
    """Raw time data of one average, served by the stand that acquired it (it stays on that
    stand's disk); another stand answers 409 with that stand's address."""
    return found(
        lab.acquisitions.average_data(acq_id, number), f"average {number} of acquisition {acq_id}"
    )
