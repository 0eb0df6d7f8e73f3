"""A load cell calibration run through the API on the real-rig path, over HTTP: the job asks for
every load case, the test operator sets it up on the simulated dead-weight bench (behind the
amplifier simulator on the configured CAN channel) and confirms; the result is installed,
downloaded, read back and recorded."""

from __future__ import annotations

import os
import time
import uuid
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest
from _api_support import TOKEN, make_settings
from _bench_rig_support import write_bench_rig

from dimacq.api import create_app
from dimacq.api.server import BackgroundServer
from dimacq.io.loadcell_calibration import read_calibration
from dimacq.simulators.lab.bridge import strain_gauge_cell
from dimacq.simulators.loadcell.amplifier import LoadCellAmplifierSim
from dimacq.simulators.loadcell.bench import DeadWeightBench


@pytest.mark.slow
def test_static_run_with_prompts_over_http(tmp_path: Path) -> None:
    rig_dir = write_bench_rig(tmp_path, node_id=2)
    cell = strain_gauge_cell(501, creep_tau_s=1.5, swing_tau_s=0.8)
    bench = DeadWeightBench(cell, sample_rate_hz=10, seed=9)
    channel = f"dimacq-apical-{os.getpid()}-{uuid.uuid4().hex[:8]}"
    settings = make_settings(
        tmp_path / "data",
        daq_backend="libusb",
        daq_vendor_id=0xFFFE,
        daq_product_id=0xFFFE,
        loadcell_interface="virtual",
        loadcell_virtual_ok=True,  # a simulator on python-can's in-process bus
        loadcell_channel=channel,
        rig_file=str(rig_dir / "rig.toml"),
    )
    plan_cases = None
    with (
        LoadCellAmplifierSim(
            channel, bench, list(range(12)), node_id=2, serial_number=501, time_scale=200.0
        ) as sim,
        BackgroundServer(create_app(settings)) as srv,
        httpx.Client(
            base_url=srv.url, headers={"Authorization": f"Bearer {TOKEN}"}, timeout=30
        ) as c,
    ):
        r = c.post("/api/calibrations/runs", json={"method": "static", "download": True})
        assert r.status_code == 202, r.text
        job = r.json()["job_id"]
        assert r.json()["simulated"] is False
        from dimacq.pipeline.loadcell_calibration import standard_load_plan

        plan_cases = standard_load_plan(cell.rated_load, minimal=True).cases
        confirmed = 0
        deadline = time.monotonic() + 240
        while time.monotonic() < deadline:
            st = c.get(f"/api/jobs/{job}").json()
            if st["state"] in ("succeeded", "failed", "cancelled"):
                break
            p = c.get(f"/api/calibrations/runs/{job}/prompt").json()
            if not p["waiting"]:
                time.sleep(0.02)
                continue
            case = plan_cases[p["case"]]
            assert p["message"] == case.prompt() and p["of"] == len(plan_cases)
            bench.place(case.mass_kg, np.array(case.position_m), np.array(case.gravity))
            wrong = c.post(f"/api/calibrations/runs/{job}/confirm", json={"case": p["case"] + 1})
            assert wrong.status_code == 422 and "waits for load case" in wrong.text
            ok = c.post(f"/api/calibrations/runs/{job}/confirm", json={"case": p["case"]})
            assert ok.status_code == 200, ok.text
            confirmed += 1
        assert st["state"] == "succeeded", st
        res = st["result"]
        assert confirmed == len(plan_cases)
        C = np.array(res["matrix"])
        C_true = np.linalg.pinv(cell.sensitivity_mvv)
        assert np.linalg.norm(C - C_true) / np.linalg.norm(C_true) < 1e-3
        assert res["download_verified"] == 72 and res["version"] == 1
        np.testing.assert_array_equal(sim.matrix, C.astype("<f4").astype(float))
        cals = c.get("/api/calibrations").json()
        assert cals[-1]["id"] == res["record_id"]
        assert cals[-1]["calibration"]["method"] == "static"
        assert cals[-1]["calibration"]["version"] == 1
        assert read_calibration(rig_dir / "calibrations" / "lc-501.json").version == 1
        # a second run while none waits: confirm is refused, naming why
        assert c.post(f"/api/calibrations/runs/{job}/confirm", json={"case": 0}).status_code == 409


