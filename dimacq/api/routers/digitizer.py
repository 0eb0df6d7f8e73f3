"""Digitizer: shots, speed of sound, points, patches, reference nodes, registration, jig
orientation, lines of action."""

from __future__ import annotations

from dataclasses import asdict
from typing import Annotated, Any, Literal

from fastapi import APIRouter, HTTPException, Path, Query, Request, Response, status
from fastapi.concurrency import run_in_threadpool

from dimacq.api.deps import CANONICAL_INT, IdPath, LabDep, NameQuery
from dimacq.api.routers._common import (
    LIST_RESPONSES,
    RAW_BODY,
    PageDep,
    body_openapi,
    deleted,
    found,
    json_array,
    paged,
    read_upload,
    strict_body,
)
from dimacq.api.schemas import (
    LABEL_PATTERN,
    MAX_ID,
    DeletedOut,
    LineOfActionRequest,
    NewTestRequest,
    OrientationRequest,
    PatchRequest,
    PhotoGeometryStored,
    PointOut,
    PointRequest,
    ReferenceNodeRequest,
    ReferenceNodesRequest,
    RegistrationRequest,
    ShotsRequest,
    SpeedOfSoundOut,
)
from dimacq.errors import DataError
from dimacq.services.geometry.records import (
    LineOfAction,
    NewTest,
    Orientation,
    PatchInfo,
    ReferenceNode,
    RegisteredPatch,
    Shots,
)

router = APIRouter(prefix="/api/digitizer", tags=["digitizer"])


@router.post("/shots", response_model=Shots, openapi_extra=body_openapi(ShotsRequest))
def fire_shots(
    lab: LabDep, body: Annotated[ShotsRequest, strict_body(ShotsRequest)]
) -> dict[str, Any]:
    """Fire raw shots; each with its triangulated tip, speed of sound and verdict."""
    if body.sim_probe is not None:
        lab.geometry.place_simulated_probe(body.sim_probe.tip_m, body.sim_probe.axis)
    return lab.geometry.fire_shots(body.n).to_json()


@router.post("/speed-of-sound", response_model=SpeedOfSoundOut)
def measure_speed_of_sound(lab: LabDep) -> dict[str, float]:
    """Fire three shots and report the speed of sound measured on the calibration bar (it fires
    the digitizer: a POST with the token; ``GET`` returns the last measured value)."""
    return {"speed_of_sound_m_s": lab.geometry.measure_speed_of_sound()}


@router.get("/speed-of-sound", response_model=SpeedOfSoundOut)
def speed_of_sound(lab: LabDep) -> dict[str, float]:
    """The speed of sound measured last (``POST`` measures it), without firing: 404 if none
    was measured since the service started."""
    v = lab.geometry.last_speed_of_sound()
    if v is None:
        raise HTTPException(
            status_code=404,
            detail="speed of sound: not measured yet; POST /api/digitizer/speed-of-sound",
        )
    return {"speed_of_sound_m_s": v}


@router.post(
    "/points",
    response_model=PointOut,
    status_code=status.HTTP_201_CREATED,
    openapi_extra=body_openapi(PointRequest),
)
def digitize_point(
    lab: LabDep, body: Annotated[PointRequest, strict_body(PointRequest)]
) -> dict[str, Any]:
    """Digitize one labelled point (committed to the database before the reply)."""
    if body.sim_probe is not None:
        lab.geometry.place_simulated_probe(body.sim_probe.tip_m, body.sim_probe.axis)
    return lab.geometry.digitize(body.label, body.shots)


@router.get("/points", response_model=list[PointOut], responses=LIST_RESPONSES)
async def list_points(lab: LabDep, page: PageDep) -> Response:
    # up to MAX_LIMIT points: read and turned into JSON in a worker (json_array)
    def read() -> Response:
        got = lab.geometry.points_page(page.limit, page.offset)
        return Response(
            json_array(PointOut, got.items),
            media_type="application/json",
            headers={"X-Total-Count": str(got.total)},
        )

    return await run_in_threadpool(read)


