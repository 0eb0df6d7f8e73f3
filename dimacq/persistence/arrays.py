"""Bulk arrays in HDF5 files under the data directory, referenced from the database by path.

Every file is written whole and atomically: to a temporary file in the same directory, flushed
and ``fsync``-ed, then renamed over the final name (and the directory ``fsync``-ed). A reader
never sees a half-written file, and a file that exists is complete, so killing the service loses
at most the item being written, never a completed average or FRF set. The database row that
references a file is committed after the file is in place; :meth:`ArrayStore.orphans` finds files
whose row was never committed (the service re-registers them at start-up).
"""

from __future__ import annotations

import io
import json
import os
import uuid
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import h5py
import numpy as np
from numpy.typing import NDArray

from dimacq.errors import DataError

__all__ = ["ArrayStore", "arrays_from_bytes", "arrays_to_bytes"]


def arrays_to_bytes(arrays: Mapping[str, NDArray[Any]], attrs: Mapping[str, Any]) -> bytes:
    """``arrays`` and JSON-able ``attrs`` as the bytes of an HDF5 file (for a database column)."""
    buf = io.BytesIO()
    with h5py.File(buf, "w") as fh:
        for name, arr in arrays.items():
            fh.create_dataset(name, data=np.asarray(arr))
        fh.attrs["meta"] = json.dumps(dict(attrs))
    return buf.getvalue()


def arrays_from_bytes(data: bytes) -> tuple[dict[str, NDArray[Any]], dict[str, Any]]:
    """Inverse of :func:`arrays_to_bytes`."""
    try:
        with h5py.File(io.BytesIO(data), "r") as fh:
            arrays = {k: fh[k][()] for k in fh.keys()}
            attrs = json.loads(fh.attrs.get("meta", "{}"))
    except (OSError, ValueError) as err:
        raise DataError(f"stored array data are not a readable HDF5 image ({err})") from err
    return arrays, attrs


def _private_dirs(folder: Path) -> None:
    """``folder`` and its missing parents created 0700 (mode given explicitly: ``mkdir``'s
    ``parents`` ignores it for the parents)."""
    missing = []
    p = folder
    while not p.exists():
        missing.append(p)
        p = p.parent
    for d in reversed(missing):
        try:
            d.mkdir(mode=0o700)
        except FileExistsError:
            continue
        os.chmod(d, 0o700)


class ArrayStore:
    """HDF5 files under ``root``; paths given and returned are relative to ``root``."""

    def __init__(self, root: Path | str) -> None:
        self.root = Path(root)
        _private_dirs(self.root)

    def path(self, rel: str) -> Path:
        p = (self.root / rel).resolve()
        if self.root.resolve() not in p.parents:
            raise DataError(
                f"array file {rel!r} lies outside the data directory; use a relative path"
            )
        return p

    def write(
        self,
        rel: str,
        arrays: Mapping[str, NDArray[Any]],
        attrs: Mapping[str, Any] | None = None,
    ) -> str:
        """Write ``arrays`` (name → ndarray) and JSON-able ``attrs`` atomically to ``rel``."""
        final = self.path(rel)
        _private_dirs(final.parent)
        tmp = final.with_name(f".{final.name}.{uuid.uuid4().hex}.tmp")
        try:
            # created 0600 (the measurements are the lab's), never through an existing link
            os.close(os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW, 0o600))
            with h5py.File(tmp, "w") as fh:
                for name, arr in arrays.items():
                    fh.create_dataset(name, data=np.asarray(arr))
                fh.attrs["meta"] = json.dumps(dict(attrs or {}))
                fh.flush()
            with open(tmp, "rb") as raw:
                os.fsync(raw.fileno())
            os.replace(tmp, final)
            dfd = os.open(final.parent, os.O_RDONLY)
            try:
                os.fsync(dfd)
            finally:
                os.close(dfd)
        finally:
            if tmp.exists():
                tmp.unlink()
        return rel

    def read(self, rel: str) -> tuple[dict[str, NDArray[Any]], dict[str, Any]]:
        """Arrays and attributes of a file written by :meth:`write`."""
        p = self.path(rel)
        if not p.exists():
            raise DataError(
                f"array file {rel!r} is missing from {self.root}; restore it from backup"
            )
        with h5py.File(p, "r") as fh:
            arrays = {k: fh[k][()] for k in fh.keys()}
            attrs = json.loads(fh.attrs.get("meta", "{}"))
        return arrays, attrs

    def exists(self, rel: str) -> bool:
        return self.path(rel).exists()

    def orphans(self, folder: str, known: set[str]) -> list[str]:
        """Complete ``.h5`` files under ``folder`` not in ``known`` (sorted relative paths)."""
        base = self.root / folder
        if not base.exists():
            return []
        out = []
        for p in sorted(base.rglob("*.h5")):
            rel = p.relative_to(self.root).as_posix()
            if rel not in known:
                out.append(rel)
        return out