@pytest.mark.slow
def test_inertial_run_on_the_simulated_lab_over_http(tmp_path: Path) -> None:
    """Method inertial through the API on the simulated lab (the rig builder and the simulated
    backends: the calibration mass on the support-side bench), with the job's progress;
    installed in a scratch copy of the rig, recorded; the shipped calibration file is left as it
    is. The circular check is asked off here (the lab page's test runs it through the API)."""
    from dimacq.config import Settings

    shipped = Settings(rig_file="").rig_path.parent / "calibrations" / "lc-501.json"
    before = shipped.read_bytes()
    settings = make_settings(tmp_path / "data")
    assert settings.loadcell == "simulated"
    with (
        BackgroundServer(create_app(settings)) as srv,
        httpx.Client(
            base_url=srv.url, headers={"Authorization": f"Bearer {TOKEN}"}, timeout=30
        ) as c,
    ):
        bad = c.post("/api/calibrations/runs", json={"method": "inertial", "averages_per_input": 0})
        assert bad.status_code == 422 and "averages_per_input" in bad.text
        r = c.post(
            "/api/calibrations/runs",
            json={
                "method": "inertial",
                "averages_per_input": 1,
                "circular_check": False,
                "download": True,
            },
        )
        assert r.status_code == 202, r.text
        assert r.json()["simulated"] is True
        job = r.json()["job_id"]
        stages: set[str] = set()
        deadline = time.monotonic() + 240
        while time.monotonic() < deadline:
            st = c.get(f"/api/jobs/{job}").json()
            if st.get("message"):
                stages.add(str(st["message"]).split(":")[0])
            if st["state"] in ("succeeded", "failed", "cancelled"):
                break
            time.sleep(0.05)
        assert st["state"] == "succeeded", st
        assert "inertial bench" in stages and "circular check" not in stages, stages
        res = st["result"]
        # the next version of the shipped file (whatever it is now)
        assert (
            res["method"] == "inertial" and res["version"] == read_calibration(shipped).version + 1
        )
        assert res["nonlinearity_pct_fs"] is None and len(res["uncertainty_pct_fs"]) == 6
        assert np.array(res["matrix"]).shape == (6, 12)
        assert "circular_mass_error_pct" not in res
        assert res["downloaded"] and res["download_verified"] == 72  # read back from the amplifier
        assert 0.9 < res["fit"]["hammer_sensitivity_ratio"] < 1.1
        cals = c.get("/api/calibrations").json()
        assert cals[-1]["id"] == res["record_id"]
        assert cals[-1]["calibration"]["method"] == "inertial"
    assert shipped.read_bytes() == before


@pytest.mark.slow
def test_inertial_strike_requests_are_the_runs_prompt(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A person strikes the inertial bench where the run asks: the run's prompt route gives
    each request as the acquisition's page says it ("strike point 101 along +X": the input's
    node, direction and line of action, the average) while the job waits for the hit; a
    confirm is refused naming why (the trigger sees the hit, there is no load to confirm).
    The bench is a stand-in that asks twice: the wiring of the requests from the impact
    session is tested on the real path (tests/services/test_inertial_calibration_real.py)."""
    import threading

    import dimacq.services.calibration.inertial_calibration as ic
    from dimacq.errors import DataError
    from dimacq.services.acquisition.rig import StrikeRequest

    seen = [threading.Event(), threading.Event()]

    def bench(settings: Any, *, on_strike: Any, on_progress: Any, **_: Any) -> Any:
        for k, (node, d) in enumerate(((101, 1), (117, -3))):
            g = (float(np.sign(d)), 0.0, 0.0) if abs(d) == 1 else (0.0, 0.0, float(np.sign(d)))
            req = StrikeRequest(k, 24, node, d, g, 1, 2, k + 1, f"strike input {k + 1}: ...")
            on_strike(req)
            on_progress(k / 2, req.message)
            assert seen[k].wait(20)
        raise DataError("stand-in bench: no data")

    monkeypatch.setattr(ic, "run_inertial_calibration", bench)
    settings = make_settings(tmp_path / "data")
    with (
        BackgroundServer(create_app(settings)) as srv,
        httpx.Client(
            base_url=srv.url, headers={"Authorization": f"Bearer {TOKEN}"}, timeout=30
        ) as c,
    ):
        r = c.post("/api/calibrations/runs", json={"method": "inertial", "circular_check": False})
        assert r.status_code == 202, r.text
        job = r.json()["job_id"]
        want = [("+X", 101, [1.0, 0.0, 0.0]), ("-Z", 117, [0.0, 0.0, -1.0])]
        for k, (label, node, gcs) in enumerate(want):
            deadline = time.monotonic() + 20
            while time.monotonic() < deadline:
                p = c.get(f"/api/calibrations/runs/{job}/prompt").json()
                if p["waiting"] and p["input_index"] == k:
                    break
                time.sleep(0.02)
            assert p["kind"] == "strike" and p["stage"] == "inertial bench", p
            assert (p["node"], p["direction"], p["direction_gcs"]) == (node, label, gcs)
            assert (p["average"], p["averages"], p["n_inputs"]) == (1, 2, 24)
            no = c.post(f"/api/calibrations/runs/{job}/confirm", json={"case": 0})
            assert no.status_code == 409 and "waits for a strike" in no.text
            seen[k].set()
        deadline = time.monotonic() + 20
        while c.get(f"/api/jobs/{job}").json()["state"] not in ("failed", "succeeded"):
            assert time.monotonic() < deadline
            time.sleep(0.02)
        assert c.get(f"/api/calibrations/runs/{job}/prompt").json() == {
            "job_id": job,
            "waiting": False,
        }
