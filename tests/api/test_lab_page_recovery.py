"""The lab page never loses a run or a result (headless Chromium through Playwright).

Each test is a user's path:

- a reload during a run: the acquisition is offered for Reattach, and Reattach brings back the
  hit waiting for a decision, which is then decided on the page (impulse rig, in-process);
- a double-click on Solve stores one solution; after a reload the stored solution opens from its
  row and its report link renders the report; the FRF plot's wheel zoom and its log-frequency and
  dB scales change the axes the plot reports (``plot.view()``, the canvas's data attributes);
- ``kill -9`` of ``dimacq serve`` while a hit waits: the "service unreachable" banner comes and
  the hit's buttons go off; after a restart and a reload, Resume from the page strikes what is
  missing and the FRF set holds every input (simulated lab, ``dimacq serve`` as its process).

Needs Debian's ``chromium`` and Playwright's Python package; skipped when either is missing.
"""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest
from _api_support import TOKEN, served_lab
from _lab_rig_support import IMPULSE_SETUP, struck_inputs_factory
from _page_support import serve, two_input_setup

from dimacq.api.server import free_port
from dimacq.io.setup_file import dump_setup_dict

CHROMIUM = shutil.which("chromium")
playwright_sync = pytest.importorskip("playwright.sync_api")
pytestmark = pytest.mark.skipif(CHROMIUM is None, reason="Debian's chromium is not installed")

EXAMPLES = Path(__file__).resolve().parents[2] / "config" / "examples"
ENDED = "/acquisition \\d+ (succeeded|incomplete|failed|cancelled)/"
#: Chromium's own line for a request refused while the service is down (not the page's error)
REFUSED = ("net::ERR_CONNECTION_REFUSED", "net::ERR_EMPTY_RESPONSE", "Failed to load resource")


@pytest.fixture
def browser() -> Iterator[Any]:
    with playwright_sync.sync_playwright() as pw:
        b = pw.chromium.launch(executable_path=CHROMIUM)
        try:
            yield b
        finally:
            b.close()


def _page(browser: Any, errors: list[str]) -> Any:
    page = browser.new_context(viewport={"width": 1280, "height": 900}).new_page()
    page.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
    page.on("pageerror", lambda e: errors.append(str(e)))
    return page


def _ready(page: Any, url: str) -> None:
    page.goto(url)
    page.wait_for_selector("body[data-ready='1']", timeout=30_000)


def _pending(page: Any, number: int | None = None, timeout_ms: int = 60_000) -> int:
    """Wait for a hit shown waiting for a decision (``number`` or any); returns its number."""
    want = "true" if number is None else f"a.pending_review.number === {number}"
    page.wait_for_function(
        "() => { const a = window.dimacq.acq.info; return a && a.pending_review && "
        f"{want} && /hit \\d+ waits/.test(document.querySelector('#hit-state').textContent)"
        " && !document.querySelector('#hit-reject').disabled; }",
        timeout=timeout_ms,
    )
    return int(page.evaluate("() => window.dimacq.acq.info.pending_review.number"))


def _decide_all(page: Any) -> None:
    """Accept every hit the checks pass (reject the others) until the acquisition ends."""
    while True:
        page.wait_for_function(
            "() => !document.querySelector('#hit-reject').disabled"
            f" || {ENDED}.test(document.querySelector('#msg').textContent)",
            timeout=90_000,
        )
        if page.locator("#hit-reject").is_disabled():
            return
        number = _pending(page)
        page.click("#hit-reject" if page.locator("#hit-accept").is_disabled() else "#hit-accept")
        page.wait_for_function(
            "() => { const a = window.dimacq.acq.info; return a.state !== 'running'"
            f" || !a.pending_review || a.pending_review.number !== {number}; }}",
            timeout=30_000,
        )


