"""App factory: ``create_app(settings)`` → FastAPI app around a :class:`~dimacq.services.lab.Lab`.

- The lab (database, devices) is opened in the lifespan handler and held on ``app.state.lab``.
- Access: every state-changing call (any method but GET/HEAD/OPTIONS) under ``/api`` needs the
  token (``Authorization: Bearer <token>``); bound to a non-loopback address, every read under
  ``/api`` needs it too (the LAN is not the lab PC). It is checked by an ASGI middleware *before*
  the body is read or validated, so an anonymous caller gets 401 and learns nothing about the
  body schema.
- Guards before that (:mod:`dimacq.api.guards`): the Host header must name the service (421,
  DNS rebinding), bodies are limited to ``max_body_bytes`` / ``max_upload_bytes`` (413).
- CORS only for the configured origins (none by default).
- Errors: every failure is a 4xx/503 JSON :class:`~dimacq.api.schemas.ErrorBody` naming the field:
  request validation → 422, except an id out of range in the path → 404 (it names no item);
  :class:`~dimacq.errors.DataError` → 400;
  :class:`~dimacq.errors.SetupError` and :class:`~dimacq.errors.SolverError` → 422;
  :class:`~dimacq.errors.DeviceStateError` → 409; other :class:`~dimacq.errors.DeviceError` → 503.
  Messages never show server paths of temporary files (uploads are spooled to one; the readers
  name "the upload", and :func:`_public` removes any temporary path that would still slip by).
"""

from __future__ import annotations

import gc
import json
import logging
import re
import secrets
import time
from collections.abc import AsyncIterator, Callable
from contextlib import asynccontextmanager
from pathlib import Path
from typing import Any

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.middleware.cors import CORSMiddleware
from fastapi.openapi.docs import get_swagger_ui_html
from fastapi.openapi.utils import get_openapi
from fastapi.responses import FileResponse, HTMLResponse, JSONResponse
from fastapi.staticfiles import StaticFiles
from starlette.exceptions import HTTPException as StarletteHTTPException
from starlette.requests import ClientDisconnect
from starlette.responses import Response
from starlette.types import ASGIApp, Receive, Scope, Send

from dimacq.api.guards import (
    LOOPBACK_NAMES,
    BodyLimitMiddleware,
    BodyTooLarge,
    HostCheckMiddleware,
    is_loopback,
    is_wildcard,
)
from dimacq.api.manual import mount_manual
from dimacq.api.public import hide_root, public
from dimacq.api.routers import (
    acquisitions,
    calibrations,
    devices,
    digitizer,
    frfs,
    jobs,
    photo_geometry,
    plans,
    rig,
    sensitivity,
    setups,
    simulation,
    solutions,
    status,
    tests,
)
from dimacq.api.routers._common import UPLOAD_PATHS, add_body_components
from dimacq.api.schemas import MAX_ID, ErrorBody
from dimacq.config import Settings, load_settings
from dimacq.errors import (
    DataError,
    DeviceError,
    DeviceStateError,
    DimacqError,
    SetupError,
    SolverError,
)
from dimacq.io.measured_points import MAX_POINTS_BYTES
from dimacq.services.lab import Lab

__all__ = ["create_app"]

log = logging.getLogger(__name__)

_SAFE_METHODS = frozenset({"GET", "HEAD", "OPTIONS"})

ERROR_RESPONSES: dict[int | str, dict[str, Any]] = {
    400: {"model": ErrorBody, "description": "unusable data (the message names the item)"},
    401: {"model": ErrorBody, "description": "missing or wrong token (state-changing calls)"},
    404: {"model": ErrorBody, "description": "no such item"},
    409: {"model": ErrorBody, "description": "the request does not fit the device or job state"},
    413: {"model": ErrorBody, "description": "request body larger than the configured limit"},
    421: {"model": ErrorBody, "description": "the Host header does not name this service"},
    422: {"model": ErrorBody, "description": "invalid request (the message names the field)"},
    503: {"model": ErrorBody, "description": "device unavailable"},
}


