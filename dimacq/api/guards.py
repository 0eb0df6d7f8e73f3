"""ASGI guards in front of the app: the Host header and the request body size.

- :class:`HostCheckMiddleware` refuses (421) a request whose ``Host`` names something other than
  the names the service is bound to or configured for. A web page the lab PC's browser loads
  from ``evil.example`` can make that name resolve to 127.0.0.1 (DNS rebinding) and then call the
  service as "same origin"; its requests still carry ``Host: evil.example`` and stop here.
  Accepted: the loopback names (``localhost``, ``127.0.0.1``, ``::1``), the bound host, and
  ``allowed_hosts`` from the settings. Bound to a wildcard address (``0.0.0.0``, ``::``) with no
  ``allowed_hosts``, the names the machine is reached by are unknown and the Host header is not
  checked (every call, reads included, needs the token there).
- :class:`BodyLimitMiddleware` refuses (413) a body larger than ``max_body_bytes`` (JSON
  requests) or ``max_upload_bytes`` (file uploads: the paths in
  :data:`dimacq.api.routers._common.UPLOAD_PATHS`): from ``Content-Length`` before any byte is
  read, and by counting the bytes of a chunked body as they arrive, so at most the limit plus
  one chunk is ever held in memory.

Both answer with the API's :class:`~dimacq.api.schemas.ErrorBody` JSON naming the header.
"""

from __future__ import annotations

import ipaddress
import json
from collections.abc import Iterable, Mapping

from starlette.exceptions import HTTPException
from starlette.types import ASGIApp, Message, Receive, Scope, Send

__all__ = [
    "LOOPBACK_NAMES",
    "BodyLimitMiddleware",
    "BodyTooLarge",
    "HostCheckMiddleware",
    "host_name",
    "is_loopback",
    "is_wildcard",
    "send_error",
]

LOOPBACK_NAMES = frozenset({"localhost", "127.0.0.1", "::1"})


def is_loopback(host: str) -> bool:
    """``host`` (a bind address or name) reaches this machine only (127.0.0.0/8, ::1,
    ``localhost``)."""
    h = host.strip().strip("[]").lower()
    if h == "localhost" or h.endswith(".localhost"):
        return True
    try:
        return ipaddress.ip_address(h).is_loopback
    except ValueError:
        return False


def is_wildcard(host: str) -> bool:
    """``host`` binds every interface (``0.0.0.0``, ``::``, empty)."""
    h = host.strip().strip("[]")
    if not h:
        return True
    try:
        return ipaddress.ip_address(h).is_unspecified
    except ValueError:
        return False


def host_name(value: str) -> str:
    """The name in a ``Host`` header value, without the port (``[::1]:8765`` → ``::1``)."""
    v = value.strip().lower()
    if v.startswith("["):
        return v[1 : v.find("]")] if "]" in v else v[1:]
    if v.count(":") == 1:
        return v.split(":", 1)[0]
    return v  # a bare name, or an IPv6 address without brackets or port


async def send_error(
    send: Send,
    status: int,
    detail: str,
    field: str | None,
    headers: Iterable[tuple[bytes, bytes]] = (),
) -> None:
    """Answer with an :class:`~dimacq.api.schemas.ErrorBody` JSON (used before routing)."""
    body = json.dumps({"detail": detail, "field": field, "errors": []}).encode()
    await send(
        {
            "type": "http.response.start",
            "status": status,
            "headers": [
                (b"content-type", b"application/json"),
                (b"content-length", str(len(body)).encode()),
                *headers,
            ],
        }
    )
    await send({"type": "http.response.body", "body": body})