@pytest.mark.slow
def test_reload_during_a_run_then_reattach_decides_the_waiting_hit(
    tmp_path: Path, browser: Any
) -> None:
    errors: list[str] = []
    with served_lab(tmp_path, "", struck_inputs_factory()) as (c, _lab):
        sid = c.post("/api/setups", json=dump_setup_dict(IMPULSE_SETUP)).json()["id"]
        page = _page(browser, errors)
        _ready(page, f"{c.base_url}/#token={TOKEN}")
        page.select_option("#acq-setup", str(sid))
        page.fill("#averages", "2")
        page.check("#acq-review")
        page.click("#acq-start")
        assert _pending(page, 1) == 1
        acq_id = page.evaluate("() => window.dimacq.acq.id")
        # the status line beside Start says what runs; Start is off while it runs
        assert f"acquisition {acq_id} running" in page.inner_text("#status-acquire")
        assert page.locator("#acq-start").is_disabled()

        # a reload: nothing of the run on the page but the offer to pick it up
        page.reload()
        page.wait_for_selector("body[data-ready='1']", timeout=30_000)
        reattach = page.locator(f"[data-rec='reattach'][data-id='{acq_id}']")
        reattach.wait_for(timeout=10_000)
        assert page.locator(f"[data-rec='cancel'][data-id='{acq_id}']").count() == 1
        assert page.locator("#hit-reject").is_disabled()
        reattach.click()
        # the hit that was waiting comes back, and is decided here
        assert _pending(page, 1, 20_000) == 1
        assert page.evaluate("() => window.dimacq.acq.id") == acq_id
        # the hit view on the event: milliseconds around the force peak, channels named
        force = page.evaluate("() => window.dimacq.plots.hitForce.view()")
        assert -5 <= force["x"][0] < 0 < force["x"][1] <= 20, force
        assert "time from the hit peak, ms" in page.evaluate(
            "() => window.dimacq.plots.hitForce.opts.xLabel"
        )
        shots = Path(os.environ.get("DIMACQ_PAGE_SHOTS") or tmp_path / "screenshots")
        shots.mkdir(parents=True, exist_ok=True)
        page.locator("#acquire").screenshot(path=str(shots / "reattached-hit.png"))
        page.click("#hit-accept")
        _decide_all(page)
        page.wait_for_function(f"() => {ENDED}.test(document.querySelector('#msg').textContent)")
        a = c.get(f"/api/acquisitions/{acq_id}").json()
        assert a["state"] == "succeeded", a
        assert a["averages"][0]["number"] == 1 and a["averages"][0]["accepted"], a["averages"]
        assert a["accepted_per_input"] == [2, 2], a
        # the table's coherence: in the band the solve will use (here the set's span), said so
        page.wait_for_function(
            "() => /coherence γ̄² in [0-9.]+–[0-9.]+ Hz/.test("
            "document.querySelector('#acq-inputs thead').textContent)",
            timeout=20_000,
        )
        # nothing left to pick up
        page.wait_for_function(
            f"() => !document.querySelector(\"[data-rec][data-id='{acq_id}']\")", timeout=10_000
        )
        page.context.close()  # before the service stops: its heartbeat would find it gone
    assert not errors, errors


def _whole_test_uff(tmp_path: Path) -> bytes:
    from dimacq.io.setup_file import load_setup
    from dimacq.io.uff import dump_uff, read_frf_uff

    setup = load_setup(EXAMPLES / "six_triax_setup.toml")
    return bytes(dump_uff(read_frf_uff(EXAMPLES / "six_triax_frf.uff", setup), setup))


def _view(page: Any, plot: str = "mag") -> dict[str, Any]:
    return dict(page.evaluate(f"() => window.dimacq.plots.{plot}.view()"))


