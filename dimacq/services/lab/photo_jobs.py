"""Geometry from photographs as a job of the lab service: ``dimacq geometry from-photos`` run on a
folder of photos under ``<data_dir>/photos``, with progress, and its records stored as digitized
geometry is.

A folder is filled by uploads (:meth:`PhotoGeometryService.save_file`: photos, ``tags.toml``,
``camera.toml``) or by copying the photos there. :meth:`PhotoGeometryService.start` checks the
request (folder, setup, tags file) and runs
:func:`dimacq.services.geometry.photo_geometry.geometry_from_photos` on a job thread; progress is
``photo k of n`` while the photos are read (fraction ``0.5 k/n``) and the adjustment's function
evaluations after (``0.5 + 0.45 m/(m + 100)``: the number it will take is not known beforehand).
Once every triax and input is fixed the job stores their records
(:meth:`dimacq.services.lab.geometry.GeometryService.import_photo_geometry`, the digitizer's
orientation and line-of-action records) and the setup the command writes (the given setup at the
photographed geometry with its stated uncertainty) as a stored setup: the default solve of that
setup uses the photographed geometry. A set that leaves a triax or input unfixed stores nothing;
its result names each one with the photos it needs and every photo that could not help.
"""

from __future__ import annotations

import re
import shutil
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

from pydantic import BaseModel, ConfigDict, Field, model_validator

from dimacq.errors import DataError, DimacqError, SetupError
from dimacq.services.lab.jobs import Job, JobContext, JobManager

if TYPE_CHECKING:
    from dimacq.services.lab.geometry import GeometryService
    from dimacq.services.lab.store import TestStore

__all__ = ["FOLDER_PATTERN", "PhotoFolderOut", "PhotoGeometryParams", "PhotoGeometryService"]

#: A photo folder's name: one path component (letters, digits, ``._-``), not starting with a dot.
FOLDER_PATTERN = r"^[A-Za-z0-9_-][A-Za-z0-9._-]{0,99}$"
#: Files an upload may add to a folder: photos, the tags file, the camera file.
_FILE_NAME = re.compile(r"^[A-Za-z0-9_-][A-Za-z0-9._ -]{0,199}$")
_TEXT_FILES = ("tags.toml", "camera.toml")
#: Most photos one folder holds (a photo set is 20-60; a folder past this is not one set).
MAX_PHOTOS = 2000
#: Upper bound of one tags or camera file sent in a job's request, characters.
_MAX_TEXT = 1_000_000

Folder = Annotated[str, Field(pattern=FOLDER_PATTERN, description="a folder under data_dir/photos")]


class PhotoGeometryParams(BaseModel):
    """A geometry-from-photos job: the photo folder, the setup to put the geometry into (a stored
    setup's id or a setup file's keys), optional tags and camera files (their text; default
    the folder's ``tags.toml`` / ``camera.toml``, then ``data_dir/photos/tags.toml``), and the
    test the stored setup joins."""

    model_config = ConfigDict(extra="forbid")

    folder: Folder
    setup_id: int | None = Field(default=None, ge=1, le=2**31 - 1)
    setup: dict[str, Any] | None = Field(
        default=None, description="a setup file's keys (instead of setup_id)"
    )
    tags_toml: str | None = Field(default=None, max_length=_MAX_TEXT)
    camera_toml: str | None = Field(default=None, max_length=_MAX_TEXT)
    test_id: int | None = Field(default=None, ge=1, le=2**31 - 1)
    name: str = Field(default="", max_length=200, pattern=r"^[^\x00-\x1f\x7f]*$")

    @model_validator(mode="after")
    def _one_setup(self) -> PhotoGeometryParams:
        if (self.setup_id is None) == (self.setup is None):
            raise ValueError("give setup_id (a stored setup) or setup (a setup file's keys), one")
        return self


class PhotoFolderOut(BaseModel):
    """A photo folder: its photos and whether it holds a tags file and a camera file."""

    folder: str
    photos: list[str]
    tags_file: bool
    camera_file: bool