@router.delete("/points", response_model=DeletedOut)
def delete_points(
    lab: LabDep,
    request: Request,
    patch: Annotated[
        int | None,
        CANONICAL_INT,
        Query(ge=0, le=MAX_ID, description="only this patch's points (default: every point)"),
    ] = None,
) -> dict[str, int]:
    """Delete the digitized points in bulk: every one, or one patch's (an import to do again);
    ``{"deleted": n}``. Registrations, orientations and lines of action are kept."""
    # a bulk delete never guesses: a misspelt filter (``?pach=2``) must not delete every point
    unknown = sorted(set(request.query_params) - {"patch"})
    if unknown:
        raise DataError(f"query parameter {unknown[0]!r} unknown; give only patch=N (or nothing)")
    return {"deleted": lab.geometry.delete_points(patch)}


@router.post(
    "/points/import",
    response_model=list[PointOut],
    status_code=status.HTTP_201_CREATED,
    openapi_extra=RAW_BODY,
)
async def import_points(
    request: Request,
    lab: LabDep,
    format: Literal["csv", "json"] = "csv",
    name: NameQuery | None = None,
) -> Response:
    """Labelled points measured by another instrument (CMM, laser tracker, photogrammetry), in
    its own frame, as a new patch: register it from reference nodes and fit orientations and
    lines of action as for digitized points (file layout: ``dimacq/io/measured_points.py``)."""
    from dimacq.io.measured_points import read_measured_points

    data = await read_upload(request)

    def parse_and_store() -> bytes:  # off the event loop, answer included (json_array)
        points = read_measured_points(data, format, what=f"measured points ({format})")
        return json_array(PointOut, lab.geometry.import_points(points, name))

    body = await run_in_threadpool(parse_and_store)
    return Response(body, status_code=status.HTTP_201_CREATED, media_type="application/json")


@router.post(
    "/photo-geometry",
    response_model=PhotoGeometryStored,
    status_code=status.HTTP_201_CREATED,
    openapi_extra=RAW_BODY,
)
async def import_photo_geometry(request: Request, lab: LabDep) -> dict[str, Any]:
    """Triax orientations and lines of action from photographs (the JSON ``dimacq geometry
    from-photos`` writes) as the current test's records: a setup built from geometry
    (``POST /api/setups/from-geometry``) then uses them as digitized ones."""
    import json

    data = await read_upload(request)
    try:
        doc = json.loads(data.decode("utf-8"))
    except (UnicodeDecodeError, ValueError) as err:
        raise HTTPException(
            status_code=422, detail=f"photo geometry: not JSON ({err}); send GEOMETRY.json"
        ) from err
    return await run_in_threadpool(lab.geometry.import_photo_geometry, doc)


@router.delete("/points/{point_id:id}", status_code=status.HTTP_204_NO_CONTENT)
def delete_point(point_id: IdPath, lab: LabDep) -> Response:
    """Delete a mistaken point (redo it: digitize the label again; the latest point of a label
    is the one used, so deleting is needed only to fall back to an earlier one)."""
    return deleted(lab.geometry.delete_point(point_id), f"point {point_id}")


@router.get("/patches", response_model=list[PatchInfo], responses=LIST_RESPONSES)
def list_patches(lab: LabDep, page: PageDep, response: Response) -> list[dict[str, Any]]:
    return paged(response, [p.to_json() for p in lab.geometry.patches()], page)


@router.post(
    "/patches",
    response_model=PatchInfo,
    status_code=status.HTTP_201_CREATED,
    openapi_extra=body_openapi(PatchRequest),
)
def new_patch(
    lab: LabDep, body: Annotated[PatchRequest, strict_body(PatchRequest)]
) -> dict[str, Any]:
    """The array moved: later points belong to a new patch."""
    return lab.geometry.new_patch(body.name).to_json()


@router.post(
    "/tests",
    response_model=NewTest,
    status_code=status.HTTP_201_CREATED,
    openapi_extra=body_openapi(NewTestRequest),
)
def new_test(
    lab: LabDep, body: Annotated[NewTestRequest, strict_body(NewTestRequest)]
) -> dict[str, Any]:
    """Start a new test: a fresh patch, reference nodes, orientations and lines of action
    cleared (earlier points stay in the database, unused)."""
    return lab.geometry.new_test(body.name).to_json()


