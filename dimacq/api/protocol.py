"""uvicorn's HTTP/1.1 protocol (httptools) with limits on what a client may hold.

uvicorn bounds none of these with httptools (its ``h11_max_incomplete_event_size`` applies to
h11 only), and its keep-alive timer runs only between requests and stops at the first byte:

- **header size**: a request head (request line and headers) larger than
  :attr:`HttpLimits.max_head_bytes` is answered 431 and the connection closed (a 1 MB header
  was read whole and answered 200);
- **slow heads**: a head not complete :attr:`HttpLimits.head_timeout_s` after the connection
  opened or the previous response ended (a header trickled byte by byte, or a connection that
  never sends) is answered 408 (nothing if no byte came) and closed; it was held forever;
- **stalled bodies**: a body whose next bytes do not come within
  :attr:`HttpLimits.body_idle_timeout_s` (shorter than its ``Content-Length``, or a stalled
  upload) is answered 408 and closed; it was held forever, the handler waiting on it.

The keep-alive time between requests stays uvicorn's ``timeout_keep_alive``
(:attr:`HttpLimits.keep_alive_s`). Answers are the API's JSON error body naming the limit.
"""

from __future__ import annotations

import asyncio
import json
from dataclasses import dataclass
from typing import Any

from uvicorn.protocols.http.httptools_impl import HttpToolsProtocol

__all__ = ["DEFAULT_LIMITS", "HttpLimits", "LimitedHttpToolsProtocol", "limited_protocol"]

_REASONS = {408: b"Request Timeout", 431: b"Request Header Fields Too Large"}

#: How long a refused connection is still read (and the bytes dropped) before it is closed, s.
LINGER_S = 2.0


@dataclass(frozen=True)
class HttpLimits:
    """What one HTTP connection may hold (see the module docstring)."""

    #: Largest request line plus headers, bytes (browsers send ~1-2 kB; a token ~40 B).
    max_head_bytes: int = 64 * 1024
    #: Longest wait for a complete request head, s.
    head_timeout_s: float = 10.0
    #: Longest wait for the next bytes of a body, s (a 256 MiB upload at 1 MB/s never waits).
    body_idle_timeout_s: float = 30.0
    #: Idle time between requests before the connection is closed, s (uvicorn's default).
    keep_alive_s: float = 5.0


DEFAULT_LIMITS = HttpLimits()


class LimitedHttpToolsProtocol(HttpToolsProtocol):
    """:class:`HttpToolsProtocol` within :attr:`limits` (a class attribute, set by
    :func:`limited_protocol`: uvicorn makes the protocol from its class)."""

    limits: HttpLimits = DEFAULT_LIMITS

    def __init__(self, *args: Any, **kw: Any) -> None:
        super().__init__(*args, **kw)
        self._reading_head = True
        self._head_bytes = 0
        self._refused = False
        self._timer: asyncio.TimerHandle | None = None

    # -- timers -------------------------------------------------------------------------------
    def _arm(self, delay_s: float, status: int, detail: str) -> None:
        self._disarm()
        self._timer = self.loop.call_later(delay_s, self._expired, status, detail)

    def _disarm(self) -> None:
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None

    def _expired(self, status: int, detail: str) -> None:
        self._timer = None
        if self.transport is None or self.transport.is_closing():
            return
        if self._reading_head and self._head_bytes == 0:
            self.transport.close()  # an idle connection: nothing to answer
            return
        self._refuse(status, detail)

    def _refuse(self, status: int, detail: str) -> None:
        """Answer ``status`` with the API's error body and close; the request (if one was
        started) sees the client gone."""
        self._refused = True
        self._disarm()
        self.flow.resume_reading()  # keep reading (and dropping) until the close
        body = json.dumps({"detail": detail, "field": "headers", "errors": []}).encode()
        self.transport.write(
            b"HTTP/1.1 %d %s\r\ncontent-type: application/json\r\ncontent-length: %d\r\n"
            b"connection: close\r\n\r\n%s" % (status, _REASONS[status], len(body), body)
        )
        if self.cycle is not None and not self.cycle.response_complete:
            self.cycle.disconnected = True
            self.cycle.message_event.set()
        if self.transport.can_write_eof():
            # a lingering close: the client may still be sending (a 1 MB header); closing now
            # would reset the connection and lose the answer. Stop writing, read and drop what
            # still comes for LINGER_S, then close.
            self.transport.write_eof()
            self._timer = self.loop.call_later(LINGER_S, self.transport.close)
        else:
            self.transport.close()

    def _head_deadline(self) -> None:
        self._reading_head = True
        self._head_bytes = 0
        self._arm(
            self.limits.head_timeout_s,
            408,
            f"the request head (request line and headers) was not complete within "
            f"{self.limits.head_timeout_s:g} s; send it at once",
        )

    # -- protocol -----------------------------------------------------------------------------
    def connection_made(self, transport: asyncio.Transport) -> None:  # type: ignore[override]
        super().connection_made(transport)
        self._head_deadline()

    def connection_lost(self, exc: Exception | None) -> None:
        self._disarm()
        super().connection_lost(exc)

    def data_received(self, data: bytes) -> None:
        if self._refused:
            return
        if self._reading_head:
            self._head_bytes += len(data)
        super().data_received(data)
        if self._refused or self.transport.is_closing():
            return
        if self._reading_head and self._head_bytes > self.limits.max_head_bytes:
            self._too_large(self._head_bytes)

    def _too_large(self, size: int) -> None:
        self._refuse(
            431,
            f"the request head (request line and headers) has more than "
            f"{self.limits.max_head_bytes} bytes ({size} received); send shorter headers",
        )

    def on_header(self, name: bytes, value: bytes) -> None:
        if not self._refused:
            super().on_header(name, value)

    def on_headers_complete(self) -> None:
        if self._refused:
            return
        size = len(self.url) + sum(len(n) + len(v) + 4 for n, v in self.headers)
        if size > self.limits.max_head_bytes:  # a whole head in one read
            self._too_large(size)
            return
        self._reading_head = False
        self._arm(self.limits.body_idle_timeout_s, 408, self._stalled_detail())
        super().on_headers_complete()

    def _stalled_detail(self) -> str:
        return (
            f"Content-Length: no bytes of the request body came for "
            f"{self.limits.body_idle_timeout_s:g} s (a body shorter than its Content-Length?); "
            "send the whole body"
        )

    def on_body(self, body: bytes) -> None:
        if self._refused:
            return
        self._arm(self.limits.body_idle_timeout_s, 408, self._stalled_detail())
        super().on_body(body)

    def on_message_complete(self) -> None:
        if self._refused:
            return
        self._disarm()
        super().on_message_complete()

    def on_response_complete(self) -> None:
        super().on_response_complete()
        if not self.transport.is_closing() and not self.pipeline:
            self._head_deadline()


def limited_protocol(limits: HttpLimits = DEFAULT_LIMITS) -> type[LimitedHttpToolsProtocol]:
    """The protocol class to give uvicorn (``Config(http=...)``) for ``limits``."""
    return type("LimitedHttpToolsProtocol", (LimitedHttpToolsProtocol,), {"limits": limits})