class PhotoGeometryService:
    """Photo folders under ``root`` and geometry-from-photos jobs.

    Parameters
    ----------
    jobs : JobManager
    geometry : GeometryService
        Stores the records (:meth:`~dimacq.services.lab.geometry.GeometryService.import_photo_geometry`).
    store : TestStore
        Reads the setup by id, stores the photographed setup.
    root : Path
        ``<data_dir>/photos``: every folder a job reads is one of its subfolders.
    """

    def __init__(
        self, jobs: JobManager, geometry: GeometryService, store: TestStore, root: Path
    ) -> None:
        self.jobs = jobs
        self.geometry = geometry
        self.store = store
        self.root = root

    # -- folders -------------------------------------------------------------------------------
    def _folder(self, name: str) -> Path:
        if not re.match(FOLDER_PATTERN, name):
            raise SetupError(
                f"folder {name!r}: give one folder name (letters, digits, '._-'), a folder "
                "under data_dir/photos"
            )
        return self.root / name

    def folder(self, name: str) -> PhotoFolderOut | None:
        """What folder ``name`` holds; None if there is no such folder."""
        from dimacq.services.geometry.photo_geometry import PHOTO_SUFFIXES

        path = self._folder(name)
        if not path.is_dir():
            return None
        photos = sorted(p.name for p in path.iterdir() if p.suffix.lower() in PHOTO_SUFFIXES)
        return PhotoFolderOut(
            folder=name,
            photos=photos,
            tags_file=(path / "tags.toml").is_file(),
            camera_file=(path / "camera.toml").is_file(),
        )

    def require_folder(self, name: str) -> PhotoFolderOut:
        """:meth:`folder`, a DataError naming the fix if there is none."""
        have = self.folder(name)
        if have is None:
            raise DataError(
                f"folder {name!r}: no such photo folder under data_dir/photos; upload photos "
                "into it (POST /api/photo-geometry/files) or copy them there"
            )
        return have

    def save_file(self, folder: str, name: str, data: bytes) -> PhotoFolderOut:
        """Write one uploaded file (a photo, ``tags.toml`` or ``camera.toml``) into ``folder``
        (created when new), replacing a file of that name; what the folder then holds."""
        from dimacq.services.geometry.photo_geometry import PHOTO_SUFFIXES

        path = self._folder(folder)
        if not _FILE_NAME.match(name) or (
            Path(name).suffix.lower() not in PHOTO_SUFFIXES and name not in _TEXT_FILES
        ):
            raise SetupError(
                f"name {name!r}: give a photo's file name ({', '.join(PHOTO_SUFFIXES)}), "
                "tags.toml or camera.toml (letters, digits, ' ._-', no folder)"
            )
        if not data:
            raise DataError(f"{name}: the file is empty; send its content as the body")
        path.mkdir(parents=True, exist_ok=True)
        have = self.require_folder(folder)
        if name not in have.photos and name not in _TEXT_FILES and len(have.photos) >= MAX_PHOTOS:
            raise DataError(
                f"folder {folder!r} holds {len(have.photos)} photos (limit {MAX_PHOTOS}); "
                "put another photo set in another folder"
            )
        tmp = path / f".{name}.part"
        tmp.write_bytes(data)
        tmp.replace(path / name)
        return self.require_folder(folder)

    def delete_folder(self, folder: str) -> bool:
        """Remove a photo folder and its files; False if there was none."""
        path = self._folder(folder)
        if not path.is_dir():
            return False
        shutil.rmtree(path)
        return True

    # -- the job ---------------------------------------------------------------------------------
    def start(self, params: PhotoGeometryParams) -> Job:
        """Check the request (folder, setup, tags and camera files) and start the job.

        Raises
        ------
        SetupError, DataError
            No such folder or no photos in it, no such setup, no tags file, a tags or camera
            file that does not read: the message names the field and the fix.
        """
        from dimacq.io.setup_file import parse_setup
        from dimacq.io.tags_file import load_tags
        from dimacq.services.geometry.photo_geometry import load_camera

        have = self.require_folder(params.folder)
        if not have.photos:
            raise DataError(f"folder {params.folder!r}: no photos in it; upload the photos first")
        path = self._folder(params.folder)
        if params.setup_id is not None:
            setup = self.store.setup(params.setup_id)
            if setup is None:
                raise SetupError(
                    f"setup_id {params.setup_id}: no such setup; list GET /api/setups for its id"
                )
        else:
            setup = parse_setup(params.setup or {}, "setup")
        # a file sent with the request replaces the folder's only once it reads
        if params.tags_toml is not None:
            _replace_checked(path / "tags.toml", params.tags_toml, load_tags)
        if params.camera_toml is not None:
            _replace_checked(path / "camera.toml", params.camera_toml, load_camera)
        tags_path = next(
            (p for p in (path / "tags.toml", self.root / "tags.toml") if p.is_file()), None
        )
        if tags_path is None:
            raise SetupError(
                f"tags_toml: folder {params.folder!r} holds no tags.toml; send the tags file "
                "(tags_toml) or upload tags.toml into the folder"
            )
        tags = load_tags(tags_path)
        camera = load_camera(path / "camera.toml") if (path / "camera.toml").is_file() else None
        name = params.name or f"{setup.name or 'setup'} (photographed, {params.folder})"

        def work(ctx: JobContext) -> dict[str, Any]:
            from dimacq.services.geometry.photo_geometry import geometry_from_photos

            ctx.progress(0.0, f"reading {len(have.photos)} photos")
            res = geometry_from_photos(
                path, tags, setup=setup, camera=camera, progress=_progress(ctx)
            )
            doc = res.to_json()
            out: dict[str, Any] = {
                "folder": params.folder,
                "verdict": res.verdict,
                "unfixed": list(res.unfixed),
                "issues": [i.to_json() for i in res.issues],
                "geometry": doc,
                "stored": None,
                "setup_id": None,
            }
            if res.setup is None:
                ctx.progress(1.0, f"refused: {len(res.unfixed)} triaxes or inputs not fixed")
                return out
            out["stored"] = self.geometry.import_photo_geometry(doc)
            stored = res.setup.model_copy(update={"name": name[:200]})
            out["setup_id"] = self.store.save_setup(stored, params.test_id)
            ctx.progress(1.0, f"stored: setup {out['setup_id']}")
            return out

        return self.jobs.submit("photo-geometry", work)


