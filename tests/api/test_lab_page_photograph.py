"""The lab page's Photograph step (``dimacq/api/static/photograph.js``) in headless Chromium
against a real ``dimacq serve`` of the simulated lab, in the style of ``test_lab_page_bench.py``:
rendered photos and their tags file chosen in the page and uploaded, the job's progress shown,
the photographed geometry stored and its setup opened in step 1; then a setup the photos cannot
fix, refused with each triax named and its fix, nothing stored. Every request stays on
127.0.0.1, the console stays free of errors. A screenshot goes to
``<tmp>/screenshots/2b-photograph.png``.

Needs Debian's ``chromium`` and Playwright's Python package; skipped when either is missing.
"""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit

import httpx
import pytest
from _photo_support import small_photo_set

CHROMIUM = shutil.which("chromium")
playwright_sync = pytest.importorskip("playwright.sync_api")
pytestmark = pytest.mark.skipif(CHROMIUM is None, reason="Debian's chromium is not installed")


@pytest.fixture
def service(tmp_path: Path) -> Any:
    from test_lab_page import TOKEN, served

    with served(tmp_path) as url:
        yield url, TOKEN


def test_photograph_module_is_package_data() -> None:
    from importlib.resources import files

    text = (files("dimacq.api") / "static" / "photograph.js").read_text(encoding="utf-8")
    assert "http://" not in text and "https://" not in text
    html = (files("dimacq.api") / "static" / "index.html").read_text(encoding="utf-8")
    assert '<section id="photograph">' in html and 'href="/static/photograph.js"' in html


def _wait_done(page: Any) -> str:
    page.wait_for_function(
        "() => /^status (done|err)$/.test(document.querySelector('#status-photograph').className)",
        timeout=1_500_000,  # a guard only: two small adjustments on a loaded machine
    )
    return str(page.get_attribute("#status-photograph", "class"))


@pytest.mark.slow
def test_photographed_geometry_through_the_page(service: Any, tmp_path: Path) -> None:
    url, token = service
    shots = tmp_path / "screenshots"
    shots.mkdir()
    ps = small_photo_set(tmp_path / "photos")
    auth = {"Authorization": f"Bearer {token}"}
    with httpx.Client(base_url=url, headers=auth, timeout=30) as c:
        small = c.post("/api/setups", json=ps.setup).json()["id"]
        full = c.post("/api/setups", json={**ps.full_setup, "name": "every triax"}).json()["id"]
    errors: list[str] = []
    outside: list[str] = []
    with playwright_sync.sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=CHROMIUM)
        ctx = browser.new_context(viewport={"width": 1280, "height": 900})

        def leaves(u: str) -> bool:
            return not u.startswith("data:") and urlsplit(u).hostname != "127.0.0.1"

        def refuse(r: Any) -> None:
            outside.append(r.request.url)
            r.abort()

        ctx.route(leaves, refuse)
        page = ctx.new_page()
        page.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
        page.on("pageerror", lambda e: errors.append(str(e)))
        page.goto(f"{url}/#token={token}")
        page.wait_for_selector("body[data-ready='1']", timeout=60_000)
        assert page.locator("header nav a[href='#photograph']").count() == 1
        page.fill("#photo-folder", "cm-two")
        files = sorted(str(p) for p in ps.folder.iterdir())
        page.set_input_files("#photo-files", files)
        page.select_option("#photo-setup", str(small))
        page.click("#photo-run")
        assert _wait_done(page) == "status done", page.inner_text("#status-photograph")
        res = page.evaluate("() => window.dimacq.photos.result")
        messages = page.evaluate("() => window.dimacq.photos.messages")
        # the progress the page showed: the photos read, then the adjustment
        assert any(m.startswith("photo ") for m in messages), messages
        assert any(m.startswith("adjust") for m in messages), messages
        assert res["stored"]["orientations"] == 2 and res["setup_id"] is not None
        assert f"setup {res['setup_id']}" in page.inner_text("#photo-verdict")
        # the stored setup is open in step 1
        page.wait_for_function(
            f"() => window.dimacq.setup && window.dimacq.setup.id === {res['setup_id']}",
            timeout=30_000,
        )
        node = res["geometry"]["orientations"][0]
        assert f"{node['origin_m'][0]:.4f}" in page.inner_text("#photo-result")
        page.locator("#photograph").screenshot(path=str(shots / "2b-photograph.png"))
        # the same folder for a setup whose other triaxes carry no tags: refused, named
        page.set_input_files("#photo-files", [])
        page.select_option("#photo-setup", str(full))
        page.click("#photo-run")
        assert _wait_done(page) == "status err"
        refused = page.inner_text("#photo-refused")
        assert "nothing was stored" in refused
        assert "triax 3: no tags in the tags file; add its block to the tags file" in refused
        assert "refused" in page.inner_text("#status-photograph")
        page.locator("#photograph").screenshot(path=str(shots / "2b-photograph-refused.png"))
        browser.close()
    assert not errors, errors
    assert not outside, outside
