"""Geometry from photographs as a job: photo folders under ``data_dir/photos`` (filled by upload
or by copying), and the job that runs ``dimacq geometry from-photos`` on one and stores its
records and setup; progress and the result through ``/api/jobs/{job_id}``."""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, Path, Query, Request, Response, status
from fastapi.concurrency import run_in_threadpool

from dimacq.api.deps import LabDep
from dimacq.api.routers._common import (
    RAW_BODY,
    body_openapi,
    deleted,
    found,
    read_upload,
    strict_body,
)
from dimacq.api.schemas import JobInfo
from dimacq.services.lab.photo_jobs import FOLDER_PATTERN, PhotoFolderOut, PhotoGeometryParams

router = APIRouter(prefix="/api/photo-geometry", tags=["photo geometry"])

FolderPath = Annotated[
    str, Path(max_length=100, pattern=FOLDER_PATTERN, description="a folder under data_dir/photos")
]


class PhotoGeometryRequest(PhotoGeometryParams):
    """A geometry-from-photos job (:class:`PhotoGeometryParams`)."""


@router.post(
    "/files",
    response_model=PhotoFolderOut,
    status_code=status.HTTP_201_CREATED,
    openapi_extra=RAW_BODY,
)
async def upload_file(
    request: Request,
    lab: LabDep,
    folder: Annotated[
        str, Query(max_length=100, pattern=FOLDER_PATTERN, description="the photo folder")
    ],
    name: Annotated[
        str,
        Query(max_length=200, description="the file's name: a photo, tags.toml or camera.toml"),
    ],
) -> PhotoFolderOut:
    """One file into a photo folder (created when new): a photo (JPEG, PNG, TIFF, BMP: the
    camera's original file, whose EXIF states the focal length), ``tags.toml`` or
    ``camera.toml``; a file of the same name is replaced. Returns what the folder holds."""
    data = await read_upload(request)
    return await run_in_threadpool(lab.photos.save_file, folder, name, data)


@router.get("/folders/{folder}", response_model=PhotoFolderOut)
def get_folder(folder: FolderPath, lab: LabDep) -> PhotoFolderOut:
    """The photos of a folder and whether it holds a tags file and a camera file."""
    return found(lab.photos.folder(folder), f"photo folder {folder!r}")


@router.delete("/folders/{folder}", status_code=status.HTTP_204_NO_CONTENT)
def delete_folder(folder: FolderPath, lab: LabDep) -> Response:
    """Remove a photo folder and its files (a set to upload again)."""
    return deleted(True if lab.photos.delete_folder(folder) else None, f"photo folder {folder!r}")


@router.post(
    "/jobs",
    response_model=JobInfo,
    status_code=status.HTTP_202_ACCEPTED,
    openapi_extra=body_openapi(PhotoGeometryRequest),
)
def start(
    lab: LabDep, body: Annotated[PhotoGeometryRequest, strict_body(PhotoGeometryRequest)]
) -> dict[str, Any]:
    """Start ``dimacq geometry from-photos`` on a photo folder: returns its job (``id``;
    ``GET /api/jobs/{id}`` gives its progress: photos read, then the adjustment's evaluations).
    Once ``succeeded``, ``result`` holds ``verdict``, ``unfixed`` (each triax or input the photos
    cannot fix, with the photos it needs: nothing is stored then), ``issues`` (each photo that
    could not help, with the fix), ``geometry`` (the command's GEOMETRY.json) and, when every
    triax and input is fixed, ``stored`` (the records now the test's orientations and lines of
    action) and ``setup_id`` (the setup at the photographed geometry)."""
    job = lab.photos.start(body)
    snap = lab.jobs.snapshot(job.id)
    assert snap is not None
    return snap
