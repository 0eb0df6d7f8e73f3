"""The lab page (``GET /``) walked in headless Chromium against a real ``dimacq serve``.

A whole simulated test through the page only: setup tables and the simulated article, digitize
(registration, jig orientations, lines of action), build the setup from that geometry, acquire
(a few inputs and averages), FRF plots, solve in a band dragged on the FRF plot, report. The
result is checked against the scenario's true properties. Every request the page makes must stay
on 127.0.0.1, the console must stay free of errors. Screenshots of every step go to
``<tmp>/screenshots``; the page load time and the draw time of 30 FRFs × 2048 lines are printed
(``pytest -s``), never asserted.

Needs Debian's ``chromium`` and Playwright's Python package (no browser download: Playwright
launches ``shutil.which("chromium")``); skipped when either is missing.
"""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit

import httpx
import numpy as np
import pytest

from dimacq.api.server import free_port

CHROMIUM = shutil.which("chromium")
playwright_sync = pytest.importorskip("playwright.sync_api")
pytestmark = pytest.mark.skipif(CHROMIUM is None, reason="Debian's chromium is not installed")

SCENARIO = "calibration-mass-bungee"
N_INPUTS = 8
AVERAGES = 2
SHOTS = 2
TOKEN = "page-test-token"


def _serve(tmp_path: Path) -> tuple[subprocess.Popen[str], str]:
    port = free_port()
    env = {
        **os.environ,
        "DIMACQ_TOKEN": TOKEN,
        "DIMACQ_SCENARIO": SCENARIO,
        "DIMACQ_DIGITIZER_URL": f"simdigitizer://page{port}?seed=3",
        "DIMACQ_DATABASE_URL": "",
    }
    proc = subprocess.Popen(
        [sys.executable, "-m", "dimacq.cli.main", "serve", "--port", str(port)]
        + ["--data-dir", str(tmp_path / "data"), "--log-level", "warning"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        env=env,
        text=True,
    )
    url = f"http://127.0.0.1:{port}"
    deadline = time.monotonic() + 30
    while True:
        try:
            httpx.get(f"{url}/api/status", timeout=1).raise_for_status()
            return proc, url
        except httpx.TransportError:
            if proc.poll() is not None or time.monotonic() > deadline:
                proc.kill()
                raise AssertionError(
                    f"dimacq serve did not start: {proc.communicate()[1]}"
                ) from None
            time.sleep(0.1)


@pytest.fixture
def service(tmp_path: Path) -> Any:
    proc, url = _serve(tmp_path)
    try:
        yield url
    finally:
        proc.send_signal(signal.SIGINT)
        try:
            proc.communicate(timeout=20)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.communicate()


def test_page_assets_come_from_the_installed_package(tmp_path: Path) -> None:
    """The page's files are package data next to the app (what ``pip install`` ships)."""
    from importlib.resources import files

    static = files("dimacq.api") / "static"
    for name in (
        "index.html",
        "app.js",
        "plot.js",
        "results.js",
        "report.html",
        "report.js",
        "style.css",
    ):
        assert (static / name).is_file(), name
    from dimacq.api import create_app
    from dimacq.api.server import BackgroundServer
    from dimacq.config import load_settings

    app = create_app(load_settings(token="t", data_dir=tmp_path, database_url=""))
    with BackgroundServer(app) as srv, httpx.Client(base_url=srv.url) as c:
        page = c.get("/")
        assert (
            page.status_code == 200 and '<script type="module" src="/static/app.js">' in page.text
        )
        for name in ("app.js", "plot.js", "style.css", "report.js"):
            r = c.get(f"/static/{name}")
            assert r.status_code == 200 and len(r.content) > 100, name
        # every asset the page names is served from here: no outside URL in any of them
        for name in (
            "index.html",
            "app.js",
            "plot.js",
            "results.js",
            "report.html",
            "report.js",
            "style.css",
        ):
            text = (static / name).read_text(encoding="utf-8")
            assert "http://" not in text and "https://" not in text, name


def _truth() -> dict[str, Any]:
    from dimacq.simulators.lab.scenarios import build_scenario

    built = build_scenario(SCENARIO, None)
    out: dict[str, Any] = built.truth_json()
    out["band_hz"] = [float(b) for b in built.band_hz]
    return out


def test_whole_simulated_test_through_the_page(service: str, tmp_path: Path) -> None:
    shots = tmp_path / "screenshots"
    shots.mkdir()
    truth = _truth()
    errors: list[str] = []
    outside: list[str] = []
    t_start = time.perf_counter()
    with playwright_sync.sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=CHROMIUM)
        ctx = browser.new_context(viewport={"width": 1280, "height": 900})

        def leaves(url: str) -> bool:
            return not url.startswith("data:") and urlsplit(url).hostname != "127.0.0.1"

        def refuse(r: Any) -> None:
            outside.append(r.request.url)
            r.abort()

        # every request's URL goes through the predicate; the ones leaving the PC are refused
        # (loopback ones are not intercepted at all, so the job's event stream flows as it does)
        ctx.route(leaves, refuse)
        ctx.on("request", lambda r: outside.append(r.url) if leaves(r.url) else None)
        page = ctx.new_page()
        page.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
        page.on("pageerror", lambda e: errors.append(str(e)))

        # --- 1 setup: the page loads, takes the token from the fragment, shows the article
        page.goto(f"{service}/#token={TOKEN}")
        page.wait_for_selector("body[data-ready='1']", timeout=20_000)
        load_ms = page.evaluate(
            "() => { const n = performance.getEntriesByType('navigation')[0];"
            " return n.loadEventEnd - n.startTime; }"
        )
        init_ms = page.evaluate("() => window.dimacq.timings.init_ms")
        assert "#token" not in page.url
        assert page.evaluate("() => sessionStorage.getItem('dimacq-token')") == TOKEN
        assert page.locator("#article-view circle").count() > 0
        page.locator("#setup").screenshot(path=str(shots / "1-setup.png"))

        # --- 2 digitize the simulated article and build the setup from that geometry
        page.fill("#n-inputs", str(N_INPUTS))
        page.fill("#shots", str(SHOTS))
        page.click("#digitize-all")
        page.wait_for_function(
            "() => document.querySelector('#msg').textContent.startsWith('digitized')"
            " || document.querySelector('#msg').className === 'err'",
            timeout=60_000,
        )
        assert page.locator("#msg").get_attribute("class") != "err", page.inner_text("#msg")
        assert page.locator("#registration td").count() >= 6 * 3
        assert page.locator("#loas tbody tr").count() == N_INPUTS
        page.click("#build-setup")
        page.wait_for_function(
            "() => document.querySelector('#msg').textContent.startsWith('setup ')",
            timeout=20_000,
        )
        t_digitized = time.perf_counter()
        page.locator("#digitize").screenshot(path=str(shots / "2-digitize.png"))
        assert page.locator("#setup-detail h4").first.is_visible()

        # --- 3 acquire: the prompt names the point and direction; progress over SSE
        page.fill("#averages", str(AVERAGES))
        page.click("#acq-start")
        page.wait_for_function(
            "() => document.querySelector('#prompt').textContent.startsWith('Strike point')",
            timeout=20_000,
        )
        prompt = page.inner_text("#prompt")
        page.locator("#acquire").screenshot(path=str(shots / "3-acquire-running.png"))
        page.wait_for_function(
            "() => /acquisition \\d+ (succeeded|failed|cancelled)/.test("
            "document.querySelector('#msg').textContent)",
            timeout=120_000,
        )
        assert "succeeded" in page.inner_text("#msg"), page.inner_text("#msg")
        t_acquired = time.perf_counter()
        page.locator("#acquire").screenshot(path=str(shots / "3-acquire-done.png"))
        assert page.locator("#acq-inputs tbody tr").count() == N_INPUTS

        # --- 4 FRFs: plots drawn; 30 FRFs × 2048 lines timed on the page's own plot module
        page.wait_for_function("() => window.dimacq.frfData !== null", timeout=20_000)
        frf_draw_ms = page.evaluate("() => window.dimacq.timings.frf_draw_ms")
        bench_ms = page.evaluate(
            """async () => {
              const { linePlot } = await import('/static/plot.js');
              const c = document.createElement('canvas');
              c.style.width = '1200px'; c.style.height = '400px';
              document.body.appendChild(c);
              const n = 2048, x = new Float64Array(n);
              for (let i = 0; i < n; i++) x[i] = i * 0.25;
              const series = [];
              for (let k = 0; k < 30; k++) {
                const y = new Float64Array(n);
                for (let i = 0; i < n; i++) y[i] = (1 + k) * (1 + Math.abs(Math.sin(i / 50 + k)));
                series.push({ y });
              }
              const t0 = performance.now();
              linePlot(c, { x, series, logY: true });
              const ms = performance.now() - t0;
              c.remove();
              return ms;
            }"""
        )

        # --- 5 solve in the scenario's band, dragged on the magnitude plot
        lo, hi = truth["band_hz"]
        page.locator("#frf-mag").scroll_into_view_if_needed()
        box = page.locator("#frf-mag").bounding_box()
        assert box is not None
        x_lo = page.evaluate(f"() => window.dimacq.plots.mag.X({lo})")
        x_hi = page.evaluate(f"() => window.dimacq.plots.mag.X({hi})")
        y = box["y"] + box["height"] / 2
        page.mouse.move(box["x"] + x_lo, y)
        page.mouse.down()
        page.mouse.move(box["x"] + (x_lo + x_hi) / 2, y, steps=4)
        page.mouse.move(box["x"] + x_hi, y, steps=4)
        page.mouse.up()
        band = page.evaluate("() => window.dimacq.band")
        page.locator("#frfs").screenshot(path=str(shots / "4-frfs.png"))
        assert band[0] == pytest.approx(lo, abs=2.0) and band[1] == pytest.approx(hi, abs=2.0)
        page.click("#solve-btn")
        page.wait_for_selector("#solution .verdict", timeout=60_000)
        page.locator("#solve").screenshot(path=str(shots / "5-solve.png"))
        n_intervals = page.locator("#solution td", has_text="[").count()
        sol = page.evaluate("() => window.dimacq.solution")

        # --- 6 report (a new tab), printable; downloads linked
        with ctx.expect_page() as rp:
            page.click("#report-link")
        report = rp.value
        report.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
        report.on("pageerror", lambda e: errors.append(str(e)))
        report.wait_for_selector("body[data-ready='1']", timeout=20_000)
        report.screenshot(path=str(shots / "6-report.png"), full_page=True)
        assert "verdict" in report.inner_text("body").lower()
        assert report.locator("a[download$='.uff']").count() == 1
        page.screenshot(path=str(shots / "0-whole-page.png"), full_page=True)
        # the page loaded again, service warm, with a setup, an FRF set and a solution stored
        page.reload()
        page.wait_for_selector("body[data-ready='1']", timeout=20_000)
        warm = page.evaluate(
            "() => [performance.getEntriesByType('navigation')[0].loadEventEnd,"
            " window.dimacq.timings.init_ms]"
        )
        browser.close()
    elapsed = time.perf_counter() - t_start

    res = sol["result"]
    m_err = (res["mass_kg"] - truth["mass_kg"]) / truth["mass_kg"]
    cg_err = float(np.linalg.norm(np.subtract(res["cg_m"], truth["cg_m"])))
    pm_err = np.abs(
        np.subtract(res["principal_moments_kgm2"], truth["principal_moments_kgm2"])
    ) / np.asarray(truth["principal_moments_kgm2"])
    print(
        f"\nlab page: load {load_ms:.0f} ms (app init {init_ms:.0f} ms), again {warm[0]:.0f} ms "
        f"(init {warm[1]:.0f} ms); FRF plot "
        f"{frf_draw_ms:.1f} ms; 30 FRFs x 2048 lines drawn in {bench_ms:.1f} ms; prompt "
        f"{prompt!r}; verdict {res['verdict']}; mass {100 * m_err:+.2f} %, CG {1e3 * cg_err:.1f} mm, "
        f"principal moments {np.round(100 * pm_err, 2).tolist()} %; walk {elapsed:.1f} s "
        f"(digitized at {t_digitized - t_start:.1f} s, acquired at {t_acquired - t_start:.1f} s); "
        f"screenshots in {shots}"
    )
    assert not errors, errors
    assert not outside, outside
    assert prompt.startswith("Strike point ") and " along " in prompt
    # the band typed from the drag (0.1 Hz), snapped by the solver to the FRF lines
    assert res["band_hz"] == pytest.approx(band, abs=1.5)
    assert res["verdict"] in ("ok", "warn", "fail")
    assert n_intervals >= 10  # the ten parameters (and principal moments), with 95 % intervals
    assert abs(m_err) < 0.02, res["mass_kg"]
    assert cg_err < 0.01, res["cg_m"]
    assert float(pm_err.max()) < 0.05, res["principal_moments_kgm2"]
