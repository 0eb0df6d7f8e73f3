"""``dimacq serve`` hardening (issue 24): the token printed once, start-up refusals in one line
(exit 2), and uvicorn's limits against slow or oversized clients, on a real server on
127.0.0.1 with raw sockets. Each test failed before its fix."""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import os
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest
from _api_support import TOKEN, make_settings
from _serve_support import Service

from dimacq.api import create_app
from dimacq.api.protocol import DEFAULT_LIMITS, HttpLimits, LimitedHttpToolsProtocol
from dimacq.api.server import BackgroundServer, free_port, server_config
from dimacq.cli.main import main
from dimacq.config import load_settings


@pytest.mark.slow
def test_serve_prints_the_token_once(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """It was printed twice (a "token for ...:" line and the lab page's address): once in the
    address now, the other line says where it is kept."""
    import dimacq.api.server as server

    def fake_serve(app, host, port, log_level="info", sock=None):  # type: ignore[no-untyped-def]
        sock.close()

        async def lifespan() -> None:  # the lab opens, on_ready prints the address, it closes
            async with app.router.lifespan_context(app):
                pass

        asyncio.run(lifespan())

    monkeypatch.setattr(server, "serve", fake_serve)
    monkeypatch.setenv("DIMACQ_TOKEN", TOKEN)
    assert main(["serve", "--port", "0", "--data-dir", str(tmp_path)]) == 0
    out, err = capsys.readouterr()
    assert (out + err).count(TOKEN) == 1, out
    assert f"/#token={TOKEN}" in out
    assert "token for state-changing calls: in DIMACQ_TOKEN" in out
    monkeypatch.delenv("DIMACQ_TOKEN")
    assert main(["serve", "--port", "0", "--data-dir", str(tmp_path / "d2")]) == 0
    out, _ = capsys.readouterr()
    token = (tmp_path / "d2" / "token").read_text().strip()
    assert out.count(token) == 1 and f"in {tmp_path / 'd2' / 'token'}" in out


# -- 8. HTTP limits on a real server ------------------------------------------------------------

LIMITS = HttpLimits(max_head_bytes=8 * 1024, head_timeout_s=1.0, body_idle_timeout_s=1.0)
SLACK_S = 3.0  # the most a test waits past a limit before it calls the connection held


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[BackgroundServer]:
    app = create_app(make_settings(tmp_path_factory.mktemp("limits")))
    with BackgroundServer(app, limits=LIMITS) as srv:
        yield srv


def _connect(
    srv: BackgroundServer, timeout_s: float = LIMITS.head_timeout_s + SLACK_S
) -> socket.socket:
    return socket.create_connection((srv.host, srv.port), timeout=timeout_s)


def _read_all(s: socket.socket) -> bytes:
    out = b""
    while True:
        try:
            chunk = s.recv(65536)
        except TimeoutError:
            raise AssertionError(f"the server held the connection; got {out[:200]!r}") from None
        except ConnectionResetError:
            break
        if not chunk:
            return out
        out += chunk
    return out


def _status(answer: bytes) -> int:
    return int(answer.split(b" ", 2)[1])


def _body(answer: bytes) -> dict[str, Any]:
    return dict(json.loads(answer.split(b"\r\n\r\n", 1)[1]))


def test_a_1_mb_header_is_431_naming_the_limit(server: BackgroundServer) -> None:
    """It was read whole and answered 200."""
    s = _connect(server)
    head = b"GET /api/status HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Big: " + b"a" * 1_000_000
    sender = threading.Thread(target=lambda: _send_quietly(s, head + b"\r\n\r\n"))
    sender.start()
    answer = _read_all(s)
    sender.join(10)
    s.close()
    assert _status(answer) == 431, answer[:200]
    assert f"more than {LIMITS.max_head_bytes} bytes" in _body(answer)["detail"]


def _send_quietly(s: socket.socket, data: bytes) -> None:
    with contextlib.suppress(OSError):  # the server stops reading after its answer
        s.sendall(data)


def test_headers_within_the_limit_pass(server: BackgroundServer) -> None:
    r = httpx.get(server.url + "/api/status", headers={"X-Pad": "a" * 6000}, timeout=10)
    assert r.status_code == 200


@pytest.mark.parametrize("hosts", [("127.0.0.1", "evil.example"), ("localhost", "127.0.0.1")])
def test_duplicate_host_headers_are_400(server: BackgroundServer, hosts: tuple[str, str]) -> None:
    """Only the first was checked: Host: 127.0.0.1 then Host: evil.example passed."""
    s = _connect(server)
    s.sendall(
        b"GET /api/setups HTTP/1.1\r\n"
        + b"".join(b"Host: %s\r\n" % h.encode() for h in hosts)
        + b"Connection: close\r\n\r\n"
    )
    answer = _read_all(s)
    s.close()
    assert _status(answer) == 400 and _body(answer)["field"] == "Host", answer[:300]
    assert "sent 2 times" in _body(answer)["detail"]


@pytest.mark.slow
def test_a_header_trickled_byte_by_byte_is_cut_off(server: BackgroundServer) -> None:
    """A slow client held the connection (and a worker's attention) forever."""
    s = _connect(server)
    t0 = time.monotonic()
    head = b"GET /api/status HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Slow: " + b"a" * 1000
    with contextlib.suppress(OSError):
        for byte in head:
            s.sendall(bytes([byte]))
            time.sleep(0.05)
            if time.monotonic() - t0 > LIMITS.head_timeout_s + SLACK_S:
                break
    answer = _read_all(s)
    s.close()
    took = time.monotonic() - t0
    assert _status(answer) == 408, answer[:200]
    assert "not complete within 1 s" in _body(answer)["detail"]
    assert took < LIMITS.head_timeout_s + SLACK_S
    # others were served meanwhile and still are
    assert httpx.get(server.url + "/api/status", timeout=10).status_code == 200


def test_a_connection_that_sends_nothing_is_closed(server: BackgroundServer) -> None:
    s = _connect(server)
    t0 = time.monotonic()
    assert _read_all(s) == b""
    s.close()
    assert LIMITS.head_timeout_s * 0.9 < time.monotonic() - t0 < LIMITS.head_timeout_s + SLACK_S


def test_a_body_shorter_than_its_content_length_is_408(
    server: BackgroundServer, caplog: pytest.LogCaptureFixture
) -> None:
    """The handler waited for the missing bytes forever; when the client gave up, uvicorn
    logged "Exception in ASGI application" (ClientDisconnect)."""
    s = _connect(server, LIMITS.body_idle_timeout_s + SLACK_S)
    t0 = time.monotonic()
    with caplog.at_level(logging.ERROR):
        s.sendall(
            b"POST /api/tests HTTP/1.1\r\nHost: 127.0.0.1\r\n"
            + f"Authorization: Bearer {TOKEN}\r\n".encode()
            + b'Content-Type: application/json\r\nContent-Length: 100\r\n\r\n{"article"'
        )
        answer = _read_all(s)
        s.close()
        time.sleep(0.3)  # the handler sees the client gone
    assert _status(answer) == 408, answer[:200]
    assert _body(answer)["detail"].startswith("Content-Length: no bytes of the request body")
    assert time.monotonic() - t0 < LIMITS.body_idle_timeout_s + SLACK_S
    assert not [r for r in caplog.records if r.levelno >= logging.ERROR], caplog.text


def test_keep_alive_connections_are_closed_when_idle(server: BackgroundServer) -> None:
    s = _connect(server)
    s.sendall(b"GET /api/status HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")
    t0 = time.monotonic()
    answer = _read_all(s)  # the answer, then the close after keep_alive_s
    s.close()
    assert _status(answer) == 200
    assert time.monotonic() - t0 < max(LIMITS.keep_alive_s, LIMITS.head_timeout_s) + SLACK_S


def test_serve_uses_the_limits() -> None:
    """``dimacq serve`` runs uvicorn through server_config: the limited protocol, no server
    header (it named uvicorn), the keep-alive of the limits."""
    config = server_config(create_app(load_settings(token=TOKEN)))
    assert issubclass(config.http, LimitedHttpToolsProtocol)  # type: ignore[arg-type]
    assert config.http.limits == DEFAULT_LIMITS  # type: ignore[union-attr]
    assert config.timeout_keep_alive == DEFAULT_LIMITS.keep_alive_s
    assert config.server_header is False


# -- 10. start-up refusals in one line ----------------------------------------------------------


@pytest.mark.slow
def test_a_second_serve_of_a_served_stand_says_so_in_one_line(tmp_path: Path) -> None:
    """It printed uvicorn's whole lifespan traceback, then "Application startup failed.
    Exiting.", and exited 3."""
    env = {"DIMACQ_STAND": "bench-a", "DIMACQ_TOKEN": TOKEN}
    first = Service(tmp_path / "data", free_port(), TOKEN, env=env)
    try:
        port = free_port()
        proc = subprocess.run(
            [sys.executable, "-m", "dimacq.cli.main", "serve", "--port", str(port)]
            + ["--data-dir", str(tmp_path / "data"), "--log-level", "warning"],
            capture_output=True,
            text=True,
            timeout=120,
            env={**os.environ, **env, "DIMACQ_PORT": str(port)},
        )
    finally:
        first.stop()
    assert proc.returncode == 2, (proc.returncode, proc.stderr[-2000:])
    assert "Traceback" not in proc.stderr and "startup failed" not in proc.stderr, proc.stderr
    errors = [line for line in proc.stderr.splitlines() if line.strip()]
    assert len(errors) == 1, proc.stderr
    assert errors[0].startswith("dimacq serve: error: stand 'bench-a' is already served")
    assert "DIMACQ_STAND" in errors[0]
    assert TOKEN not in proc.stdout + proc.stderr  # never served: no lab page address
