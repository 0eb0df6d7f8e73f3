"""The manual at ``/help``: the package's ``dimacq/manual/*.md`` rendered to HTML, offline.

``/help`` redirects to ``/help/index.md``; ``/help/<name>.md`` is a page rendered by markdown-it
(CommonMark with tables; raw HTML in the source is escaped, never passed through), so the
relative links between pages (``cli.md``, ``page/acquire.png``) work unchanged in the service and
on GitHub. Images under the manual's folders are served as files. Only names of the form
``[a-z0-9-]+(/[a-z0-9-]+)*.(md|png|jpg|svg)`` that exist inside the manual folder are answered
(no path traversal); every answer carries the lab page's security headers.
"""

from __future__ import annotations

import html
import re
from functools import lru_cache
from pathlib import Path

from fastapi import FastAPI, HTTPException
from fastapi.responses import FileResponse, HTMLResponse, RedirectResponse

__all__ = ["MANUAL_DIR", "mount_manual", "render_page"]

#: The manual's folder (package data).
MANUAL_DIR = Path(__file__).resolve().parents[1] / "manual"

_NAME = re.compile(r"^[a-z0-9][a-z0-9_-]*(/[a-z0-9][a-z0-9_-]*)*\.(md|png|jpg|svg)$")
_MEDIA = {".png": "image/png", ".jpg": "image/jpeg", ".svg": "image/svg+xml"}
_TITLE = re.compile(r"^#\s+(.+)$", re.M)


def _resolve(name: str) -> Path:
    """The file ``name`` inside :data:`MANUAL_DIR`, or a 404 naming it."""
    if not _NAME.match(name):
        raise HTTPException(404, f"help page {name!r}: no such page; see /help")
    path = (MANUAL_DIR / name).resolve()
    if MANUAL_DIR not in path.parents or not path.is_file():
        raise HTTPException(404, f"help page {name!r}: no such page; see /help")
    return path


@lru_cache(maxsize=64)
def _render_cached(name: str, mtime_ns: int) -> str:
    from markdown_it import MarkdownIt

    text = (MANUAL_DIR / name).read_text(encoding="utf-8")
    body = MarkdownIt("commonmark", {"html": False}).enable("table").render(text)
    found = _TITLE.search(text)
    title = html.escape(found.group(1).strip() if found else name)
    return (
        "<!doctype html>\n"
        '<html lang="en"><head><meta charset="utf-8">'
        '<meta name="viewport" content="width=device-width, initial-scale=1">'
        f"<title>{title} — dimacq manual</title>"
        '<link rel="stylesheet" href="/static/help.css"></head>\n'
        '<body><nav class="help-nav"><a href="/help/index.md">Manual</a> · '
        '<a href="/">Lab page</a> · <a href="/docs">API</a></nav>\n'
        f'<main class="help">{body}</main></body></html>\n'
    )


def render_page(name: str) -> str:
    """The HTML of manual page ``name`` (``index.md``, ``cli.md``, …).

    Raises :class:`fastapi.HTTPException` 404 when there is no such page.
    """
    path = _resolve(name)
    if path.suffix != ".md":
        raise HTTPException(404, f"help page {name!r}: not a page; see /help")
    return _render_cached(path.relative_to(MANUAL_DIR).as_posix(), path.stat().st_mtime_ns)


def mount_manual(app: FastAPI, headers: dict[str, str]) -> None:
    """Serve the manual at ``/help`` with the lab page's ``headers`` (CSP, framing, referrer)."""

    @app.get("/help", include_in_schema=False)
    async def help_index() -> RedirectResponse:
        return RedirectResponse("/help/index.md", status_code=307, headers=headers)

    @app.get("/help/{name:path}", include_in_schema=False, response_model=None)
    async def help_page(name: str) -> HTMLResponse | FileResponse:
        if name.endswith(".md"):
            return HTMLResponse(render_page(name), headers=headers)
        path = _resolve(name)
        return FileResponse(path, media_type=_MEDIA[path.suffix], headers=headers)
