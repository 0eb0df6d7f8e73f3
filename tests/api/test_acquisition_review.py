"""The operator's decisions during an acquisition (issue 13): accept / reject / redo each hit,
stop and keep the accepted averages, redo one input and append inputs into an FRF set.

On the impulse source (:mod:`_lab_rig_support`), whose FRFs have a closed form: what the operator
decides must be exactly what the stored averages and FRFs say.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest
from _acq_support import ImpulseSource
from _api_support import served_lab
from _lab_rig_support import IMPULSE_SETUP, struck_inputs_factory

from dimacq.drivers.daq.protocol import frame_size
from dimacq.io.setup_file import dump_setup_dict
from dimacq.services.acquisition.session import OPERATOR_OVERRIDE, OPERATOR_REDO, OPERATOR_REJECT
from dimacq.simulators.daq.backend import DaqFaults
from dimacq.simulators.imperfections import NONE

BODY = {"averages_per_input": 2, "min_averages": 2, "record_samples": 2048, "trigger_level_n": 20.0}


@pytest.fixture
def review_api(tmp_path: Path, database_url: str) -> Iterator[httpx.Client]:
    with served_lab(tmp_path, database_url, struck_inputs_factory()) as (c, _lab):
        yield c


def _wait(c: httpx.Client, acq_id: int, cond: Callable[[dict], bool]) -> dict:
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        a = c.get(f"/api/acquisitions/{acq_id}").json()
        if cond(a):
            return a
        time.sleep(0.02)
    raise AssertionError(f"acquisition {acq_id}: condition not reached: {a}")


def _decide(c: httpx.Client, acq_id: int, decision: str) -> dict:
    """Wait for the next hit to review, look at it, decide; return the hit's view."""
    a = _wait(c, acq_id, lambda a: a["pending_review"] is not None or a["state"] != "running")
    assert a["state"] == "running", a
    hit = c.get(f"/api/acquisitions/{acq_id}/hit").json()
    n = a["pending_review"]["number"]
    assert hit["pending"] and hit["number"] == n
    r = c.post(f"/api/acquisitions/{acq_id}/review", json={"number": n, "decision": decision})
    assert r.status_code == 200, r.text
    return hit


def _frf(c: httpx.Client, frf_id: int) -> tuple[np.ndarray, np.ndarray, list[int]]:
    data = c.get(f"/api/frfs/{frf_id}/data").json()
    f = np.asarray(data["frequencies_hz"])
    h = np.asarray(data["real"]) + 1j * np.asarray(data["imag"])
    return f, h, [i["node"] for i in data["inputs"]]


def _closed_form(f: np.ndarray) -> np.ndarray:
    return ImpulseSource(n_inputs=2, n_responses=3, response_gain=0.01).frf(f)


@pytest.mark.slow
def test_accept_reject_redo_each_hit_then_redo_and_append_inputs(review_api) -> None:
    c = review_api
    sid = c.post("/api/setups", json=dump_setup_dict(IMPULSE_SETUP)).json()["id"]
    bad = c.post("/api/acquisitions", json={**BODY, "setup_id": sid, "inputs": [0, 2]})
    assert bad.status_code == 422 and "inputs" in bad.json()["detail"]

    # --- the whole test, reviewed: input 10 accept, reject, redo; then accept ×2; input 11 ×2
    acq = c.post("/api/acquisitions", json={**BODY, "setup_id": sid, "review": True}).json()
    aid = acq["id"]
    hit = _decide(c, aid, "accept")
    # what the operator looks at: the force pulse and the response, their spectra
    fs = hit["sample_rate_hz"]
    assert len(hit["force_n"]) == BODY["record_samples"] and hit["peak_force_n"] > 20.0
    assert len(hit["frequencies_hz"]) == BODY["record_samples"] // 2 + 1
    assert hit["frequencies_hz"][1] == pytest.approx(fs / BODY["record_samples"])
    assert max(hit["force_db"]) == pytest.approx(0.0) and hit["reasons"] == []
    wrong = c.post(f"/api/acquisitions/{aid}/review", json={"number": 99, "decision": "accept"})
    _decide(c, aid, "reject")
    assert wrong.status_code == 409
    _decide(c, aid, "redo")
    a = _wait(c, aid, lambda a: len(a["averages"]) == 3)
    assert [(av["accepted"], av["reason"]) for av in a["averages"]] == [
        (False, OPERATOR_REDO),  # accepted first, dropped by the redo
        (False, OPERATOR_REJECT),
        (False, OPERATOR_REDO),
    ]
    for decision in ("accept", "accept", "accept", "accept"):
        _decide(c, aid, decision)
    a = _wait(c, aid, lambda a: a["state"] != "running")
    assert a["state"] == "succeeded", a
    assert a["accepted_per_input"] == [2, 2] and a["averages_rejected"] == 3
    assert all(v is not None and v > 0.99 for v in a["input_coherence"]), a["input_coherence"]
    f, h, nodes = _frf(c, a["frf_id"])
    assert nodes == [10, 11]
    np.testing.assert_allclose(h, _closed_form(f), atol=3e-3 * np.abs(h).max())
    assert c.get(f"/api/acquisitions/{aid}/hit").json()["pending"] is False

    # --- redo input 11 into that FRF set: a new set, input 11 replaced, input 10 kept as it was
    body = {**BODY, "setup_id": sid, "inputs": [1], "merge_frf_id": a["frf_id"]}
    redo = c.post("/api/acquisitions", json=body).json()
    assert redo["inputs"] == [1]
    b = _wait(c, redo["id"], lambda a: a["state"] != "running")
    assert b["state"] == "succeeded" and b["frf_id"] != a["frf_id"], b
    assert {av["input_index"] for av in b["averages"]} == {1}  # setup indices, not session ones
    f2, h2, nodes2 = _frf(c, b["frf_id"])
    assert nodes2 == [10, 11]
    np.testing.assert_array_equal(h2[:, :, 0], h[:, :, 0])
    np.testing.assert_allclose(h2, _closed_form(f2), atol=3e-3 * np.abs(h2).max())