class TokenMiddleware:
    """Refuse state-changing calls under ``/api`` without the token (before any body parsing);
    with ``protect_reads`` (bound to a non-loopback address) every call under ``/api`` but
    OPTIONS."""

    def __init__(self, app: ASGIApp, token: str, protect_reads: bool = False) -> None:
        self.app = app
        self.token = token.encode()
        self.protected = frozenset({"OPTIONS"} if protect_reads else _SAFE_METHODS)

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if (
            scope["type"] == "http"
            and scope["path"] == "/api/status"
            and scope["method"] == "GET"
            and "GET" in self.protected
        ):
            # the poll of every client during acquisitions: answered here, from memory, without
            # routing or dependency resolution (same body as the documented route)
            body = json.dumps(scope["app"].state.lab.status().to_json()).encode()
            await send(
                {
                    "type": "http.response.start",
                    "status": 200,
                    "headers": [
                        (b"content-type", b"application/json"),
                        (b"content-length", str(len(body)).encode()),
                    ],
                }
            )
            await send({"type": "http.response.body", "body": body})
            return
        if (
            scope["type"] == "http"
            and scope["method"] not in self.protected
            and scope["path"].startswith("/api")
        ):
            given = b""
            for k, v in scope.get("headers", []):
                if k == b"authorization" and v[:7].lower() == b"bearer ":
                    given = v[7:].strip()
                elif k == b"x-dimacq-token":
                    given = v.strip()
            if not given or not secrets.compare_digest(given, self.token):
                body = json.dumps(
                    {
                        "detail": "this call needs the token: send "
                        "'Authorization: Bearer <token>' (see <data_dir>/token or DIMACQ_TOKEN)",
                        "field": "Authorization",
                        "errors": [],
                    }
                ).encode()
                await send(
                    {
                        "type": "http.response.start",
                        "status": 401,
                        "headers": [
                            (b"content-type", b"application/json"),
                            (b"content-length", str(len(body)).encode()),
                            (b"www-authenticate", b"Bearer"),
                        ],
                    }
                )
                await send({"type": "http.response.body", "body": body})
                return
        await self.app(scope, receive, send)


def _public(text: str) -> str:
    """``text`` without server paths (:func:`dimacq.api.public.public`)."""
    return public(text)


def _error(
    status: int, detail: str, field: str | None = None, errors: list[Any] | None = None
) -> JSONResponse:
    return JSONResponse(
        status_code=status,
        content={"detail": _public(detail), "field": field, "errors": errors or []},
    )


def _loc(loc: tuple[Any, ...] | list[Any]) -> str:
    out = ""
    for p in loc:
        if isinstance(p, int):
            out += f"[{p}]"
        else:
            out += ("." if out else "") + str(p)
    return out


def _allowed_methods(app: FastAPI, path: str) -> set[str]:
    """Methods the spec documents for ``path`` (static paths win over templated ones)."""
    static: set[str] = set()
    templated: set[str] = set()
    for template, ops in app.openapi().get("paths", {}).items():
        rx = "^" + re.sub(r"\\\{[^/]+?\\\}", "[^/]+", re.escape(template)) + "$"
        if template == path:
            static |= {m.upper() for m in ops}
        elif "{" in template and re.match(rx, path):
            templated |= {m.upper() for m in ops}
    return static or templated


def _path_value(req: Request, name: str) -> str:
    value = str(req.path_params.get(name, "?"))
    unit = "digits" if value.isdigit() else "characters"
    shown = value if len(value) <= 40 else f"{value[:12]}…({len(value)} {unit})"
    return shown if value.isdigit() or value == "?" else repr(shown)


_ITEM = re.compile(r"item '([^']+)'")


def _field_of(req: Request, err: Exception) -> str | None:
    """The field a refusal of the service names: the item the message names inside the body
    (``body.responses.0.position_m``), else the body (a file or a JSON body refused as a whole),
    else none (a state of the stand, not a field of the request)."""
    given = getattr(err, "field", None)
    if isinstance(given, str):
        return given
    if req.method in ("POST", "PUT", "PATCH"):
        m = _ITEM.search(str(err))
        return f"body.{m.group(1)}" if m else "body"
    return None


