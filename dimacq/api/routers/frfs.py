"""FRF sets: list, read, values by node and direction over a band, delete, import (UFF), export
(UFF)."""

from __future__ import annotations

from collections import Counter
from dataclasses import asdict, dataclass
from typing import Annotated, Any

from fastapi import APIRouter, Depends, Query, Request, Response, status
from fastapi.exceptions import RequestValidationError
from pydantic import Field
from starlette.concurrency import run_in_threadpool

from dimacq.api.deps import CANONICAL_INT, IdPath, LabDep, NameQuery
from dimacq.api.routers._common import (
    LIST_RESPONSES,
    RAW_BODY,
    PageDep,
    deleted,
    found,
    paged,
    read_upload,
)
from dimacq.api.schemas import MAX_ID, FrfDataOut, FrfEnvelopeOut, FrfOut
from dimacq.io.frf_binary import MEDIA_TYPE
from dimacq.services.lab.store import ChannelQuery, FrfSummary

router = APIRouter(prefix="/api/frfs", tags=["frfs"])

_Index = Annotated[int | None, CANONICAL_INT, Query(ge=0, le=MAX_ID)]
_Node = Annotated[int | None, CANONICAL_INT, Query(ge=1, le=MAX_ID)]
_Dir = Annotated[int | None, CANONICAL_INT, Query(ge=-6, le=6, description="UFF direction, ±1..±6")]
_Hz = Annotated[float | None, Query(ge=0, le=1e9)]


@dataclass(frozen=True)
class _Selection:
    """The query both value routes share: responses, the inputs' node and direction, the band."""

    responses: ChannelQuery
    input_node: int | None
    input_direction: int | None
    band_hz: tuple[float | None, float | None]

    def inputs(self, index: int | None = None, indices: tuple[int, ...] = ()) -> ChannelQuery:
        return ChannelQuery(index, self.input_node, self.input_direction, indices)


def _selection(
    response: _Index = None,
    response_node: _Node = None,
    response_direction: _Dir = None,
    input_node: _Node = None,
    input_direction: _Dir = None,
    f_min_hz: _Hz = None,
    f_max_hz: _Hz = None,
) -> _Selection:
    return _Selection(
        ChannelQuery(response, response_node, response_direction),
        input_node,
        input_direction,
        (f_min_hz, f_max_hz),
    )


SelectionDep = Annotated[_Selection, Depends(_selection)]


@router.get("", response_model=list[FrfOut], responses=LIST_RESPONSES)
def list_frfs(
    lab: LabDep,
    page: PageDep,
    response: Response,
    test_id: Annotated[
        int | None,
        CANONICAL_INT,
        Query(ge=1, le=MAX_ID, description="of the setups of this test only"),
    ] = None,
) -> list[FrfSummary]:
    return paged(response, lab.store.frfs(page.limit, page.offset, test_id), page)


@router.get("/{frf_id:id}", response_model=FrfOut)
def get_frf(frf_id: IdPath, lab: LabDep) -> FrfSummary:
    return found(lab.store.frf_summary(frf_id), f"FRF set {frf_id}")


@router.delete("/{frf_id:id}", status_code=status.HTTP_204_NO_CONTENT)
def delete_frf(frf_id: IdPath, lab: LabDep) -> Response:
    """Delete an FRF set and its solutions (the acquisition that measured it stays)."""
    return deleted(lab.store.delete_frf(frf_id), f"FRF set {frf_id}")


@router.get("/{frf_id:id}/data", response_model=FrfDataOut)
def frf_data(
    frf_id: IdPath,
    lab: LabDep,
    sel: SelectionDep,
    input: _Index = None,
) -> dict[str, Any]:
    """FRF values H (response acceleration or reaction per input force) of the chosen responses
    × inputs on the lines in [``f_min_hz``, ``f_max_hz``]: ``real``, ``imag`` and ``coherence``
    indexed ``[line][response][input]`` (``layout``), each response with its ``kind`` and
    ``unit`` ((m/s²)/N, N/N, N·m/N). Choose a channel by its index in the set (``response``,
    ``input``) or by node and optional UFF direction (``response_node`` and
    ``response_direction``, ``input_node`` and ``input_direction``); all of them otherwise."""
    return asdict(
        found(
            lab.store.frf_values(frf_id, sel.responses, sel.inputs(input), sel.band_hz),
            f"FRF set {frf_id}",
        )
    )