@pytest.mark.slow
def test_finish_keeps_the_accepted_averages_and_append_completes_the_set(review_api) -> None:
    c = review_api
    sid = c.post("/api/setups", json=dump_setup_dict(IMPULSE_SETUP)).json()["id"]
    acq = c.post("/api/acquisitions", json={**BODY, "setup_id": sid, "review": True}).json()
    aid = acq["id"]
    _decide(c, aid, "accept")
    _decide(c, aid, "accept")
    _wait(c, aid, lambda a: a["pending_review"] is not None)  # input 11's first hit waits
    assert c.post(f"/api/acquisitions/{aid}/finish").status_code == 200
    a = _wait(c, aid, lambda a: a["state"] != "running")
    # FRFs for input 10 only: not a success, the input left is named by point and direction
    assert a["state"] == "incomplete" and a["incomplete_inputs"] == [1], a
    assert "11+X" in a["message"] and f"FRF set {a['frf_id']}" in a["message"], a["message"]
    assert [(s["name"], s["state"]) for s in a["input_states"]] == [
        ("10+X", "complete"),
        ("11+X", "incomplete"),
    ]
    assert _frf(c, a["frf_id"])[2] == [10]
    # a finished acquisition takes no more decisions
    late = c.post(f"/api/acquisitions/{aid}/review", json={"number": 3, "decision": "accept"})
    assert late.status_code == 409
    # append input 11 (no review: the checks decide)
    body = {**BODY, "setup_id": sid, "inputs": [1], "merge_frf_id": a["frf_id"]}
    b = c.post("/api/acquisitions", json=body).json()
    b = _wait(c, b["id"], lambda x: x["state"] != "running")
    f2, h2, nodes2 = _frf(c, b["frf_id"])
    assert b["state"] == "succeeded" and nodes2 == [10, 11], b
    np.testing.assert_allclose(h2, _closed_form(f2), atol=3e-3 * np.abs(h2).max())


@pytest.mark.slow
def test_inputs_are_named_by_their_line_of_action(review_api) -> None:
    # input 11 recorded with UFF direction 1 (+X in its node's system) but struck along −Z in
    # the GCS: every message names it by where the operator strikes, 11-Z
    c = review_api
    d = dump_setup_dict(IMPULSE_SETUP)
    d["inputs"][1]["direction_gcs"] = [0.0, 0.0, -1.0]
    assert d["inputs"][1]["direction"] == 1
    sid = c.post("/api/setups", json=d).json()["id"]
    aid = c.post("/api/acquisitions", json={**BODY, "setup_id": sid, "review": True}).json()["id"]
    _decide(c, aid, "accept")
    _decide(c, aid, "accept")
    p = _wait(c, aid, lambda a: a["pending_review"] is not None)["pending_review"]
    assert p["input_name"] == "11-Z", p
    assert c.post(f"/api/acquisitions/{aid}/finish").status_code == 200
    a = _wait(c, aid, lambda a: a["state"] != "running")
    assert [(s["name"], s["state"]) for s in a["input_states"]] == [
        ("10+X", "complete"),
        ("11-Z", "incomplete"),
    ]
    assert "11-Z" in a["message"] and "11+X" not in a["message"], a["message"]


