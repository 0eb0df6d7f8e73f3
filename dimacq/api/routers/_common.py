"""Shared router helpers (404s, raw uploads)."""

from __future__ import annotations

from typing import Any, TypeVar

from fastapi import HTTPException, Request

T = TypeVar("T")

MAX_UPLOAD_BYTES = 256 * 1024 * 1024

RAW_BODY: dict[str, Any] = {
    "requestBody": {
        "required": True,
        "content": {"application/octet-stream": {"schema": {"type": "string", "format": "binary"}}},
    }
}


def found(value: T | None, what: str) -> T:
    """``value`` or a 404 naming the item."""
    if value is None:
        raise HTTPException(
            status_code=404, detail=f"{what} does not exist; list the collection to find its id"
        )
    return value


async def read_upload(request: Request) -> bytes:
    data = await request.body()
    if not data:
        raise HTTPException(
            status_code=422, detail="body: send the file content as the request body"
        )
    if len(data) > MAX_UPLOAD_BYTES:
        raise HTTPException(
            status_code=413, detail=f"body: file larger than {MAX_UPLOAD_BYTES} bytes"
        )
    return data
