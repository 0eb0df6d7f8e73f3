"""``dimacq serve`` hardening (issue 24): the token printed once, start-up refusals in one line
(exit 2), and uvicorn's limits against slow or oversized clients, on a real server on
127.0.0.1 with raw sockets. Each test failed before its fix."""

from __future__ import annotations

import asyncio
from pathlib import Path

import pytest
from _api_support import TOKEN

from dimacq.cli.main import main


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