# --- issue 24: reviewing a hit loses the test -------------------------------------------------


@contextmanager
def _review_lab(tmp_path: Path, database_url: str, **kw: Any) -> Iterator[tuple[httpx.Client, Any]]:
    """A served lab on the impulse rig (``kw`` to :func:`impulse_rig_factory`); yields the
    client and the rig factory (its simulated DAQs: ``.backends``)."""
    factory = struck_inputs_factory(**kw)
    with served_lab(tmp_path, database_url, factory) as (c, _lab):
        yield c, factory


def _states(a: dict) -> list[tuple[str, int, int, int, str]]:
    return [
        (s["name"], s["accepted"], s["rejected"], s["lost"], s["state"]) for s in a["input_states"]
    ]


@pytest.mark.slow
def test_a_review_longer_than_the_fifo_holds_loses_nothing(tmp_path: Path, database_url: str):
    """The DAQ free-runs at 2x real time (not adaptive: it never waits for the host) into a FIFO
    of 16 frames (4096 samples, 1 s of wall time); the operator looks at the first hit while the
    DAQ clocks 6 FIFOs' worth: the session drains it, no sample and no strike is lost, every hit
    is accepted. A session that drains slower than the DAQ clocks (the reading that waited half a
    block per block read drained at half the rate) overflows whatever the FIFO's size; the FIFO
    holds 1 s so that a host whose threads are preempted for a fraction of that (a loaded CI
    machine) loses nothing either."""
    fifo_frames, n_channels = 16, 5
    imp = dataclasses.replace(
        NONE,
        daq_free_running=True,
        daq_time_scale=2.0,
        daq_fifo_bytes=fifo_frames * frame_size(256, n_channels),
    )
    with _review_lab(tmp_path, database_url, imperfections=imp) as (c, factory):
        sid = c.post("/api/setups", json=dump_setup_dict(IMPULSE_SETUP)).json()["id"]
        acq = c.post("/api/acquisitions", json={**BODY, "setup_id": sid, "review": True}).json()
        aid = acq["id"]
        a = _wait(c, aid, lambda a: a["pending_review"] is not None)
        (daq,) = factory.backends
        assert daq.free_running and daq.fifo_bytes
        seen = daq.clock.count()
        fifo_samples = fifo_frames * 256
        # wait on the simulated DAQ's clock, not on time: six FIFOs clocked while the hit waits
        deadline = time.monotonic() + 60
        while daq.clock.count() < seen + 6 * fifo_samples:
            assert time.monotonic() < deadline, "the simulated DAQ does not clock"
            time.sleep(0.02)
        assert c.get(f"/api/acquisitions/{aid}").json()["pending_review"] == a["pending_review"]
        for _ in range(4):
            _decide(c, aid, "accept")
        a = _wait(c, aid, lambda a: a["state"] != "running")
        assert daq.injected.get("fifo_overflow", 0) == 0, daq.injected
    assert a["state"] == "succeeded", a
    assert _states(a) == [("10+X", 2, 0, 0, "complete"), ("11+X", 2, 0, 0, "complete")]
    assert "lost" not in a["message"], a["message"]


