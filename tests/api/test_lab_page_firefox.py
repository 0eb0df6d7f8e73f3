"""The lab page in Firefox (Debian's ``firefox-esr``) against a real ``dimacq serve`` on loopback,
driven through Firefox's own WebDriver BiDi (``--remote-debugging-port``, a websocket; no
geckodriver, no Playwright browser build).

The walk: the page loads (ready, no console error); a new test through the Test step; the
bundled simulated six-triax test imported as one whole-test UFF through the page's file input
(``input.setFiles``), so the setup opens with its 3-D view (drawn, and turned by a mouse drag)
and the FRF set opens with its plots; the band dragged on the FRF plot with the mouse
(``input.performActions``); Solve; the result checked against the example's truth. Every
request the page makes (``network.beforeRequestSent``) must stay on 127.0.0.1; the profile also
sends everything else to a closed loopback port. Screenshots go to ``<tmp>/screenshots``
(``DIMACQ_PAGE_SHOTS=DIR``: DIR).

Skipped, with the reason, when Firefox is not installed, except under ``CI=true`` (``.ci/run``
installs ``firefox-esr``), where that fails.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit

import pytest
from _firefox_support import FIREFOX, Bidi, Page, launch_firefox, lines_of, stop, wait_line

from dimacq.api.server import free_port

IN_CI = os.environ.get("CI", "").lower() == "true"
pytestmark = pytest.mark.skipif(
    FIREFOX is None and not IN_CI,
    reason="Firefox is not installed (apt-get install -y firefox-esr); CI installs it",
)

SCENARIO = "calibration-mass-bungee"
TOKEN = "firefox-test-token"
EXAMPLES = Path(__file__).resolve().parents[2] / "config" / "examples"


@pytest.fixture
def firefox_and_service(tmp_path: Path) -> Iterator[tuple[Bidi, str, list[Any]]]:
    """``dimacq serve`` and headless Firefox started side by side; yields the BiDi session, the
    service's URL and the events list."""
    assert FIREFOX is not None, "CI=true: Firefox must be installed (.ci/run installs firefox-esr)"
    port = free_port()
    serve = subprocess.Popen(
        [sys.executable, "-m", "dimacq.cli.main", "serve"]
        + ["--port", str(port), "--data-dir", str(tmp_path / "data"), "--log-level", "warning"],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        env={
            **os.environ,
            "DIMACQ_TOKEN": TOKEN,
            "DIMACQ_SCENARIO": SCENARIO,
            "DIMACQ_DIGITIZER_URL": f"simdigitizer://ff{port}?seed=3",
            "DIMACQ_DATABASE_URL": "",
        },
        text=True,
    )
    ff_port = free_port()
    firefox = launch_firefox(tmp_path, ff_port)
    from websockets.sync.client import connect

    events: list[Any] = []
    try:
        wait_line(firefox, lines_of(firefox), "WebDriver BiDi listening on", "firefox")
        wait_line(serve, lines_of(serve), "lab page:", "dimacq serve")
        with connect(f"ws://127.0.0.1:{ff_port}/session", max_size=None, open_timeout=20) as ws:
            bidi = Bidi(ws, lambda m, p: events.append((m, p)))
            caps = bidi.call("session.new", {"capabilities": {}})["capabilities"]
            events.append(("session.new", caps))
            yield bidi, f"http://127.0.0.1:{port}", events
    finally:
        stop(firefox)
        stop(serve)
        for proc in (firefox, serve):
            assert proc.stdout is not None
            proc.stdout.close()


def _whole_test_uff(tmp_path: Path) -> Path:
    """The bundled simulated six-triax test (setup file + FRFs) as one whole-test UFF file, as
    the lab's other software would hand it over."""
    from dimacq.io.setup_file import load_setup
    from dimacq.io.uff import dump_uff, read_frf_uff

    setup = load_setup(EXAMPLES / "six_triax_setup.toml")
    frf = read_frf_uff(EXAMPLES / "six_triax_frf.uff", setup)
    path = tmp_path / "six-triax-test.uff"
    path.write_bytes(dump_uff(frf, setup))
    return path