def _replace_checked(target: Path, text: str, load: Callable[[Path], object]) -> None:
    """Write ``text`` as ``target`` once ``load`` reads it (its error, naming the file, is
    raised and ``target`` is left as it was)."""
    tmp = target.with_name(f".{target.name}.part")
    tmp.write_text(text, encoding="utf-8")
    try:
        load(tmp)
    except DimacqError as err:
        tmp.unlink(missing_ok=True)
        raise type(err)(str(err).replace(str(tmp), target.name)) from err
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    tmp.replace(target)


def _progress(ctx: JobContext) -> Callable[[str], None]:
    """The job's progress from the chain's messages: ``photo k/n …`` while reading, then
    ``adjustment: m evaluations …``; another message keeps the fraction. A cancel is honoured
    at each message."""
    photo = re.compile(r"^photo (\d+)/(\d+)")
    evals = re.compile(r"^adjustment: (\d+) evaluations")
    now = [0.0]

    def say(message: str) -> None:
        ctx.check_cancelled()
        m = photo.match(message)
        e = evals.match(message)
        if m:
            now[0] = 0.5 * int(m.group(1)) / max(int(m.group(2)), 1)
        elif e:
            k = int(e.group(1))
            now[0] = 0.5 + 0.45 * k / (k + 100)
        ctx.progress(now[0], message)

    return say
