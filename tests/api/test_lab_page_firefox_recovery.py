"""The recovery path of the lab page in Firefox (Debian's ``firefox-esr``, WebDriver BiDi): a run
with every hit reviewed on the page, ``dimacq serve`` killed with SIGKILL while a hit waits (the
"service unreachable" banner comes and the hit's buttons go off), restarted; a reload offers the
interrupted acquisition, Resume strikes what it is missing, and the FRF set holds every input.

Skipped, with the reason, when Firefox is not installed, except under ``CI=true``.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest
from _firefox_support import FIREFOX, Bidi, Page, launch_firefox, lines_of, stop, wait_line
from _page_support import serve, two_input_setup

from dimacq.api.server import free_port

IN_CI = os.environ.get("CI", "").lower() == "true"
pytestmark = pytest.mark.skipif(
    FIREFOX is None and not IN_CI,
    reason="Firefox is not installed (apt-get install -y firefox-esr); CI installs it",
)
TOKEN = "firefox-recovery-token"
ENDED = "/acquisition \\d+ (succeeded|incomplete|failed|cancelled)/"


@pytest.fixture
def firefox(tmp_path: Path) -> Iterator[tuple[Bidi, list[Any]]]:
    assert FIREFOX is not None, "CI=true: Firefox must be installed (.ci/run installs firefox-esr)"
    ff_port = free_port()
    proc = launch_firefox(tmp_path, ff_port)
    from websockets.sync.client import connect

    events: list[Any] = []
    try:
        wait_line(proc, lines_of(proc), "WebDriver BiDi listening on", "firefox")
        with connect(f"ws://127.0.0.1:{ff_port}/session", max_size=None, open_timeout=20) as ws:
            bidi = Bidi(ws, lambda m, p: events.append((m, p)))
            bidi.call("session.new", {"capabilities": {}})
            yield bidi, events
    finally:
        stop(proc)
        assert proc.stdout is not None
        proc.stdout.close()


PENDING = (
    "(() => { const a = window.dimacq.acq.info; return !!(a && a.pending_review"
    " && /hit \\d+ waits/.test(document.querySelector('#hit-state').textContent)"
    " && !document.querySelector('#hit-reject').disabled); })()"
)


def _decide_one(page: Page) -> None:
    """Accept the waiting hit (reject it when the checks refuse it) and wait until it is gone."""
    number = page.js("window.dimacq.acq.info.pending_review.number")
    refused = page.js("document.querySelector('#hit-accept').disabled")
    page.click("#hit-reject" if refused else "#hit-accept")
    page.wait(
        "(() => { const a = window.dimacq.acq.info; return !a.pending_review"
        f" || a.pending_review.number !== {number}; }})()",
        30,
        f"hit {number} decided",
    )


@pytest.mark.slow
def test_recovery_in_firefox(firefox: Any, tmp_path: Path) -> None:
    bidi, events = firefox
    port = free_port()
    url = f"http://127.0.0.1:{port}"
    proc = serve(tmp_path / "data", port, TOKEN)
    try:
        with httpx.Client(
            base_url=url, headers={"Authorization": f"Bearer {TOKEN}"}, timeout=30
        ) as c:
            sid = c.post("/api/setups", json=two_input_setup()).json()["id"]
        bidi.call("session.subscribe", {"events": ["log.entryAdded"]})
        context = bidi.call("browsingContext.getTree", {})["contexts"][0]["context"]
        page = Page(bidi, context)
        bidi.call(
            "browsingContext.navigate",
            {"context": context, "url": f"{url}/#token={TOKEN}", "wait": "complete"},
        )
        page.wait("document.body.dataset.ready === '1'", 30, "page ready")
        page.js(
            "(() => { const s = document.querySelector('#acq-setup');"
            f" s.value = '{sid}'; s.dispatchEvent(new Event('change'));"
            " document.querySelector('#averages').value = '2';"
            " document.querySelector('#acq-review').checked = true; })()"
        )
        page.click("#acq-start")
        while True:
            page.wait(PENDING, 90, "a hit waits")
            a = page.js("window.dimacq.acq.info")
            if sum(av["accepted"] and av["input_index"] == 0 for av in a["averages"]) >= 2:
                break
            _decide_one(page)
        acq_id = a["id"]

        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(20)
        t_kill = time.perf_counter()
        page.wait(
            "!document.querySelector('#offline').hidden && ['#hit-accept', '#hit-reject',"
            " '#hit-redo'].every((s) => document.querySelector(s).disabled)",
            10,
            "the banner, the hit's buttons off",
        )
        banner_s = time.perf_counter() - t_kill

        proc = serve(tmp_path / "data", port, TOKEN)
        page.wait("document.querySelector('#offline').hidden", 30, "the banner gone")
        bidi.call("browsingContext.reload", {"context": context, "wait": "complete"})
        page.wait("document.body.dataset.ready === '1'", 30, "page ready after the reload")
        resume = f"[data-rec='resume'][data-id='{acq_id}']"
        page.wait(f"!!document.querySelector({json.dumps(resume)})", 20, "Resume offered")
        page.click(resume)
        page.wait(f"window.dimacq.acq.id && window.dimacq.acq.id !== {acq_id}", 20, "resumed")
        new_id = page.js("window.dimacq.acq.id")
        while True:
            page.wait(
                f"{PENDING} || {ENDED}.test(document.querySelector('#msg').textContent)",
                90,
                "a hit waits or the run ends",
            )
            if not page.js(PENDING):
                break
            _decide_one(page)
        with httpx.Client(
            base_url=url, headers={"Authorization": f"Bearer {TOKEN}"}, timeout=30
        ) as c:
            a = c.get(f"/api/acquisitions/{new_id}").json()
            assert a["state"] == "succeeded", a
            data = c.get(f"/api/frfs/{a['frf_id']}/data").json()
            setup = c.get(f"/api/setups/{sid}").json()["setup"]
        got = sorted((i["node"], i["direction"]) for i in data["inputs"])
        assert got == sorted((e["node"], e["direction"]) for e in setup["inputs"]), got
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
            try:
                proc.wait(30)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
    errors = [
        p.get("text", "") for m, p in events if m == "log.entryAdded" and p.get("level") == "error"
    ]
    print(f"\nfirefox: banner and hit buttons off {banner_s:.2f} s after the kill")
    assert not [e for e in errors if "NetworkError" not in e and "127.0.0.1" not in e], errors