@pytest.mark.slow
def test_lab_page_in_firefox(firefox_and_service: Any, tmp_path: Path) -> None:
    bidi, url, events = firefox_and_service

    shots = Path(os.environ.get("DIMACQ_PAGE_SHOTS") or tmp_path / "screenshots")
    shots.mkdir(parents=True, exist_ok=True)
    uff = _whole_test_uff(tmp_path)
    truth = json.loads((EXAMPLES / "six_triax_truth.json").read_text())
    t0 = time.perf_counter()
    bidi.call("session.subscribe", {"events": ["log.entryAdded", "network.beforeRequestSent"]})
    context = bidi.call("browsingContext.getTree", {})["contexts"][0]["context"]
    bidi.call(
        "browsingContext.setViewport",
        {"context": context, "viewport": {"width": 1280, "height": 900}},
    )
    page = Page(bidi, context)
    caps = next(p for m, p in events if m == "session.new")
    version = f"{caps.get('browserName')} {caps.get('browserVersion')}"

    # --- the page loads and takes the token from the fragment
    bidi.call(
        "browsingContext.navigate",
        {"context": context, "url": f"{url}/#token={TOKEN}", "wait": "complete"},
    )
    page.wait("document.body.dataset.ready === '1'", 30, "page ready")
    ready_ms = page.js(
        "window.dimacq.timings.ready_ms - performance.getEntriesByType('navigation')[0].startTime"
    )
    assert page.js("location.hash") == ""
    assert page.js("sessionStorage.getItem('dimacq-token')") == TOKEN
    assert page.js("document.querySelectorAll('#article-table tbody tr').length") > 0

    # --- a new test (POST /api/tests), opened
    page.js(
        "(() => { document.querySelector('#test-article').value = 'six-triax frame';"
        " document.querySelector('#test-operator').value = 'firefox'; })()"
    )
    page.click("#new-test")
    page.wait("window.dimacq.test && window.dimacq.test.article === 'six-triax frame'", 20)
    test_id = page.js("window.dimacq.test.id")

    # --- the simulated test imported through the page's file input: setup, 3-D view, FRFs
    bidi.call(
        "input.setFiles",
        {"context": context, "element": page.element("#setup-file"), "files": [str(uff)]},
    )
    page.wait(
        "window.dimacq.setup && window.dimacq.frf && window.dimacq.frfData", 60, "import + open"
    )
    assert page.js("window.dimacq.setup.test_id") == test_id
    assert page.js("window.dimacq.frfData.inputs.length") == truth_inputs(page)
    view = "document.querySelector('#view3d')"
    ink = (
        f"(() => {{ const c = {view}; const d = c.getContext('2d')"
        ".getImageData(0, 0, c.width, c.height).data; let n = 0, h = 0;"
        " for (let i = 3; i < d.length; i += 4) if (d[i] > 0) { n++; h = (h * 31 + i + d[i - 1]) | 0; }"
        " return [n, h]; })()"
    )
    assert "setup" in page.js("document.querySelector('#view3d-what').textContent")
    drawn, before = page.js(ink)
    assert drawn > 500, drawn  # nodes, arrows and axes on the canvas
    page.js(f"{view}.scrollIntoView({{block: 'center'}})")
    r = page.js(f"{view}.getBoundingClientRect().toJSON()")
    cx, cy = r["x"] + r["width"] / 2, r["y"] + r["height"] / 2
    page.drag([(cx, cy), (cx + 40, cy + 10), (cx + 90, cy + 25)])
    page.wait(f"{ink}[1] !== {before}", 5, "the 3-D view turns when dragged")
    page.shot(shots / "firefox-1-setup-3d.png")

    # --- the band dragged on the FRF magnitude plot, then Solve
    lo, hi = 10.0, 100.0
    mag = "document.querySelector('#frf-mag')"
    page.js(f"{mag}.scrollIntoView({{block: 'center'}})")
    r = page.js(f"{mag}.getBoundingClientRect().toJSON()")
    x_lo = r["x"] + page.js(f"window.dimacq.plots.mag.X({lo})")
    x_hi = r["x"] + page.js(f"window.dimacq.plots.mag.X({hi})")
    y = r["y"] + r["height"] / 2
    page.drag([(x_lo, y), ((x_lo + x_hi) / 2, y), (x_hi, y)])
    band = page.js("window.dimacq.band")
    assert band[0] == pytest.approx(lo, abs=2.0) and band[1] == pytest.approx(hi, abs=2.0), band
    page.shot(shots / "firefox-2-frfs.png")
    page.click("#solve-btn")
    # the solutions list is filled after the verdict and the spectrum (solve.js: render, then
    # list): wait for the row asserted below too, not only for what comes before it
    page.wait(
        "document.querySelector('#solution .verdict') && window.dimacq.spectrum"
        " && document.querySelectorAll('#solutions tbody tr').length === 1",
        60,
        "solve",
    )
    sol = page.js("window.dimacq.solution")
    page.js("document.querySelector('#solve').scrollIntoView()")
    page.shot(shots / "firefox-3-solve.png")
    assert page.js("document.querySelectorAll('#solutions tbody tr').length") == 1
    elapsed = time.perf_counter() - t0

    errors = [
        p.get("text") for m, p in events if m == "log.entryAdded" and p.get("level") == "error"
    ]
    requests = [p["request"]["url"] for m, p in events if m == "network.beforeRequestSent"]
    outside = [
        u
        for u in requests
        if not u.startswith(("data:", "blob:", "about:")) and urlsplit(u).hostname != "127.0.0.1"
    ]
    res = sol["result"]
    print(
        f"\n{version}: page ready {ready_ms:.0f} ms; walk {elapsed:.1f} s; "
        f"{len(requests)} requests; verdict {res['verdict']}, mass {res['mass_kg']:.4f} kg "
        f"(truth {truth['mass_kg']}); screenshots in {shots}"
    )
    assert not errors, errors
    assert requests and not outside, outside
    assert res["verdict"] == "ok", res["verdict_reasons"]
    assert res["band_hz"] == pytest.approx(band, abs=1.5)
    assert res["mass_kg"] == pytest.approx(truth["mass_kg"], rel=1e-3)
    assert res["cg_m"] == pytest.approx(truth["cg_m"], abs=1e-3)


def truth_inputs(page: Page) -> int:
    """The number of inputs of the opened setup (the FRF set has one column per input)."""
    return int(page.js("window.dimacq.setup.setup.inputs.length"))