@router.get(
    "/{frf_id:id}/data.f32",
    response_class=Response,
    responses={200: {"content": {MEDIA_TYPE: {}}}},
)
def frf_data_f32(
    frf_id: IdPath,
    lab: LabDep,
    sel: SelectionDep,
    input: _Index = None,
) -> Response:
    """``/data`` as float32 little-endian arrays behind a small JSON header (what the page
    draws, about a fifth of the bytes and no parsing of nested lists): ``b"DFRF"``, the header's
    length (uint32), the JSON header (``frequencies_hz``, ``responses``, ``inputs``, ``layout``
    and where each array starts: ``arrays``), then ``real``, ``imag`` and ``coherence`` (NaN: none)
    each ``[line][response][input]``. The same selection as ``/data``."""
    body = found(
        lab.store.frf_values_f32(frf_id, sel.responses, sel.inputs(input), sel.band_hz),
        f"FRF set {frf_id}",
    )
    return Response(content=body, media_type=MEDIA_TYPE)


@router.get("/{frf_id:id}/envelope", response_model=FrfEnvelopeOut)
def frf_envelope(
    frf_id: IdPath,
    lab: LabDep,
    sel: SelectionDep,
    points: Annotated[
        int, CANONICAL_INT, Query(ge=1, le=100_000, description="most points per pair")
    ] = 512,
    input: Annotated[
        list[Annotated[int, CANONICAL_INT, Field(ge=0, le=MAX_ID)]] | None,
        Query(max_length=1000, description="input indices (repeat the key for several)"),
    ] = None,
) -> dict[str, Any]:
    """What a plot or a report shows of the set, at a fraction of ``/data``'s size: the |H|
    envelope of the chosen responses × inputs (as in ``/data``) on the lines in [``f_min_hz``,
    ``f_max_hz``] in at most ``points`` points (each the largest and smallest |H| of its group
    of consecutive lines), and each pair's mean coherence over those lines. ``input`` may be
    repeated (``input=0&input=1``: those inputs, in that order), each once; at most
    :data:`~dimacq.services.lab.store.MAX_ENVELOPE_VALUES` points × responses × inputs."""
    if input is not None and len(set(input)) != len(input):
        twice = sorted(i for i, n in Counter(input).items() if n > 1)
        raise RequestValidationError(
            [
                {
                    "loc": ("query", "input"),
                    "msg": f"input {', '.join(map(str, twice))} given more than once; "
                    "give each input once",
                    "type": "unique_items",
                }
            ]
        )
    return found(
        lab.store.frf_envelope(
            frf_id, points, sel.responses, sel.inputs(indices=tuple(input or ())), sel.band_hz
        ),
        f"FRF set {frf_id}",
    )


@router.get(
    "/{frf_id:id}/uff",
    response_class=Response,
    responses={200: {"content": {"application/octet-stream": {}}}},
)
def export_uff(frf_id: IdPath, lab: LabDep, whole_test: bool = True) -> Response:
    """The FRFs as UFF 58 (with geometry 164/2420/2411 when ``whole_test``)."""
    data = found(lab.store.export_frf_uff(frf_id, whole_test), f"FRF set {frf_id}")
    return Response(content=data, media_type="application/octet-stream")


@router.post(
    "/import", response_model=FrfOut, status_code=status.HTTP_201_CREATED, openapi_extra=RAW_BODY
)
async def import_uff(
    request: Request,
    lab: LabDep,
    setup_id: Annotated[int, CANONICAL_INT, Query(ge=1, le=MAX_ID)],
    name: NameQuery = "",
) -> FrfSummary:
    """Send a UFF file (58 records) whose channels match the setup; returns the set with its
    ``id``."""
    data = await read_upload(request)
    fid = await run_in_threadpool(lab.store.import_frf, data, setup_id, name)
    return found(lab.store.frf_summary(fid), f"FRF set {fid}")