@pytest.mark.slow
def test_double_click_solve_stores_one_solution_that_reopens_after_a_reload(
    tmp_path: Path, browser: Any
) -> None:
    errors: list[str] = []
    shots = Path(os.environ.get("DIMACQ_PAGE_SHOTS") or tmp_path / "screenshots")
    shots.mkdir(parents=True, exist_ok=True)
    with served_lab(tmp_path, "", struck_inputs_factory()) as (c, _lab):
        r = c.post(
            "/api/setups/import?format=uff&name=six-triax.uff",
            content=_whole_test_uff(tmp_path),
        )
        assert r.status_code == 201, r.text
        frf_id = r.json()["frf_id"]
        page = _page(browser, errors)
        _ready(page, f"{c.base_url}/#token={TOKEN}")
        page.select_option("#frf-set", str(frf_id))
        page.wait_for_function("() => window.dimacq.frfData && window.dimacq.plots.mag")
        assert "FRF set" in page.inner_text("#status-frfs")

        # --- the plot: units on the axis, legend by channel kind; wheel zoom; log f; dB; reset
        full = _view(page)
        assert full["xScale"] == "linear" and full["yScale"] == "log" and not full["zoomed"]
        ylabel = page.evaluate("() => window.dimacq.plots.mag.yLabel()")
        assert ylabel == "|H|, (m/s²)/N", ylabel
        assert "accelerometers" in page.inner_text("#frf-mag + .legend")
        box = page.locator("#frf-mag").bounding_box()
        page.locator("#frf-mag").scroll_into_view_if_needed()
        box = page.locator("#frf-mag").bounding_box()
        page.mouse.move(box["x"] + box["width"] / 2, box["y"] + box["height"] / 2)
        scroll_before = page.evaluate("() => window.scrollY")
        page.mouse.wheel(0, -240)
        page.wait_for_function("() => window.dimacq.plots.mag.view().zoomed")
        zoomed = _view(page)
        assert zoomed["x"][1] - zoomed["x"][0] < 0.9 * (full["x"][1] - full["x"][0]), zoomed
        assert page.evaluate("() => window.scrollY") == scroll_before  # the page did not scroll
        # the cursor readout: frequency, value and the channel's name
        readout = page.get_attribute("#frf-mag", "data-cursor") or ""
        assert " Hz: " in readout and "(m/s²)/N" in readout and " — " in readout, readout
        page.check("#frf-logx")
        page.check("#frf-db")
        logv = _view(page)
        assert logv["xScale"] == "log" and logv["yScale"] == "dB", logv
        assert page.get_attribute("#frf-mag", "data-x-scale") == "log"
        assert page.evaluate("() => window.dimacq.plots.mag.yLabel()") == ("|H|, dB re 1 (m/s²)/N")
        assert logv["y"][1] < 100 and logv["y"][0] > -300, logv  # dB, not |H|
        page.locator("#frfs").screenshot(path=str(shots / "frfs-log-db.png"))
        page.click("#frf-reset")
        reset = _view(page)
        assert not reset["zoomed"] and reset["x"][1] == pytest.approx(full["x"][1]), reset
        page.uncheck("#frf-logx")
        page.uncheck("#frf-db")

        # --- a band typed outside the FRF span is refused on the form, naming the field
        page.fill("#band-lo", "10")
        page.fill("#band-hi", "1000000")
        page.click("#solve-btn")
        page.wait_for_function(
            "() => document.querySelector('#status-solve').classList.contains('err')"
        )
        assert "band, Hz" in page.inner_text("#status-solve")
        assert "bad" in (page.get_attribute("#band-hi", "class") or "")
        assert c.get("/api/solutions").json() == [] or not c.get("/api/solutions").json()

        # --- a double-click on Solve: one solution
        page.fill("#band-hi", "100")
        page.dblclick("#solve-btn")
        page.wait_for_function(
            "() => document.querySelector('#status-solve').classList.contains('busy')"
        )
        assert page.locator("#solve-btn").is_disabled()
        page.locator("#solve").screenshot(path=str(shots / "solving.png"))
        page.wait_for_function(
            "() => document.querySelectorAll('#solutions tbody tr').length === 1"
            " && !document.querySelector('#solve-btn').disabled",
            timeout=120_000,
        )
        sols = c.get("/api/solutions").json()
        sols = sols["items"] if isinstance(sols, dict) else sols
        assert len(sols) == 1, [s["id"] for s in sols]
        sid = sols[0]["id"]

        # --- a reload: the FRF set and the solution come back; a row opens it and its report
        page.reload()
        page.wait_for_selector("body[data-ready='1']", timeout=30_000)
        page.wait_for_function(
            f"() => window.dimacq.solution && window.dimacq.solution.id === {sid}"
            " && window.dimacq.frf && document.querySelector('#report-link')",
            timeout=30_000,
        )
        assert f"solution {sid}" in page.inner_text("#solution")
        page.evaluate("() => { window.dimacq.solution = null; }")
        page.click(f"[data-open-solution='{sid}']")
        page.wait_for_function(
            f"() => window.dimacq.solution && window.dimacq.solution.id === {sid}"
            " && window.dimacq.spectrum"
        )
        assert "verdict: ok" in page.inner_text("#solution").lower()
        assert "95 % interval" in page.inner_text("#solution")
        page.locator("#solve").screenshot(path=str(shots / "solution-reopened.png"))
        href = page.get_attribute(f"[data-report='{sid}']", "href")
        assert href and href.startswith(f"/report?solution={sid}")
        report = page.context.new_page()
        report.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
        report.goto(f"{c.base_url}{href}")
        report.wait_for_function("() => document.body.innerText.includes('mass')", timeout=30_000)
        assert str(sid) in report.inner_text("body")
        page.context.close()  # before the service stops: its heartbeat would find it gone
    assert not errors, errors