def _install_error_handlers(app: FastAPI) -> None:
    @app.exception_handler(RequestValidationError)
    async def _validation(req: Request, err: RequestValidationError) -> JSONResponse:
        errs: list[dict[str, Any]] = []
        for e in err.errors():
            loc = tuple(e.get("loc", ()))
            errs.append(
                {
                    "loc": [str(p) for p in loc],
                    "field": _loc(loc),
                    "msg": str(e.get("msg", "")),
                    "type": str(e.get("type", "")),
                }
            )
        field = errs[0]["field"] if errs else None
        if errs and all(e["loc"][:1] == ["path"] for e in errs):
            # an id out of range names no item: the same answer as an id that is not stored
            name = errs[0]["loc"][-1]
            form = (
                "job ids are letters, digits, '-' and '_'"
                if name == "job_id"
                else f"ids are 1..{MAX_ID}"
            )
            return _error(
                404,
                f"{name} {_path_value(req, name)} does not exist ({form}); list the "
                "collection to find its id",
                field,
                errs,
            )
        detail = "; ".join(f"{e['field']}: {e['msg']}" for e in errs) or "invalid request"
        return _error(422, detail, field, errs)

    @app.exception_handler(StarletteHTTPException)
    async def _http(req: Request, err: StarletteHTTPException) -> JSONResponse:
        headers = dict(err.headers or {})
        if err.status_code == 405:
            # Starlette lists only the first matching route's methods; list every route's
            allowed = _allowed_methods(req.app, req.url.path)
            if allowed:
                headers["Allow"] = ", ".join(sorted(allowed))
        field = "body" if isinstance(err, BodyTooLarge) else None  # a chunked body too long
        return JSONResponse(
            status_code=err.status_code,
            content={"detail": _public(str(err.detail)), "field": field, "errors": []},
            headers=headers,
        )

    @app.exception_handler(ClientDisconnect)
    async def _gone(_req: Request, _err: ClientDisconnect) -> JSONResponse:
        # the client closed (or stalled and was closed: dimacq.api.protocol) before its body
        # was complete; nobody reads this answer, but it is not a server error in the log
        return _error(400, "the client closed the connection before the body was complete")

    @app.exception_handler(DataError)
    async def _data(req: Request, err: DataError) -> JSONResponse:
        return _error(400, str(err), _field_of(req, err))

    @app.exception_handler(SetupError)
    async def _setup(req: Request, err: SetupError) -> JSONResponse:
        return _error(422, str(err), _field_of(req, err))

    @app.exception_handler(SolverError)
    async def _solver(req: Request, err: SolverError) -> JSONResponse:
        return _error(422, str(err), _field_of(req, err))

    @app.exception_handler(DeviceStateError)
    async def _state(_req: Request, err: DeviceStateError) -> JSONResponse:
        return _error(409, str(err))

    @app.exception_handler(DeviceError)
    async def _device(_req: Request, err: DeviceError) -> JSONResponse:
        return _error(503, str(err))


def _custom_openapi(app: FastAPI, protect_reads: bool) -> Any:
    def openapi() -> dict[str, Any]:
        if app.openapi_schema:
            return app.openapi_schema
        schema = get_openapi(
            title=app.title, version=app.version, description=app.description, routes=app.routes
        )
        comps = schema.setdefault("components", {})
        add_body_components(comps)
        comps.setdefault("securitySchemes", {})["bearer"] = {"type": "http", "scheme": "bearer"}
        for path, ops in schema.get("paths", {}).items():
            for method, op in ops.items():
                guarded = protect_reads and method.upper() != "OPTIONS"
                if (guarded or method.upper() not in _SAFE_METHODS) and path.startswith("/api"):
                    op["security"] = [{"bearer": []}]
                # the default 422 schema is replaced by ErrorBody everywhere
        app.openapi_schema = schema
        return schema

    return openapi


def allowed_hosts(settings: Settings) -> frozenset[str] | None:
    """Names the Host header may carry: loopback names, the bound host, ``allowed_hosts``;
    None (not checked) when bound to a wildcard address with no ``allowed_hosts``."""
    if is_wildcard(settings.host) and not settings.allowed_hosts:
        return None
    names = set(LOOPBACK_NAMES) | set(settings.allowed_hosts)
    if not is_wildcard(settings.host):
        names.add(settings.host.strip().strip("[]").lower())
    return frozenset(names)


STATIC_DIR = Path(__file__).with_name("static")


#: Content-Security-Policy of the lab page and the report: scripts, styles and connections to
#: this service only (no inline script, nothing from elsewhere); images also from ``blob:`` (the
#: solution's figure) and ``data:`` (the empty icon); never framed (clickjacking).
PAGE_CSP = (
    "default-src 'self'; script-src 'self'; style-src 'self'; img-src 'self' blob: data:; "
    "connect-src 'self'; object-src 'none'; base-uri 'none'; form-action 'self'; "
    "frame-ancestors 'none'"
)

#: Headers of the lab page and the report.
PAGE_HEADERS = {
    "Cache-Control": "no-cache",
    "Content-Security-Policy": PAGE_CSP,
    "X-Frame-Options": "DENY",
    "X-Content-Type-Options": "nosniff",
    "Referrer-Policy": "no-referrer",
}

