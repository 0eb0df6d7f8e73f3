"""Run the app with uvicorn: in the foreground (``dimacq serve``) or on a background thread
on a loopback port (``dimacq demo``, tests, benchmarks)."""

from __future__ import annotations

import errno
import logging
import socket
import sys
import threading
import time
from types import TracebackType
from typing import Any

import uvicorn
from fastapi import FastAPI
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from dimacq.api.protocol import DEFAULT_LIMITS, HttpLimits, limited_protocol
from dimacq.errors import DeviceError, SetupError

__all__ = [
    "BackgroundServer",
    "bind_socket",
    "free_port",
    "serve",
    "server_config",
    "warm_routes",
]


def free_port(host: str = "127.0.0.1") -> int:
    """A free TCP port on ``host`` (the OS picks it)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind((host, 0))
        return int(s.getsockname()[1])


#: GIL switch interval of the service process, s. Acquisition threads are CPU-bound (decoding,
#: checks); with Python's default 5 ms the event loop can wait that long for the GIL at every
#: step of a request, which is what status pollers would see as latency.
SWITCH_INTERVAL_S = 0.0005


def bind_socket(host: str, port: int) -> socket.socket:
    """A TCP socket bound to ``host:port`` (listening starts when the server runs on it).

    Raises
    ------
    SetupError
        The address cannot be bound (port in use, address not on this machine, no permission);
        the message names ``--host``/``--port``.
    """
    try:
        infos = socket.getaddrinfo(
            host or None, port, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE
        )
    except socket.gaierror as err:
        raise SetupError(f"--host {host}: not an address of this machine ({err.strerror})") from err
    family, kind, proto, _, addr = infos[0]
    sock = socket.socket(family, kind, proto)
    try:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        sock.bind(addr)
    except OSError as err:
        sock.close()
        if err.errno == errno.EADDRINUSE:
            raise SetupError(
                f"--port {port}: {host}:{port} is already in use (another dimacq serve?); "
                "stop that process or choose another port with --port"
            ) from err
        raise SetupError(
            f"--host {host} --port {port}: cannot bind ({err.strerror}); choose another "
            "--host or --port"
        ) from err
    sock.set_inheritable(True)
    return sock


def warm_routes(app: FastAPI) -> None:
    """Build FastAPI's per-route state now rather than on the first request.

    FastAPI (0.16x) builds the routes of an included router (a pydantic ``TypeAdapter`` per
    parameter and response, ~0.5 s for this app) when the first request reaches that router,
    on the event loop: the first calls after ``dimacq serve`` started stalled every other one,
    ``/api/status`` 0.6–0.8 s. Walks the routers' ``effective_candidates`` where the installed
    FastAPI has them; nothing to do where routes are built when included.
    """
    todo = list(app.router.routes)
    while todo:
        route = todo.pop()
        build = getattr(route, "effective_candidates", None)
        if callable(build):
            todo.extend(build())
        low = getattr(route, "effective_low_priority_routes", None)
        if callable(low):
            low()


def serve(
    app: FastAPI, host: str, port: int, log_level: str = "info", sock: socket.socket | None = None
) -> None:
    """Serve in the foreground until interrupted (this process is the service), on ``sock``
    (from :func:`bind_socket`) or on a socket bound here; the routes are built first
    (:func:`warm_routes`)."""
    sys.setswitchinterval(SWITCH_INTERVAL_S)
    warm_routes(app)
    sock = sock or bind_socket(host, port)
    # listening from now on: a client that comes while the lab opens waits in the backlog
    # (answered once it is open) instead of being refused
    sock.listen(2048)
    quiet = _QuietRefusal(app)
    uvicorn_log = logging.getLogger("uvicorn.error")
    uvicorn_log.addFilter(quiet.filter)
    try:
        uvicorn.Server(server_config(quiet, log_level=log_level)).run(sockets=[sock])
    except SystemExit:  # uvicorn exits 3 when the startup failed
        if not quiet.refused():
            raise
    finally:
        uvicorn_log.removeFilter(quiet.filter)
    refused = getattr(app.state, "startup_error", None)
    if refused is not None:
        raise refused  # dimacq serve: one line, exit 2


class _QuietRefusal:
    """The app, with a refusal to start (a :class:`~dimacq.errors.DimacqError` of the lifespan,
    kept in ``app.state.startup_error``) left to the caller to say in one line: uvicorn logged
    the lifespan's whole traceback and "Application startup failed. Exiting.", then returned
    as if all were well."""

    def __init__(self, app: FastAPI) -> None:
        self.app = app

    def refused(self) -> bool:
        return getattr(self.app.state, "startup_error", None) is not None

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "lifespan":
            await self.app(scope, receive, send)
            return

        async def without_traceback(message: Message) -> None:
            if message["type"] == "lifespan.startup.failed" and self.refused():
                message = {**message, "message": ""}  # uvicorn logs a non-empty message
            await send(message)

        await self.app(scope, receive, without_traceback)

    def filter(self, record: logging.LogRecord) -> bool:
        return not (self.refused() and record.levelno >= logging.ERROR)


def server_config(app: ASGIApp, limits: HttpLimits = DEFAULT_LIMITS, **kw: Any) -> uvicorn.Config:
    """uvicorn's configuration of the service: HTTP/1.1 through
    :class:`~dimacq.api.protocol.LimitedHttpToolsProtocol` (request heads at most
    ``limits.max_head_bytes``, complete within ``limits.head_timeout_s``; bodies never idle
    longer than ``limits.body_idle_timeout_s``), keep-alive ``limits.keep_alive_s``, no access
    log, no ``server`` header (it names uvicorn's version)."""
    return uvicorn.Config(
        app,
        http=limited_protocol(limits),
        timeout_keep_alive=max(1, round(limits.keep_alive_s)),
        access_log=False,
        server_header=False,
        **kw,
    )


class BackgroundServer:
    """uvicorn on a thread; ``with BackgroundServer(app) as srv: httpx.get(srv.url + ...)``."""

    def __init__(
        self,
        app: FastAPI,
        host: str = "127.0.0.1",
        port: int | None = None,
        limits: HttpLimits = DEFAULT_LIMITS,
    ) -> None:
        self.app = app
        self.host = host
        self.port = port or free_port(host)
        config = server_config(
            app, limits, host=host, port=self.port, log_level="warning", lifespan="on"
        )
        self.server = uvicorn.Server(config)
        self.thread = threading.Thread(
            target=self.server.run, name=f"dimacq-uvicorn-{self.port}", daemon=True
        )

    @property
    def url(self) -> str:
        return f"http://{self.host}:{self.port}"

    def start(self, timeout_s: float = 30.0) -> None:
        self.thread.start()
        deadline = time.monotonic() + timeout_s
        while not self.server.started:
            if not self.thread.is_alive() or time.monotonic() > deadline:
                self.stop()
                refused = getattr(self.app.state, "startup_error", None)
                if refused is not None:
                    raise refused
                raise DeviceError(f"the API server on {self.url} did not start")
            time.sleep(0.01)

    def stop(self, timeout_s: float = 30.0) -> None:
        self.server.should_exit = True
        if self.thread.is_alive():
            self.thread.join(timeout_s)

    def __enter__(self) -> BackgroundServer:
        self.start()
        return self

    def __exit__(
        self, et: type[BaseException] | None, ev: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.stop()
