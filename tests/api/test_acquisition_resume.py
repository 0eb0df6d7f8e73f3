"""Finish and resume an acquisition that ended short (issue 24, "resume after a crash").

On the impulse source (:mod:`_lab_rig_support`), whose FRFs have a closed form. The acquisition
is stopped in review mode at a known hit (input 10+X: 3 of 3, input 11+X: 1 of 3 accepted) and
marked ``interrupted`` as :meth:`AcquisitionService.recover` marks it after a crash (the real
kill of ``dimacq serve`` is in ``test_crash_safety.py``).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from pathlib import Path

import httpx
import numpy as np
import pytest
from _acq_support import ImpulseSource
from _api_support import served_lab
from _lab_rig_support import IMPULSE_SETUP, impulse_rig_factory

from dimacq.io.setup_file import dump_setup_dict
from dimacq.model.impact import ImpactSettings
from dimacq.services.acquisition.session import input_frf
from dimacq.services.lab import Lab

BODY = {"averages_per_input": 3, "min_averages": 2, "record_samples": 2048, "trigger_level_n": 20.0}


@pytest.fixture
def lab_api(tmp_path: Path, database_url: str) -> Iterator[tuple[httpx.Client, Lab]]:
    with served_lab(tmp_path, database_url, impulse_rig_factory()) as (c, lab):
        yield c, lab


def _wait(c: httpx.Client, acq_id: int, cond: Callable[[dict], bool]) -> dict:
    deadline = time.monotonic() + 30
    while time.monotonic() < deadline:
        a = c.get(f"/api/acquisitions/{acq_id}").json()
        if cond(a):
            return a
        time.sleep(0.02)
    raise AssertionError(f"acquisition {acq_id}: condition not reached: {a}")


def _accept(c: httpx.Client, acq_id: int, n: int) -> None:
    for _ in range(n):
        a = _wait(c, acq_id, lambda a: a["pending_review"] is not None or a["state"] != "running")
        assert a["state"] == "running", a
        number = a["pending_review"]["number"]
        r = c.post(
            f"/api/acquisitions/{acq_id}/review", json={"number": number, "decision": "accept"}
        )
        assert r.status_code == 200, r.text


def _frf(c: httpx.Client, frf_id: int) -> tuple[np.ndarray, np.ndarray, list[int]]:
    data = c.get(f"/api/frfs/{frf_id}/data").json()
    f = np.asarray(data["frequencies_hz"])
    h = np.asarray(data["real"]) + 1j * np.asarray(data["imag"])
    return f, h, [i["node"] for i in data["inputs"]]


def _closed_form(f: np.ndarray) -> np.ndarray:
    return ImpulseSource(n_inputs=2, n_responses=3, response_gain=0.01).frf(f)


def _interrupted(c: httpx.Client, lab: Lab) -> int:
    """An acquisition left with input 10+X complete (3) and 11+X at 1 of 3, interrupted."""
    sid = c.post("/api/setups", json=dump_setup_dict(IMPULSE_SETUP)).json()["id"]
    r = c.post("/api/acquisitions", json={**BODY, "setup_id": sid, "review": True})
    assert r.status_code == 202, r.text
    aid = r.json()["id"]
    _accept(c, aid, 4)
    _wait(c, aid, lambda a: a["pending_review"] is not None)  # the 5th hit waits
    assert c.post(f"/api/acquisitions/{aid}/stop").status_code == 200
    a = _wait(c, aid, lambda a: a["state"] != "running")
    assert a["accepted_per_input"] == [3, 1] and a["frf_id"] is None, a
    # what recover() does to a running acquisition after the service was killed
    lab.acquisitions._set(aid, state="interrupted", message="the service stopped")
    return aid


@pytest.mark.slow
def test_finish_an_interrupted_acquisition(lab_api) -> None:
    c, lab = lab_api
    aid = _interrupted(c, lab)
    r = c.post(f"/api/acquisitions/{aid}/finish")
    assert r.status_code == 200, r.text
    a = r.json()
    # never a silent success: the missing input is named, by point and direction
    assert a["state"] == "incomplete" and a["incomplete_inputs"] == [1], a
    assert "11+X (1 of 3)" in a["message"] and "resume" in a["message"], a["message"]
    f, h, nodes = _frf(c, a["frf_id"])
    assert nodes == [10]
    assert c.get(f"/api/frfs/{a['frf_id']}").json()["acquisition_id"] == aid
    np.testing.assert_allclose(h, _closed_form(f)[:, :, :1], atol=3e-3 * np.abs(h).max())
    # the live estimator on the kept files: the same numbers
    recs = []
    for av in a["averages"]:
        if av["accepted"] and av["input_index"] == 0:
            arrays, attrs = lab.arrays.read(av["path"])
            recs.append(arrays)
    applied = ImpactSettings.model_validate(a["config"]["applied"])
    f0, h0, _ = input_frf(recs, float(attrs["sample_rate_hz"]), applied)
    np.testing.assert_array_equal(h[:, :, 0], h0[f0 > 0])
    # finished: not again
    again = c.post(f"/api/acquisitions/{aid}/finish")
    assert again.status_code == 409 and "FRF set" in again.json()["detail"], again.text


@pytest.mark.slow
def test_resume_strikes_only_what_is_missing(lab_api) -> None:
    c, lab = lab_api
    aid = _interrupted(c, lab)
    assert c.post("/api/acquisitions/999/resume").status_code == 404
    finished = c.post(f"/api/acquisitions/{aid}/finish").json()
    r = c.post(f"/api/acquisitions/{aid}/resume")
    assert r.status_code == 202, r.text
    b = r.json()
    assert b["state"] == "running" and b["inputs"] == [0, 1] and b["config"]["resume_of"] == aid
    assert b["config"]["merge_frf_id"] == finished["frf_id"]
    old = c.get(f"/api/acquisitions/{aid}").json()
    assert old["state"] == "resumed" and f"acquisition {b['id']}" in old["message"], old
    # resumed already; the new one runs; both 409
    r = c.post(f"/api/acquisitions/{aid}/resume")
    assert r.status_code == 409 and "resumed" in r.json()["detail"], r.text
    r = c.post(f"/api/acquisitions/{b['id']}/resume")
    assert r.status_code == 409 and "running" in r.json()["detail"], r.text
    _accept(c, b["id"], 2)  # input 11+X: its 2 missing averages, nothing of 10+X
    b = _wait(c, b["id"], lambda a: a["state"] != "running")
    assert b["state"] == "succeeded" and b["incomplete_inputs"] == [], b
    assert b["accepted_per_input"] == [3, 3]  # the 4 kept and the 2 new
    assert [av["input_index"] for av in b["averages"]] == [1, 1]
    f, h, nodes = _frf(c, b["frf_id"])
    assert nodes == [10, 11]
    np.testing.assert_allclose(h, _closed_form(f), atol=3e-3 * np.abs(h).max())
    # input 10+X: from the same kept averages, the same numbers as the finish gave
    np.testing.assert_array_equal(h[:, :, 0], _frf(c, finished["frf_id"])[1][:, :, 0])
    # nothing left to resume
    r = c.post(f"/api/acquisitions/{b['id']}/resume")
    assert r.status_code == 409 and "succeeded" in r.json()["detail"], r.text


@pytest.mark.slow
def test_resume_without_finish_and_refusals(lab_api) -> None:
    """Resumed straight away (no FRF set yet): the new set still covers every input; a
    complete acquisition's kept averages are not struck again (409, finish it)."""
    c, lab = lab_api
    aid = _interrupted(c, lab)
    r = c.post(f"/api/acquisitions/{aid}/resume")
    assert r.status_code == 202, r.text
    b = r.json()
    assert b["config"]["merge_frf_id"] is None
    _accept(c, b["id"], 2)
    b = _wait(c, b["id"], lambda a: a["state"] != "running")
    assert b["state"] == "succeeded", b
    assert _frf(c, b["frf_id"])[2] == [10, 11]
    # an interrupted acquisition that has all its averages: nothing to strike
    lab.acquisitions._set(b["id"], state="interrupted", frf_id=None)
    r = c.post(f"/api/acquisitions/{b['id']}/resume")
    assert r.status_code == 409 and "nothing to strike" in r.json()["detail"], r.text
    r = c.post(f"/api/acquisitions/{b['id']}/finish")  # over the whole chain: complete
    assert r.status_code == 200 and r.json()["state"] == "succeeded", r.text


