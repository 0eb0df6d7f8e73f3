"""The lab page's bench-calibration step (``dimacq/api/static/calibration.js``) in headless
Chromium against a real ``dimacq serve`` on the simulated lab, in the style of
``tests/api/test_lab_page.py``: an inertial calibration run with its circular check started from
the page, its progress followed, the certificate figures and the check shown, the calibration
listed; every request stays on 127.0.0.1, the console stays free of errors. A screenshot goes to
``<tmp>/screenshots/7-bench.png``.

Needs Debian's ``chromium`` and Playwright's Python package; skipped when either is missing.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit

import pytest

CHROMIUM = shutil.which("chromium")
playwright_sync = pytest.importorskip("playwright.sync_api")
pytestmark = pytest.mark.skipif(CHROMIUM is None, reason="Debian's chromium is not installed")


@pytest.fixture
def service(tmp_path: Path) -> Any:
    from test_lab_page import TOKEN, served

    with served(tmp_path) as url:
        yield url, TOKEN


def test_bench_calibration_module_is_package_data() -> None:
    from importlib.resources import files

    js = files("dimacq.api") / "static" / "calibration.js"
    text = js.read_text(encoding="utf-8")
    assert "http://" not in text and "https://" not in text
    html = (files("dimacq.api") / "static" / "index.html").read_text(encoding="utf-8")
    assert '<script type="module" src="/static/calibration.js">' in html


@pytest.mark.slow
def test_inertial_calibration_through_the_page(service: Any, tmp_path: Path) -> None:
    url, token = service
    shots = tmp_path / "screenshots"
    shots.mkdir()
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
        page.wait_for_selector("#bench[data-ready='1']", timeout=20_000)
        assert page.locator("header nav a[href='#bench']").count() == 1
        page.select_option("#bench-method", "inertial")
        page.fill("#bench-averages", "1")
        # On the simulated lab the world strikes by itself and asks nobody: the run's prompt
        # route is answered here with a strike request of its shape (the route itself is
        # tested in tests/api/test_calibration_runs.py) until the page has said it in words
        strike = {
            "job_id": "-",
            "waiting": True,
            "kind": "strike",
            "stage": "inertial bench",
            "input_index": 2,
            "n_inputs": 24,
            "node": 103,
            "direction": "-X",
            "direction_gcs": [-1.0, 0.0, 0.0],
            "average": 1,
            "averages": 1,
            "request": 3,
            "message": "strike input 3: 103-X (average 1 of 1, input 3 of 24, request 3)",
        }
        prompt_route = "**/api/calibrations/runs/*/prompt"
        page.route(
            prompt_route,
            lambda r: r.fulfill(
                status=200, content_type="application/json", body=json.dumps(strike)
            ),
        )
        page.click("#bench-start")
        page.wait_for_function(
            "() => document.querySelector('#bench-prompt').textContent === "
            "'inertial bench: strike point 103 along −X — input 3/24, average 1/1'",
            timeout=30_000,
        )
        page.unroute(prompt_route)
        page.wait_for_function(
            "() => /inertial bench/.test(document.querySelector('#bench-msg').textContent)",
            timeout=30_000,
        )
        # the run's end: the page's own words for it (calibration.js start()), not any progress
        # message that happens to contain "failed" (a struck average the checks refused)
        page.wait_for_function(
            "() => /^(calibration (finished|failed|cancelled)|HTTP)/.test("
            "document.querySelector('#bench-msg').textContent)"
            " || document.querySelector('#bench-msg').className === 'fail'",
            timeout=240_000,
        )
        msg = page.inner_text("#bench-msg")
        assert msg.startswith("calibration finished: inertial"), msg
        result = page.evaluate("() => window.dimacqBench.result")
        assert result["method"] == "inertial" and len(result["uncertainty_pct_fs"]) == 6
        # what the page shows is the job's result
        cert = page.inner_text("#bench-cert")
        assert f"{result['uncertainty_pct_fs'][0]:.4f}" in cert
        assert "NaN" not in cert, cert  # the 6 × 6 crosstalk shown per axis, not as NaN
        circular = page.inner_text("#bench-circular")
        assert f"{result['circular_mass_error_pct']:.3f} %" in circular
        assert result["circular_verdict"].upper() in circular  # CSS upper-cases it
        rows = page.locator("#bench-list tbody tr")
        assert rows.count() >= 1 and "inertial" in rows.first.inner_text()
        page.locator("#bench").screenshot(path=str(shots / "7-bench.png"))
        browser.close()
    assert not errors, errors
    assert not outside, outside