@router.put(
    "/reference-nodes",
    response_model=list[ReferenceNode],
    openapi_extra=body_openapi(ReferenceNodesRequest),
)
def set_reference_nodes(
    lab: LabDep, body: Annotated[ReferenceNodesRequest, strict_body(ReferenceNodesRequest)]
) -> list[dict[str, Any]]:
    """Replace every reference node (those not given are removed)."""
    return [asdict(r) for r in lab.geometry.set_reference_nodes(body.nodes)]


@router.get("/reference-nodes", response_model=list[ReferenceNode], responses=LIST_RESPONSES)
def reference_nodes(lab: LabDep, page: PageDep, response: Response) -> list[dict[str, Any]]:
    return paged(response, [asdict(r) for r in lab.geometry.reference_nodes()], page)


@router.put(
    "/reference-nodes/{label}",
    response_model=list[ReferenceNode],
    openapi_extra=body_openapi(ReferenceNodeRequest),
)
def set_reference_node(
    lab: LabDep,
    label: Annotated[str, Path(max_length=200, pattern=LABEL_PATTERN)],
    body: Annotated[ReferenceNodeRequest, strict_body(ReferenceNodeRequest)],
) -> list[dict[str, Any]]:
    """Add or replace one reference node's known GCS position."""
    return [asdict(r) for r in lab.geometry.set_reference_nodes({label: body.position_m})]


@router.delete("/reference-nodes/{label}", status_code=status.HTTP_204_NO_CONTENT)
def delete_reference_node(
    lab: LabDep, label: Annotated[str, Path(max_length=200, pattern=LABEL_PATTERN)]
) -> Response:
    """Remove a reference node (registrations already made are kept)."""
    found(True if lab.geometry.delete_reference_node(label) else None, f"reference node {label!r}")
    return Response(status_code=status.HTTP_204_NO_CONTENT)


@router.post(
    "/registrations",
    response_model=RegisteredPatch,
    openapi_extra=body_openapi(RegistrationRequest),
)
def register_patch(
    lab: LabDep, body: Annotated[RegistrationRequest, strict_body(RegistrationRequest)]
) -> dict[str, Any]:
    """Register a patch from its reference nodes; refused (400, naming the worst node and its
    residual in mm) when a node's residual is above the limit."""
    return lab.geometry.register_patch(body.patch, body.method, body.labels, body.limit_m).to_json()


@router.post(
    "/orientations",
    response_model=Orientation,
    status_code=status.HTTP_201_CREATED,
    openapi_extra=body_openapi(OrientationRequest),
)
def fit_orientation(
    lab: LabDep, body: Annotated[OrientationRequest, strict_body(OrientationRequest)]
) -> dict[str, Any]:
    """Orientation of a triax from its digitized jig indentations (``<prefix>X1`` .. ``Z8``)."""
    return lab.geometry.fit_orientation(body.node, body.prefix, body.method).to_json()


@router.get("/orientations", response_model=list[Orientation], responses=LIST_RESPONSES)
def orientations(lab: LabDep, page: PageDep, response: Response) -> list[dict[str, Any]]:
    return paged(response, [o.to_json() for o in lab.geometry.orientations()], page)


@router.post(
    "/lines-of-action",
    response_model=LineOfAction,
    status_code=status.HTTP_201_CREATED,
    openapi_extra=body_openapi(LineOfActionRequest),
)
def fit_line_of_action(
    lab: LabDep, body: Annotated[LineOfActionRequest, strict_body(LineOfActionRequest)]
) -> dict[str, Any]:
    return lab.geometry.fit_line_of_action(
        body.node, body.input_label, body.labels, body.method
    ).to_json()


@router.get("/lines-of-action", response_model=list[LineOfAction], responses=LIST_RESPONSES)
def lines_of_action(lab: LabDep, page: PageDep, response: Response) -> list[dict[str, Any]]:
    return paged(response, [a.to_json() for a in lab.geometry.lines_of_action()], page)