#: Where ``/docs`` takes Swagger UI's script and style from: the ``swagger-ui-bundle`` package,
#: served at :data:`DOCS_ASSETS` (FastAPI's default fetches them from a CDN).
DOCS_ASSETS = "/docs-assets"
#: The spec as ``/docs`` reads it (see :func:`_mount_docs`).
DOCS_SPEC = "/docs/openapi.json"


def _mount_page(app: FastAPI) -> None:
    """The lab page: ``/`` (``static/index.html``) and its assets under ``/static`` (package data,
    nothing fetched from elsewhere), with :data:`PAGE_HEADERS`."""

    @app.get("/", include_in_schema=False)
    async def index() -> FileResponse:
        return FileResponse(STATIC_DIR / "index.html", headers=PAGE_HEADERS)

    @app.get("/report", include_in_schema=False)
    async def report() -> FileResponse:
        return FileResponse(STATIC_DIR / "report.html", headers=PAGE_HEADERS)

    app.mount("/static", PageStaticFiles(directory=STATIC_DIR), name="static")
    mount_manual(app, PAGE_HEADERS)


class PageStaticFiles(StaticFiles):
    """The page's assets; an HTML file among them (``/static/index.html``) is the page itself
    and gets :data:`PAGE_HEADERS` (CSP, framing, referrer) as ``/`` does; every asset is
    ``nosniff``."""

    async def get_response(self, path: str, scope: Scope) -> Response:
        response = await super().get_response(path, scope)
        if response.headers.get("content-type", "").startswith("text/html"):
            response.headers.update(PAGE_HEADERS)
        else:
            response.headers["X-Content-Type-Options"] = "nosniff"
        return response


def _mount_docs(app: FastAPI) -> None:
    """``/docs``: Swagger UI from local assets (``swagger-ui-bundle``), never framed; the lab
    PC may have no internet, and a CDN script would run with the page's access."""
    from swagger_ui_bundle import swagger_ui_path

    app.mount(DOCS_ASSETS, StaticFiles(directory=swagger_ui_path), name="docs-assets")

    @app.get(DOCS_SPEC, include_in_schema=False)
    async def docs_spec() -> JSONResponse:
        # the package's Swagger UI (4.15) refuses an "openapi: 3.1.0" document ("does not
        # specify a valid version field"); FastAPI's spec is 3.1 and stays so at /openapi.json.
        # The page gets it labelled 3.0.3: it renders every operation and its schemas (tuples'
        # prefixItems show as plain arrays)
        return JSONResponse({**app.openapi(), "openapi": "3.0.3"})

    @app.get("/docs", include_in_schema=False)
    async def docs() -> HTMLResponse:
        page = get_swagger_ui_html(
            openapi_url=DOCS_SPEC,
            title=f"{app.title} API",
            swagger_js_url=f"{DOCS_ASSETS}/swagger-ui-bundle.js",
            swagger_css_url=f"{DOCS_ASSETS}/swagger-ui.css",
            swagger_favicon_url=f"{DOCS_ASSETS}/favicon-32x32.png",
        )
        page.headers["X-Frame-Options"] = "DENY"
        return page


#: What the lab page reads when it opens (``static/*.js`` at load), answered once in-process by
#: :func:`warm_up` before the service says it is ready. A path no route has comes first: matching
#: it walks every route, which builds FastAPI's per-route state (models, dependencies) that it
#: otherwise builds on the first request that walks past each route (~1 s on this machine).
PAGE_FIRST_READS = (
    "/__warm_up__",
    "/",
    "/api/status",
    "/api/tests?archived=false",
    "/api/setups",
    "/api/simulation/article",
    "/api/frfs",
    "/api/solutions",
    "/api/rig",
    "/api/digitizer/reference-nodes",
    "/api/calibrations",
)


class _WarmUpReceive:
    """ASGI ``receive`` of a warm-up GET: the (empty) body once, then the client is gone."""

    def __init__(self) -> None:
        self.asked = False

    async def __call__(self) -> dict[str, Any]:
        if not self.asked:
            self.asked = True
            return {"type": "http.request", "body": b"", "more_body": False}
        return {"type": "http.disconnect"}


async def _drop(_message: Any) -> None:
    """ASGI ``send`` of a warm-up GET: the answer is not needed."""


