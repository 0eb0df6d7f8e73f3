"""One solution per solve request: an identical solve while one runs answers 409 naming it (a
double-click that reaches the service twice), and a request sent again with its Idempotency-Key
gets the solution it stored."""

from __future__ import annotations

import threading
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from _api_support import Api

from dimacq.io.setup_file import dump_setup_dict
from dimacq.io.uff import write_frf_uff
from dimacq.simulators.lab.forward import calibration_mass

BODY = {"band_hz": [20, 100], "unbiased": False, "refine_geometry": False}


@pytest.fixture(scope="module")
def frf_id(api: Api) -> int:
    model = calibration_mass(0, support="bungee")
    frf = model.frf(np.linspace(10.0, 120.0, 56))
    sid = api.client.post("/api/setups", json=dump_setup_dict(model.setup)).json()["id"]
    buf = Path(api.settings.data_dir) / "once.uff"
    write_frf_uff(buf, frf)
    r = api.client.post("/api/frfs/import", params={"setup_id": sid}, content=buf.read_bytes())
    assert r.status_code == 201, r.text
    return int(r.json()["id"])


def _count(api: Api, fid: int) -> int:
    return len(api.client.get("/api/solutions", params={"frf_id": fid}).json())


@pytest.mark.slow
def test_a_second_identical_solve_while_the_first_runs_is_refused(
    api: Api, frf_id: int, monkeypatch: pytest.MonkeyPatch
) -> None:
    analysis = api.lab.analysis
    inside, release = threading.Event(), threading.Event()
    real = analysis._analyse

    def held(*a: Any, **kw: Any) -> Any:
        inside.set()
        assert release.wait(60), "the test never released the first solve"
        return real(*a, **kw)

    monkeypatch.setattr(analysis, "_analyse", held)
    before = _count(api, frf_id)
    first: dict[str, Any] = {}
    body = {"frf_id": frf_id, **BODY}
    t = threading.Thread(
        target=lambda: first.update(r=api.client.post("/api/solutions", json=body))
    )
    t.start()
    try:
        assert inside.wait(60)
        second = api.client.post("/api/solutions", json=body)
        assert second.status_code == 409, second.text
        detail = second.json()["detail"]
        assert f"solve of FRF set {frf_id}" in detail and "running already" in detail, detail
        assert "solve " in detail and "started" in detail  # names the running one
        # another solve of the same set (other options) is no duplicate: it may run
        monkeypatch.setattr(analysis, "_analyse", real)
        other = api.client.post("/api/solutions", json={**body, "band_hz": [20, 90]})
        assert other.status_code == 201, other.text
    finally:
        release.set()
        t.join(60)
    assert first["r"].status_code == 201, first["r"].text
    assert _count(api, frf_id) == before + 2  # the first and the other, not the refused one
    # once the first has ended, the same request solves again (a new solution, asked for)
    again = api.client.post("/api/solutions", json=body)
    assert again.status_code == 201 and again.json()["id"] != first["r"].json()["id"]


@pytest.mark.slow
def test_the_same_idempotency_key_returns_the_stored_solution(api: Api, frf_id: int) -> None:
    body = {"frf_id": frf_id, **BODY}
    before = _count(api, frf_id)
    key = {"Idempotency-Key": "solve-click-7f3a"}
    a = api.client.post("/api/solutions", json=body, headers=key)
    assert a.status_code == 201, a.text
    b = api.client.post("/api/solutions", json=body, headers=key)
    assert b.status_code == 201 and b.json() == a.json()
    assert _count(api, frf_id) == before + 1
    # the key with another request is a client error, named
    c = api.client.post("/api/solutions", json={**body, "band_hz": [20, 80]}, headers=key)
    assert c.status_code == 422 and "Idempotency-Key" in c.json()["detail"], c.text
    # a deleted solution is solved again on a retry (nothing to return)
    assert api.client.delete(f"/api/solutions/{a.json()['id']}").status_code == 204
    d = api.client.post("/api/solutions", json=body, headers=key)
    assert d.status_code == 201 and d.json()["id"] != a.json()["id"]
    bad = api.client.post("/api/solutions", json=body, headers={"Idempotency-Key": "a b"})
    assert bad.status_code == 422