@pytest.mark.slow
def test_a_resumed_acquisition_is_deleted_after_the_one_that_resumed_it(lab_api) -> None:
    c, lab = lab_api
    aid = _interrupted(c, lab)
    b = c.post(f"/api/acquisitions/{aid}/resume").json()
    _accept(c, b["id"], 2)
    _wait(c, b["id"], lambda a: a["state"] != "running")
    r = c.delete(f"/api/acquisitions/{aid}")
    assert r.status_code == 409 and f"acquisition {b['id']}" in r.json()["detail"], r.text
    assert c.delete(f"/api/acquisitions/{b['id']}").status_code == 204
    assert c.delete(f"/api/acquisitions/{aid}").status_code == 204


@pytest.mark.slow
def test_redo_on_a_resumed_acquisition_drops_the_kept_averages_too(lab_api) -> None:
    c, lab = lab_api
    aid = _interrupted(c, lab)
    b = c.post(f"/api/acquisitions/{aid}/resume").json()
    a = _wait(c, b["id"], lambda a: a["pending_review"] is not None)
    n = a["pending_review"]["number"]
    r = c.post(f"/api/acquisitions/{b['id']}/review", json={"number": n, "decision": "redo"})
    assert r.status_code == 200, r.text
    _accept(c, b["id"], 3)  # input 11+X again from nothing: 3 averages
    b = _wait(c, b["id"], lambda a: a["state"] != "running")
    assert b["state"] == "succeeded" and b["accepted_per_input"] == [3, 3], b
    old = c.get(f"/api/acquisitions/{aid}").json()
    assert old["accepted_per_input"] == [3, 0]  # its kept average of 11+X was redone