async def warm_up(app: ASGIApp, token: str, paths: tuple[str, ...] = PAGE_FIRST_READS) -> float:
    """GET ``paths`` through the whole app (middleware included) without a socket, answers
    dropped; returns the time it took, s. Reads only: no GET changes anything (see
    ``tests/api/test_hardening.py``). What the first visitor would otherwise wait for: FastAPI's
    lazily built route state, the first database queries, pydantic's first serialisations, the
    simulated article's geometry."""
    t0 = time.perf_counter()
    for target in paths:
        path, _, query = target.partition("?")
        scope: dict[str, Any] = {
            "type": "http",
            "asgi": {"version": "3.0", "spec_version": "2.4"},
            "http_version": "1.1",
            "method": "GET",
            "scheme": "http",
            "path": path,
            "raw_path": path.encode(),
            "query_string": query.encode(),
            "root_path": "",
            "headers": [(b"host", b"127.0.0.1"), (b"authorization", f"Bearer {token}".encode())],
            "client": ("127.0.0.1", 0),
            "server": ("127.0.0.1", 0),
        }

        try:
            await app(scope, _WarmUpReceive(), _drop)
        except Exception as err:  # a read that fails here fails for the page too, and says so
            log.warning("warm-up GET %s: %s", target, err)
    return time.perf_counter() - t0


def create_app(
    settings: Settings | None = None,
    *,
    lab: Lab | None = None,
    on_ready: Callable[[], None] | None = None,
) -> FastAPI:
    """Build the app. ``lab`` may be given (tests); otherwise the lifespan opens one from
    ``settings`` and closes it at shutdown. ``on_ready`` (``dimacq serve``): the lab is open and
    the page's first reads have been answered once (:func:`warm_up`); called just before the
    server accepts connections, so a visitor who follows what it prints does not wait for them."""
    settings = settings or load_settings()
    token = settings.resolved_token()

    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        owned = lab is None
        try:
            app.state.lab = lab if lab is not None else Lab(settings)
        except DimacqError as err:
            # a refusal to start (stand already served, database unreachable, ...): the
            # server says it in one line (dimacq.api.server.serve), not as a traceback
            app.state.startup_error = err
            raise
        if on_ready is not None:
            took = await warm_up(app, token)
            log.info("warm-up: the page's first reads answered in %.2f s", took)
        # Everything loaded so far (numpy, scipy, SQLAlchemy, pydantic models, ...) lives as long
        # as the service: move it out of the collector's reach, so a full collection during an
        # acquisition walks only new objects instead of stalling every request for ~100 ms.
        gc.collect()
        gc.freeze()
        if on_ready is not None:
            on_ready()
        try:
            yield
        finally:
            if owned:
                app.state.lab.close()

    app = FastAPI(
        title="dimacq",
        version="0.1.0",
        description="Rigid-body inertia properties by the Dynamic Inertia Method: the lab service.",
        lifespan=lifespan,
        responses=ERROR_RESPONSES,
        docs_url=None,  # served from local assets (_mount_docs)
        redoc_url=None,  # ReDoc has no local assets here; /docs is the documentation
    )
    app.state.settings = settings
    app.state.token = token
    hide_root(settings.data_dir, "data")
    hide_root(settings.data_dir / "tmp", "upload", keep_tail=False)  # the spool (Lab)
    hide_root(settings.rig_path.parent, "rig")
    _install_error_handlers(app)
    for r in (
        status,
        tests,
        devices,
        digitizer,
        setups,
        acquisitions,
        frfs,
        calibrations,
        solutions,
        sensitivity,
        plans,
        photo_geometry,
        jobs,
        simulation,
        rig,
    ):
        app.include_router(r.router)
    _mount_page(app)
    _mount_docs(app)
    # added innermost first: Host check → token → body limit → routes
    app.add_middleware(
        BodyLimitMiddleware,
        max_body_bytes=settings.max_body_bytes,
        max_upload_bytes=settings.max_upload_bytes,
        upload_paths=UPLOAD_PATHS,
        path_limits={"/api/digitizer/points/import": (MAX_POINTS_BYTES, "MAX_POINTS_BYTES")},
    )
    app.add_middleware(TokenMiddleware, token=token, protect_reads=not is_loopback(settings.host))
    app.add_middleware(HostCheckMiddleware, allowed=allowed_hosts(settings))
    if settings.cors_origins:  # outermost, so a 401 still carries the CORS headers
        app.add_middleware(
            CORSMiddleware,
            allow_origins=list(settings.cors_origins),
            allow_methods=["*"],
            allow_headers=["Authorization", "Content-Type", "X-Dimacq-Token"],
        )
    app.openapi = _custom_openapi(  # type: ignore[method-assign]
        app, protect_reads=not is_loopback(settings.host)
    )
    return app