class HostCheckMiddleware:
    """400 for more than one ``Host`` header (only the first was checked: ``Host: 127.0.0.1``
    then ``Host: evil.example`` passed); 421 for a ``Host`` header naming none of ``allowed``
    (names without ports, lower case). ``allowed=None`` checks the names not. A request without
    a Host header (HTTP/1.0 tools; browsers always send one) passes."""

    def __init__(self, app: ASGIApp, allowed: frozenset[str] | None) -> None:
        self.app = app
        self.allowed = allowed

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] in ("http", "websocket"):
            hosts = [v for k, v in scope.get("headers", []) if k == b"host"]
            if len(hosts) > 1:
                # which one names the service? Proxies and the app may read different ones
                # (RFC 9112 §3.2: a request with more than one Host is answered 400)
                await send_error(
                    send,
                    400,
                    f"Host: sent {len(hosts)} times; send one Host header",
                    "Host",
                    [(b"connection", b"close")],
                )
                return
        if self.allowed is not None and scope["type"] in ("http", "websocket"):
            for k, v in scope.get("headers", []):
                if k == b"host":
                    name = host_name(v.decode("latin-1"))
                    if name not in self.allowed:
                        await send_error(
                            send,
                            421,
                            f"Host {name!r} is not a name of this service (accepted: "
                            f"{', '.join(sorted(self.allowed))}); call it by one of those, or "
                            "add the name to allowed_hosts (DIMACQ_ALLOWED_HOSTS)",
                            "Host",
                        )
                        return
                    break
        await self.app(scope, receive, send)


class BodyTooLarge(HTTPException):
    """Raised from ``receive`` when a chunked body passes the limit (answered 413 by the app's
    HTTP error handler, or by :class:`BodyLimitMiddleware` if it escapes)."""

    def __init__(self, limit: int, setting: str) -> None:
        super().__init__(status_code=413, detail=_too_large(limit, setting, "body"))


def _too_large(limit: int, setting: str, field: str = "Content-Length") -> str:
    """The 413 message; ``setting`` a lower-case setting (raised through ``DIMACQ_<SETTING>``)
    or an upper-case limit of an import kind (the file is to be split)."""
    fix = (
        f"raise {setting} (DIMACQ_{setting.upper()})"
        if setting.islower()
        else f"split the file (the {setting} limit)"
    )
    return f"{field}: the request body is larger than {limit} bytes; send less, or {fix}"


class BodyLimitMiddleware:
    """413 for bodies over ``max_body_bytes`` (``max_upload_bytes`` on ``upload_paths``; the
    lower limit of ``path_limits`` on an import kind that has one)."""

    def __init__(
        self,
        app: ASGIApp,
        max_body_bytes: int,
        max_upload_bytes: int,
        upload_paths: frozenset[str],
        path_limits: Mapping[str, tuple[int, str]] | None = None,
    ) -> None:
        self.app = app
        self.max_body_bytes = max_body_bytes
        self.max_upload_bytes = max_upload_bytes
        self.upload_paths = upload_paths
        self.path_limits = dict(path_limits or {})

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        if scope["path"] in self.upload_paths:
            limit, setting = self.max_upload_bytes, "max_upload_bytes"
        else:
            limit, setting = self.max_body_bytes, "max_body_bytes"
        if scope["path"] in self.path_limits:  # an import kind with its own, lower limit
            limit, setting = min((limit, setting), self.path_limits[scope["path"]])
        for k, v in scope.get("headers", []):
            if k == b"content-length":
                try:
                    declared = int(v)
                except ValueError:
                    await send_error(
                        send, 400, "Content-Length: not a number of bytes", "Content-Length"
                    )
                    return
                if declared > limit:
                    # refused before a byte of the body is read; the connection is closed
                    # after the answer (the unread body cannot be skipped cheaply)
                    await send_error(
                        send,
                        413,
                        _too_large(limit, setting),
                        "Content-Length",
                        [(b"connection", b"close")],
                    )
                    return
        seen = 0
        started = False

        async def counted_receive() -> Message:
            nonlocal seen
            message = await receive()
            if message["type"] == "http.request":
                seen += len(message.get("body", b""))
                if seen > limit:
                    raise BodyTooLarge(limit, setting)
            return message

        async def tracked_send(message: Message) -> None:
            nonlocal started
            if message["type"] == "http.response.start":
                started = True
            await send(message)

        try:
            await self.app(scope, counted_receive, tracked_send)
        except BodyTooLarge as err:
            if started:
                raise
            await send_error(send, 413, str(err.detail), "body")