@pytest.mark.slow
def test_kill_the_service_mid_acquisition_then_resume_from_the_page(
    tmp_path: Path, browser: Any
) -> None:
    """kill -9 while a hit waits: the banner and the hit's buttons off; restart, reload, Resume:
    the FRF set holds every input."""
    errors: list[str] = []
    port = free_port()
    url = f"http://127.0.0.1:{port}"
    proc = serve(tmp_path / "data", port, TOKEN)
    try:
        with httpx.Client(
            base_url=url, headers={"Authorization": f"Bearer {TOKEN}"}, timeout=30
        ) as c:
            sid = c.post("/api/setups", json=two_input_setup()).json()["id"]
            # the simulator's truth, for the page to show beside an answer (the scenario's)
            from dimacq.simulators.lab.scenarios import build_scenario

            truth = c.get("/api/simulation/truth").json()
            want = build_scenario("calibration-mass-bungee", None).truth_json()
            assert truth["mass_kg"] == want["mass_kg"] and truth["cg_m"] == want["cg_m"]
        page = _page(browser, errors)
        _ready(page, f"{url}/#token={TOKEN}")
        page.select_option("#acq-setup", str(sid))
        page.fill("#averages", "2")
        page.check("#acq-review")
        page.click("#acq-start")
        acq_id = None
        # decide hits until the second input is being struck, then kill while a hit waits
        while True:
            number = _pending(page)
            acq_id = page.evaluate("() => window.dimacq.acq.id")
            a = page.evaluate("() => window.dimacq.acq.info")
            if sum(av["accepted"] and av["input_index"] == 0 for av in a["averages"]) >= 2:
                break
            page.click(
                "#hit-reject" if page.locator("#hit-accept").is_disabled() else "#hit-accept"
            )
            page.wait_for_function(
                "() => { const a = window.dimacq.acq.info; return !a.pending_review"
                f" || a.pending_review.number !== {number}; }}",
                timeout=30_000,
            )
        page.locator("#acquire").screenshot(path=str(tmp_path / "before-kill.png"))
        t_kill = time.perf_counter()
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(20)
        page.wait_for_selector("#offline:not([hidden])", timeout=10_000)
        page.wait_for_function(
            "() => ['#hit-accept', '#hit-reject', '#hit-redo']"
            ".every((s) => document.querySelector(s).disabled)",
            timeout=10_000,
        )
        banner_s = time.perf_counter() - t_kill
        n_err = len(errors)
        time.sleep(4)  # the outage goes on: the page backs off
        errors_in_outage = len(errors) - n_err
        assert page.locator("#hit-accept").is_disabled()
        assert "unreachable" in page.inner_text("#offline")
        shots = Path(os.environ.get("DIMACQ_PAGE_SHOTS") or tmp_path / "screenshots")
        shots.mkdir(parents=True, exist_ok=True)
        page.screenshot(path=str(shots / "service-unreachable.png"))

        # restart; the banner goes by itself; a reload offers Resume
        proc = serve(tmp_path / "data", port, TOKEN)
        page.wait_for_selector("#offline", state="hidden", timeout=30_000)
        page.wait_for_selector(f"[data-rec='resume'][data-id='{acq_id}']", timeout=20_000)
        page.reload()
        page.wait_for_selector("body[data-ready='1']", timeout=30_000)
        resume = page.locator(f"[data-rec='resume'][data-id='{acq_id}']")
        resume.wait_for(timeout=20_000)
        assert "interrupted" in page.inner_text("#acq-recover")
        page.locator("#acquire").screenshot(path=str(shots / "pick-up-interrupted.png"))
        resume.click()
        page.wait_for_function(
            f"() => window.dimacq.acq.id && window.dimacq.acq.id !== {acq_id}", timeout=20_000
        )
        new_id = page.evaluate("() => window.dimacq.acq.id")
        _decide_all(page)
        page.wait_for_function(f"() => {ENDED}.test(document.querySelector('#msg').textContent)")
        with httpx.Client(
            base_url=url, headers={"Authorization": f"Bearer {TOKEN}"}, timeout=30
        ) as c:
            a = c.get(f"/api/acquisitions/{new_id}").json()
            assert a["state"] == "succeeded", a
            data = c.get(f"/api/frfs/{a['frf_id']}/data").json()
            setup = c.get(f"/api/setups/{sid}").json()["setup"]
            assert c.get(f"/api/acquisitions/{acq_id}").json()["state"] == "resumed"
        got = [(i["node"], i["direction"]) for i in data["inputs"]]
        want = [(e["node"], e["direction"]) for e in setup["inputs"]]
        assert sorted(got) == sorted(want), (got, want)
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
            try:
                proc.wait(30)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
    print(
        f"\nbanner and hit buttons off {banner_s:.2f} s after the kill; "
        f"{errors_in_outage} console errors in the next 4 s of the outage"
    )
    page_errors = [e for e in errors if not any(r in e for r in REFUSED)]
    assert not page_errors, page_errors
    assert errors_in_outage <= 8, errors[n_err:]