@pytest.mark.slow
def test_the_daq_lost_while_a_hit_waits_keeps_the_hit(tmp_path: Path, database_url: str) -> None:
    """The DAQ drops off the bus (USB re-enumeration) while the first hit waits for review: the
    session finds it again and starts the run anew, the hit waiting is kept for the operator, and
    the test goes on from the new run: every hit accepted, nothing lost."""
    faults = DaqFaults(reenumerate_rate=0.02, reenumerate_s=0.05)
    with _review_lab(tmp_path, database_url, faults=lambda: faults) as (c, factory):
        sid = c.post("/api/setups", json=dump_setup_dict(IMPULSE_SETUP)).json()["id"]
        acq = c.post("/api/acquisitions", json={**BODY, "setup_id": sid, "review": True}).json()
        aid = acq["id"]
        a = _wait(c, aid, lambda a: a["pending_review"] is not None)
        (daq,) = factory.backends
        # wait on the simulator's state: one re-enumeration while this hit waits, then no more
        seen = daq.injected.get("usb_reenumeration", 0)
        deadline = time.monotonic() + 60
        while daq.injected.get("usb_reenumeration", 0) == seen:
            assert time.monotonic() < deadline, "the simulated DAQ did not re-enumerate"
            time.sleep(0.01)
        faults.reenumerate_rate = 0.0
        first = a["pending_review"]["number"]
        assert c.get(f"/api/acquisitions/{aid}").json()["pending_review"]["number"] == first
        decided = []
        while True:
            a = _wait(c, aid, lambda a: a["pending_review"] is not None or a["state"] != "running")
            if a["state"] != "running":
                break
            decided.append(_decide(c, aid, "accept")["number"])
    assert a["state"] == "succeeded", a
    assert decided[0] == first and len(decided) == 4, decided
    assert all(av["accepted"] for av in a["averages"]), a["averages"]
    assert _states(a) == [("10+X", 2, 0, 0, "complete"), ("11+X", 2, 0, 0, "complete")]


@pytest.mark.slow
def test_lost_strikes_are_reported_and_not_counted(tmp_path: Path, database_url: str) -> None:
    """Five USB transfers are lost while the session waits for input 10's strikes (frames 0, 2,
    4, 6, 8: each holds the strike asked for): five strikes lost, each reported on the input
    with its reason and in the message, and struck again. They do not use the strike budget (3
    per average: 6): the input still gets its 2 averages and the test succeeds (counted, it was
    left with 1: incomplete)."""
    with _review_lab(
        tmp_path, database_url, faults=lambda: DaqFaults(lost_transfers={0, 2, 4, 6, 8})
    ) as (c, _factory):
        sid = c.post("/api/setups", json=dump_setup_dict(IMPULSE_SETUP)).json()["id"]
        acq = c.post("/api/acquisitions", json={**BODY, "setup_id": sid}).json()
        a = _wait(c, acq["id"], lambda a: a["state"] != "running")
    assert a["state"] == "succeeded", a
    assert _states(a) == [("10+X", 2, 0, 5, "complete"), ("11+X", 2, 0, 0, "complete")]
    assert a["input_states"][0]["lost_reasons"] == ["DAQ samples lost (transfer lost)"]
    assert "10+X 5 (DAQ samples lost (transfer lost))" in a["message"], a["message"]


@pytest.mark.slow
def test_an_input_that_loses_every_strike_is_incomplete_and_named(
    tmp_path: Path, database_url: str
) -> None:
    """Every strike asked of input 10 falls in a lost transfer: after 6 lost (3 per average, as
    the strike budget) it is asked no more; input 11 gets its averages. The acquisition ends
    "incomplete" (never "succeeded"), naming 10+X and why its strikes were lost."""
    lost = {0, 2, 4, 6, 8, 10}
    with _review_lab(tmp_path, database_url, faults=lambda: DaqFaults(lost_transfers=lost)) as (
        c,
        _factory,
    ):
        sid = c.post("/api/setups", json=dump_setup_dict(IMPULSE_SETUP)).json()["id"]
        acq = c.post("/api/acquisitions", json={**BODY, "setup_id": sid}).json()
        a = _wait(c, acq["id"], lambda a: a["state"] != "running")
    assert a["state"] == "incomplete" and a["incomplete_inputs"] == [0], a
    assert _states(a) == [("10+X", 0, 0, 6, "incomplete"), ("11+X", 2, 0, 0, "complete")]
    assert "inputs 10+X incomplete" in a["message"], a["message"]
    assert "10+X 6 (DAQ samples lost (transfer lost))" in a["message"], a["message"]


