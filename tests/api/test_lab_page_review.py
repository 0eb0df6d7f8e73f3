"""The acquire step's review in headless Chromium (issue 24, "Reviewing a hit loses the test"),
on the impulse rig behind an in-process service: a hit with samples lost has Accept disabled,
the reason shown and no "accept anyway"; a double hit has Accept disabled and "accept anyway",
which keeps it; unticking "review every hit" during a run lets the checks decide the rest.

Needs Debian's ``chromium`` and Playwright's Python package; skipped when either is missing.
"""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import Any

import pytest
from _api_support import TOKEN, served_lab
from _lab_rig_support import IMPULSE_SETUP, struck_inputs_factory

from dimacq.io.setup_file import dump_setup_dict
from dimacq.services.acquisition.session import OPERATOR_OVERRIDE
from dimacq.simulators.daq.backend import DaqFaults

CHROMIUM = shutil.which("chromium")
playwright_sync = pytest.importorskip("playwright.sync_api")
pytestmark = pytest.mark.skipif(CHROMIUM is None, reason="Debian's chromium is not installed")

WARNED: list[str] = []
ENDED = "/acquisition \\d+ (succeeded|incomplete|failed|cancelled)/"


def _seen(page: Any) -> str:
    """What the page shows, for a failure's message."""
    return str(
        page.evaluate(
            "() => ({info: window.dimacq.acq.info, msg: document.querySelector('#msg')"
            ".textContent, hit: document.querySelector('#hit-state').textContent,"
            " prompt: document.querySelector('#prompt').textContent})"
        )
    )


def _pending(page: Any, number: int) -> dict[str, Any]:
    try:
        page.wait_for_function(
            "() => { const a = window.dimacq.acq.info; return a && a.pending_review"
            f" && a.pending_review.number === {number}"
            f" && /hit {number}/.test(document.querySelector('#hit-state').textContent)"
            " && !document.querySelector('#hit-reject').disabled; }",
            timeout=60_000,
        )
    except playwright_sync.TimeoutError:
        raise AssertionError(
            f"hit {number} is not shown waiting: {_seen(page)}, {WARNED}"
        ) from None
    return page.evaluate("() => window.dimacq.acq.info.pending_review")


def _decided(page: Any, number: int) -> None:
    page.wait_for_function(
        "() => { const a = window.dimacq.acq.info; return a.state !== 'running'"
        f" || !a.pending_review || a.pending_review.number !== {number}; }}",
        timeout=60_000,
    )


@pytest.mark.slow
def test_review_on_the_page(tmp_path: Path) -> None:
    factory = struck_inputs_factory(
        double_hit_input=1, faults=lambda: DaqFaults(lost_transfers={1})
    )
    errors: list[str] = []
    warned = WARNED
    with served_lab(tmp_path, "", factory) as (c, _lab):
        sid = c.post("/api/setups", json=dump_setup_dict(IMPULSE_SETUP)).json()["id"]
        with playwright_sync.sync_playwright() as pw:
            browser = pw.chromium.launch(executable_path=CHROMIUM)
            page = browser.new_page()
            page.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
            page.on("pageerror", lambda e: errors.append(str(e)))
            page.on("console", lambda m: warned.append(m.text) if m.type == "warning" else None)
            page.goto(f"{c.base_url}/#token={TOKEN}")
            page.wait_for_selector("body[data-ready='1']", timeout=20_000)
            page.select_option("#acq-setup", str(sid))
            page.fill("#averages", "2")
            page.check("#acq-review")
            page.click("#acq-start")

            # hit 1: a USB transfer lost in its record: no accept, not even anyway
            p = _pending(page, 1)
            assert p["accept"] == "no", p
            assert page.locator("#hit-accept").is_disabled()
            assert page.locator("#hit-override").is_hidden()
            assert "cannot be accepted" in page.inner_text("#hit-why")
            assert "samples lost" in page.inner_text("#hit-why")
            page.click("#hit-reject")
            _decided(page, 1)
            for number in (2, 3, 4):  # clean hits: Accept on, nothing to say
                _pending(page, number)
                assert page.inner_text("#hit-why").strip() == ""
                assert page.locator("#hit-override").is_hidden()
                page.click("#hit-accept")
                _decided(page, number)
            # hit 5: a double hit: Accept off with the reason, "accept anyway" keeps it
            p = _pending(page, 5)
            assert p["reasons"] == ["double hit"], p
            assert page.locator("#hit-accept").is_disabled()
            assert "double hit" in page.inner_text("#hit-why")
            assert "accept it anyway" in page.inner_text("#prompt")
            page.click("#hit-override")
            page.wait_for_function(
                f"() => {ENDED}.test(document.querySelector('#msg').textContent)"
            )
            assert "succeeded" in page.inner_text("#msg"), page.inner_text("#msg")
            a = page.evaluate("() => window.dimacq.acq.info")
            assert a["averages"][-1]["reason"] == f"double hit; {OPERATOR_OVERRIDE}"
            assert page.locator("#acq-inputs tbody tr").count() == 2
            # the override stays on record in the input's row
            assert "hit 5: double hit" in page.inner_text("#acq-inputs .override")

            # review unticked while the first hit of the next acquisition waits: the checks
            # decide it and the rest
            page.check("#acq-review")
            page.click("#acq-start")
            page.wait_for_function(
                f"() => {{ const a = window.dimacq.acq.info; return a && a.id !== {a['id']}"
                " && a.pending_review && !document.querySelector('#hit-reject').disabled; }",
                timeout=60_000,
            )
            # the final state of the first stays (no read under way when it ended overwrites it)
            assert page.evaluate("() => window.dimacq.acq.info.id") != a["id"]
            page.uncheck("#acq-review")
            second_id = page.evaluate("() => window.dimacq.acq.id")
            page.wait_for_function(
                f"() => new RegExp('acquisition {second_id} (succeeded|incomplete|failed|cancell"
                "ed)').test(document.querySelector('#msg').textContent)",
                timeout=60_000,
            )
            second = page.evaluate("() => window.dimacq.acq.info")
            msg, prompt = page.inner_text("#msg"), page.inner_text("#prompt")
            browser.close()
    # input 11's strikes after its first are double hits: the checks reject them now, it is
    # left with 1 average: the acquisition is incomplete, said so, the input named
    assert second["review"] is False, second
    assert [(s["name"], s["accepted"], s["state"]) for s in second["input_states"]] == [
        ("10+X", 2, "complete"),
        ("11+X", 1, "incomplete"),
    ], (second["state"], second["id"], msg, prompt, WARNED)
    assert second["state"] == "incomplete" and "11+X" in second["message"], second
    # the count it was held to: 2 averages asked, so "fewer than 2" (not the service's 3)
    assert "fewer than 2 accepted averages" in second["message"], second["message"]
    assert "incomplete" in msg and "incomplete (no FRF): 11+X" in prompt, (msg, prompt)
    assert not errors, errors
