"""The manual at ``/help``: every page renders, every link between pages resolves, and a browser
walking it from ``dimacq serve`` makes no request that leaves the machine.

The browser part drives Debian's ``chromium`` through Playwright (no browser download), as the
lab page's tests do; it is skipped when either is missing.
"""

from __future__ import annotations

import re
import shutil
from pathlib import Path
from urllib.parse import urlsplit

import pytest
from _serve_support import Service
from fastapi import HTTPException

from dimacq.api.manual import MANUAL_DIR, render_page
from dimacq.api.server import free_port

PAGES = sorted(p.relative_to(MANUAL_DIR).as_posix() for p in MANUAL_DIR.rglob("*.md"))
_LINK = re.compile(r"\]\(([^)\s#]+)(#[^)\s]*)?\)")


def test_the_manual_has_its_pages() -> None:
    """The pages the README and the index promise are there."""
    for name in ("index.md", "method.md", "cli.md", "api.md", "accuracy.md", "architecture.md"):
        assert name in PAGES


@pytest.mark.parametrize("name", PAGES)
def test_every_page_renders_and_its_links_resolve(name: str) -> None:
    html = render_page(name)
    assert '<main class="help">' in html and "<h1>" in html, name
    text = (MANUAL_DIR / name).read_text(encoding="utf-8")
    for target, _anchor in _LINK.findall(text):
        if "://" in target or target.startswith("/"):
            continue
        resolved = (MANUAL_DIR / name).parent / target
        assert resolved.exists(), f"{name}: link to {target!r} has no file"


def test_raw_html_is_escaped_and_names_outside_the_manual_are_refused() -> None:
    for bad in ("../README.md", "..%2fapi.md", "/etc/passwd", "index.py", "page/../../x.md"):
        with pytest.raises(HTTPException) as err:
            render_page(bad)
        assert err.value.status_code == 404
    assert "<script" not in "".join(render_page(p) for p in PAGES)


CHROMIUM = shutil.which("chromium")


@pytest.mark.slow
@pytest.mark.skipif(CHROMIUM is None, reason="Debian's chromium is not installed")
def test_help_is_served_offline_from_dimacq_serve(tmp_path: Path) -> None:
    """``/help`` opens the index; following its links shows every linked page; each answer has
    the page's CSP; every request the browser makes goes to 127.0.0.1."""
    playwright_sync = pytest.importorskip("playwright.sync_api")
    service = Service(tmp_path / "data", free_port(), "help-token")
    requests: list[str] = []
    try:
        head = service.client.get("/help/index.md")
        assert head.status_code == 200
        assert "default-src 'self'" in head.headers["content-security-policy"]
        assert service.client.get("/help/nope.md").status_code == 404
        with playwright_sync.sync_playwright() as pw:
            browser = pw.chromium.launch(executable_path=CHROMIUM)
            page = browser.new_page()
            page.on("request", lambda r: requests.append(r.url))
            page.goto(f"{service.url}/help")
            assert page.locator("h1").first.inner_text() == "The dimacq manual"
            links = page.eval_on_selector_all(
                "main a[href$='.md']", "els => els.map(e => e.getAttribute('href'))"
            )
            assert len(links) >= 10
            for href in dict.fromkeys(links):
                page.goto(f"{service.url}/help/index.md")
                page.click(f"main a[href='{href}']")
                page.wait_for_load_state()
                assert page.url.endswith("/help/" + href), page.url
                assert page.locator("main.help h1").count() == 1, href
            browser.close()
    finally:
        service.stop()
    hosts = {urlsplit(u).hostname for u in requests}
    assert hosts == {"127.0.0.1"}, hosts