@pytest.mark.slow
def test_a_hit_the_checks_rejected_needs_an_override(tmp_path: Path, database_url: str) -> None:
    """Input 10's first record lost a USB transfer (frame 1): it cannot be accepted, not even
    with override (409 naming the samples lost). Input 11's second strike is a double hit:
    accept is refused (409 naming the check) until override: true, which keeps it with the
    check's reason and the operator's."""
    with _review_lab(
        tmp_path,
        database_url,
        double_hit_input=1,
        faults=lambda: DaqFaults(lost_transfers={1}),
    ) as (c, _factory):
        sid = c.post("/api/setups", json=dump_setup_dict(IMPULSE_SETUP)).json()["id"]
        acq = c.post("/api/acquisitions", json={**BODY, "setup_id": sid, "review": True}).json()
        aid = acq["id"]
        url = f"/api/acquisitions/{aid}/review"
        p = _wait(c, aid, lambda a: a["pending_review"] is not None)["pending_review"]
        assert p["number"] == 1 and p["accept"] == "no" and p["input_name"] == "10+X", p
        lost = p["reasons"]
        assert lost == ["DAQ samples lost (256: transfer lost)"], p
        for override in (False, True):
            r = c.post(url, json={"number": 1, "decision": "accept", "override": override})
            assert r.status_code == 409 and "samples lost" in r.json()["detail"], r.text
        _decide(c, aid, "reject")
        for _ in range(3):
            _decide(c, aid, "accept")
        a = _wait(c, aid, lambda a: (a["pending_review"] or {}).get("number") == 5)
        p = a["pending_review"]
        assert p["reasons"] == ["double hit"] and p["accept"] == "override", p
        assert p["input_name"] == "11+X"
        r = c.post(url, json={"number": 5, "decision": "accept"})
        assert r.status_code == 409 and "double hit" in r.json()["detail"], r.text
        assert "override: true" in r.json()["detail"]
        r = c.post(url, json={"number": 5, "decision": "reject", "override": True})
        assert r.status_code == 422 and "override" in r.json()["detail"], r.text
        r = c.post(url, json={"number": 5, "decision": "accept", "override": True})
        assert r.status_code == 200, r.text
        a = _wait(c, aid, lambda a: a["state"] != "running")
    assert a["state"] == "succeeded", a
    assert [(av["accepted"], av["reason"]) for av in a["averages"]] == [
        (False, lost[0]),
        (True, ""),
        (True, ""),
        (True, ""),
        (True, f"double hit; {OPERATOR_OVERRIDE}"),
    ]
    assert _states(a) == [("10+X", 2, 1, 0, "complete"), ("11+X", 2, 0, 0, "complete")]


@pytest.mark.slow
def test_review_switched_off_mid_run_takes_effect(tmp_path: Path, database_url: str) -> None:
    """Unticking "review every hit": the hit waiting is decided by the checks and the rest run
    on without the operator; the acquisition says review is off. A finished acquisition is not
    switched (409); a stop before any accepted average fails, naming the inputs."""
    with _review_lab(tmp_path, database_url) as (c, _factory):
        sid = c.post("/api/setups", json=dump_setup_dict(IMPULSE_SETUP)).json()["id"]
        acq = c.post("/api/acquisitions", json={**BODY, "setup_id": sid, "review": True}).json()
        aid = acq["id"]
        assert acq["review"] is True
        _wait(c, aid, lambda a: a["pending_review"] is not None)
        r = c.patch(f"/api/acquisitions/{aid}", json={"review": False})
        assert r.status_code == 200 and r.json()["review"] is False, r.text
        a = _wait(c, aid, lambda a: a["state"] != "running")
        assert a["state"] == "succeeded" and a["review"] is False, a
        assert _states(a) == [("10+X", 2, 0, 0, "complete"), ("11+X", 2, 0, 0, "complete")]
        late = c.patch(f"/api/acquisitions/{aid}", json={"review": True})
        assert late.status_code == 409, late.text
        assert c.patch(f"/api/acquisitions/{aid}", json={"reveiw": True}).status_code == 422
        # switched on mid-run: the next hit waits
        acq = c.post("/api/acquisitions", json={**BODY, "setup_id": sid, "review": False}).json()
        r = c.patch(f"/api/acquisitions/{acq['id']}", json={"review": True})
        if r.status_code == 200:  # it may have ended already (4 hits on a kind DAQ)
            a = _wait(c, acq["id"], lambda a: a["pending_review"] or a["state"] != "running")
            assert c.post(f"/api/acquisitions/{acq['id']}/stop").status_code == 200
        _wait(c, acq["id"], lambda a: a["state"] != "running")
        # stopped before any accepted average: failed, the inputs named by point and direction
        acq = c.post("/api/acquisitions", json={**BODY, "setup_id": sid, "review": True}).json()
        _wait(c, acq["id"], lambda a: a["pending_review"] is not None)
        assert c.post(f"/api/acquisitions/{acq['id']}/finish").status_code == 200
        a = _wait(c, acq["id"], lambda a: a["state"] != "running")
    assert a["state"] == "failed" and "10+X" in a["message"] and "11+X" in a["message"], a
    assert a["incomplete_inputs"] == [0, 1] and a["frf_id"] is None
    assert [s["state"] for s in a["input_states"]] == ["incomplete", "incomplete"]
