"""Shared router helpers (404s, raw uploads)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from functools import cache
from typing import Annotated, Any, TypeVar

import numpy as np
import pydantic_core
from fastapi import Depends, HTTPException, Query, Request, Response
from fastapi.exceptions import RequestValidationError
from pydantic import BaseModel, TypeAdapter, ValidationError

from dimacq.api.deps import CANONICAL_INT
from dimacq.api.schemas import MAX_ID
from dimacq.errors import SetupError
from dimacq.io.documents import find_non_finite, loads_json
from dimacq.services.lab.store import Page

T = TypeVar("T")

# -- pagination ---------------------------------------------------------------------------------
#: Most items one list call returns.
MAX_LIMIT = 10_000


@dataclass(frozen=True)
class PageQuery:
    """``limit`` (at most :data:`MAX_LIMIT`, also when left out: no answer holds more) items
    after the first ``offset``, in id order (creation order); ``X-Total-Count`` tells how many
    there are in all."""

    limit: Annotated[
        int | None,
        CANONICAL_INT,
        Query(ge=1, le=MAX_LIMIT, description="items to return (default and at most 10000)"),
    ] = MAX_LIMIT
    offset: Annotated[int, CANONICAL_INT, Query(ge=0, le=MAX_ID, description="items to skip")] = 0


PageDep = Annotated[PageQuery, Depends()]

#: The documented headers of every list response.
LIST_RESPONSES: dict[int | str, dict[str, Any]] = {
    200: {
        "description": "one page of the collection, oldest first; the total count of the "
        "collection in the X-Total-Count header",
        "headers": {
            "X-Total-Count": {
                "description": "items in the whole collection (for paging with limit/offset)",
                "schema": {"type": "integer"},
            }
        },
    }
}


def paged(response: Response, got: Page[T] | Sequence[T], page: PageQuery) -> list[T]:
    """The page's items, and the collection's total in ``X-Total-Count``. A :class:`Page` was
    cut by the database already; a plain sequence (small in-memory collections) is cut here."""
    if isinstance(got, Page):
        items, total = got.items, got.total
    else:
        total = len(got)
        stop = None if page.limit is None else page.offset + page.limit
        items = list(got[page.offset : stop])
    response.headers["X-Total-Count"] = str(total)
    return items


#: Items one pydantic call validates and serialises in :func:`json_array`.
JSON_CHUNK = 256


@cache
def _list_adapter(model: type[BaseModel]) -> TypeAdapter[list[Any]]:
    return TypeAdapter(list[model])  # type: ignore[valid-type]


def json_array(model: type[BaseModel], items: Sequence[Any], chunk: int = JSON_CHUNK) -> bytes:
    """``items`` (objects or mappings with ``model``'s fields) as the JSON array of ``model``
    that FastAPI's ``response_model`` would send, built ``chunk`` items per pydantic call.

    For big answers, in a worker thread (``run_in_threadpool``), returned as a ``Response``:
    FastAPI itself turns a response into JSON on the event loop, and one pydantic call holds
    the GIL until it returns; a chunk at a time keeps each hold short, so the event loop
    (``/api/status``) is served between chunks.
    """
    adapter = _list_adapter(model)
    parts = []
    for i in range(0, len(items), chunk):
        valid = adapter.validate_python(items[i : i + chunk], from_attributes=True)
        parts.append(adapter.dump_json(valid)[1:-1])
    return b"[" + b",".join(parts) + b"]"


def json_object(raw: bytes, example: str) -> dict[str, Any]:
    """A JSON object body (``{}`` when empty), or 422 naming the body, the limit it passed
    (:mod:`dimacq.io.documents`) and an example."""
    try:
        # within the documents' limits: depth, values, digits (dimacq.io.documents)
        body = loads_json(raw, "body") if raw.strip() else {}
    except SetupError as err:
        msg = str(err).removeprefix("body: ")
        raise RequestValidationError(
            [{"loc": ("body",), "msg": f"{msg}; send {example}", "type": "json_invalid"}]
        ) from err
    if not isinstance(body, dict):
        raise RequestValidationError(
            [{"loc": ("body",), "msg": f"send a JSON object, e.g. {example}", "type": "dict_type"}]
        )
    return body


def deleted(done: bool | None, what: str) -> Response:
    """204 after a delete, 404 naming the item when there was none."""
    found(done, what)
    return Response(status_code=204)


#: Paths whose body is a file (``RAW_BODY``): limited by ``max_upload_bytes`` instead of
#: ``max_body_bytes`` (:class:`dimacq.api.guards.BodyLimitMiddleware`).
UPLOAD_PATHS = frozenset(
    {
        "/api/setups/import",
        "/api/frfs/import",
        "/api/digitizer/points/import",
        "/api/digitizer/photo-geometry",
        "/api/photo-geometry/files",
    }
)

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
    """The body of an upload (a path in :data:`UPLOAD_PATHS`); 422 if empty."""
    if request.url.path not in UPLOAD_PATHS:
        raise RuntimeError(f"{request.url.path}: add the upload path to UPLOAD_PATHS")
    data = await request.body()
    if not data:
        raise HTTPException(
            status_code=422, detail="body: send the file content as the request body"
        )
    return data  # its size is limited before it is read (max_upload_bytes)


# -- strict JSON bodies -------------------------------------------------------------------------
#: Request models documented through :func:`body_openapi`; added to the spec's components.
BODY_MODELS: dict[str, type[BaseModel]] = {}

M = TypeVar("M", bound=BaseModel)


def strict_body(model: type[M]) -> Any:
    """Dependency: the request body validated as ``model`` in pydantic's strict JSON mode.

    FastAPI validates bodies in lax mode, where ``false`` passes for ``0.0`` and ``"1"`` for ``1``
    (also inside the domain models, whose config we do not own). Strict mode refuses every value
    whose JSON type differs from the schema, so the API accepts exactly what its spec says. Errors
    are request validation errors located under ``body`` (422 naming the field).
    """

    async def dependency(request: Request) -> M:
        return parse_strict(model, await request.body())

    return Depends(dependency)


def parse_strict(model: type[M], raw: bytes) -> M:
    """``raw`` validated as ``model`` in strict JSON mode (:func:`strict_body`); 422 naming the
    field otherwise, also for any NaN or infinite number in the body."""
    bad = _non_finite_in(raw)
    if bad is not None:
        raise RequestValidationError(
            [
                {
                    "loc": ("body", *bad[0]),
                    "msg": f"{bad[1]} is not a finite number; give a finite number "
                    "(NaN and infinities are refused)",
                    "type": "finite_number",
                }
            ]
        )
    try:
        # the domain validators use numpy: absurd magnitudes overflow to inf and are refused
        # by the checks; do not let an overflow warning escape as an error
        with np.errstate(all="ignore"):
            return model.model_validate_json(raw or b"null", strict=True)
    except ValidationError as err:
        errors = [
            {"loc": ("body", *e["loc"]), "msg": e["msg"], "type": e["type"]}
            for e in err.errors(include_url=False)
        ]
        raise RequestValidationError(errors) from None


def _non_finite_in(raw: bytes) -> tuple[tuple[str | int, ...], float] | None:
    """Where a JSON body holds ``NaN``, ``Infinity`` or a number too large for a float
    (``1e999``), checked before any model sees it (the domain models' own checks do not cover
    every float: settings, tolerances); None when it holds none or is not JSON (the model's
    validation says why)."""
    try:
        doc = pydantic_core.from_json(raw or b"null")
    except ValueError:
        return None
    return find_non_finite(doc)


def body_openapi(model: type[BaseModel]) -> dict[str, Any]:
    """``openapi_extra`` documenting a JSON request body of ``model``."""
    BODY_MODELS[model.__name__] = model
    return {
        "requestBody": {
            "required": True,
            "content": {
                "application/json": {"schema": {"$ref": f"#/components/schemas/{model.__name__}"}}
            },
        }
    }


def add_body_components(components: dict[str, Any]) -> None:
    """Put the request models (validation-mode JSON schema) into ``components["schemas"]``."""
    schemas = components.setdefault("schemas", {})
    for name, model in BODY_MODELS.items():
        schema = model.model_json_schema(ref_template="#/components/schemas/{model}")
        for k, v in schema.pop("$defs", {}).items():
            schemas[k] = v
        schemas[name] = schema
