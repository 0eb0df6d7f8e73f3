"""Kill ``dimacq serve`` with SIGKILL mid-acquisition (the simulated lab's impact test of the
calibration mass), restart it: no completed average and no digitized point is lost; the
interrupted acquisition and job say so; it can be finished (FRFs of its complete inputs) and
resumed (only the missing averages struck) to the FRFs of a run without the kill. On SQLite and
on PostgreSQL."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import httpx
import numpy as np
import pytest

from dimacq.api.server import free_port
from dimacq.io.setup_file import dump_setup_dict
from dimacq.model.channels import input_name
from dimacq.persistence import ArrayStore
from dimacq.simulators.lab.scenarios import build_scenario

TOKEN = "crash-token"


def _start(
    data_dir: Path, port: int, database_url: str, env_extra: dict[str, str] | None = None
) -> subprocess.Popen[bytes]:
    env = {
        **os.environ,
        "DIMACQ_DATABASE_URL": database_url,
        "DIMACQ_TOKEN": TOKEN,
        "DIMACQ_DIGITIZER_URL": f"simdigitizer://crash{port}?seed=5",
        "DIMACQ_SCENARIO": "calibration-mass-bungee",
        **(env_extra or {}),
    }
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "dimacq.cli.main",
            "serve",
            "--port",
            str(port),
            "--data-dir",
            str(data_dir),
            "--log-level",
            "warning",
        ],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        env=env,
    )
    deadline = time.monotonic() + 120  # a guard only: it returns as soon as the server answers
    while time.monotonic() < deadline:
        try:
            if httpx.get(f"http://127.0.0.1:{port}/api/status", timeout=1).status_code == 200:
                return proc
        except httpx.TransportError:
            pass
        if proc.poll() is not None:
            raise AssertionError(
                f"server died: {proc.stderr.read().decode() if proc.stderr else ''}"
            )
        time.sleep(0.1)
    proc.kill()
    _, err = proc.communicate(timeout=10)  # reaped and its pipe closed: nothing left to GC
    raise AssertionError(f"server did not start: {err.decode(errors='replace')[-2000:]}")


ROOT = Path(__file__).resolve().parents[2]
#: 3 of the calibration mass's 24 inputs, 4 averages each of 1 s (2048 samples at 2048 Hz)
RESUME_BODY = {
    "inputs": [0, 1, 2],
    "averages_per_input": 4,
    "min_averages": 2,
    "record_samples": 2048,
    "seed": 7,
}


def _quiet_lab(tmp: Path) -> dict[str, str]:
    """A world that gives the same averages whenever it is struck: the calibration mass bolted
    to the floor (support modes 137–1070 Hz, long decayed when the next strike comes) without
    transducer noise, on a DAQ clocked by the host's reads (not wall time) that neither stalls
    nor loses CAN frames. Two runs of it with one seed give identical FRFs."""
    text = (ROOT / "config/scenarios/calibration-mass-ground.toml").read_text(encoding="utf-8")
    for name in ("accel_noise_ms2", "force_noise_n", "gauge_noise_v"):
        text = "\n".join(
            f"{name} = 0.0" if line.startswith(f"{name} =") else line for line in text.splitlines()
        )
    scenario = tmp / "quiet-ground.toml"
    scenario.write_text(text, encoding="utf-8")
    return {
        "DIMACQ_SCENARIO": str(scenario),
        "DIMACQ_RIG_FILE": str(ROOT / "config/rig.toml"),
        "DIMACQ_SIMULATION_IMPERFECTIONS": json.dumps(
            {
                "daq_free_running": False,
                "daq_stale_frames": False,
                "daq_stall_rate": 0.0,
                "can_frame_loss_rate": 0.0,
                "loadcell_oscillator_ppm": 0.0,
            }
        ),
    }


def _client(port: int) -> httpx.Client:
    return httpx.Client(
        base_url=f"http://127.0.0.1:{port}",
        headers={"Authorization": f"Bearer {TOKEN}"},
        timeout=30,
    )


def _until(c: httpx.Client, acq_id: int, cond: object, timeout_s: float = 60) -> dict:
    deadline = time.monotonic() + timeout_s
    while True:
        a = c.get(f"/api/acquisitions/{acq_id}").json()
        if cond(a) or time.monotonic() > deadline:  # type: ignore[operator]
            return a
        time.sleep(0.02)


def _frf(c: httpx.Client, frf_id: int) -> tuple[np.ndarray, np.ndarray, list[str]]:
    data = c.get(f"/api/frfs/{frf_id}/data").json()
    h = np.asarray(data["real"]) + 1j * np.asarray(data["imag"])
    names = [f"{i['node']}{i['direction']}" for i in data["inputs"]]
    return np.asarray(data["frequencies_hz"]), h, names


def _stop(proc: subprocess.Popen[bytes], kill: bool = False) -> None:
    if proc.poll() is None:
        if kill:
            os.kill(proc.pid, signal.SIGKILL)
        else:
            proc.send_signal(signal.SIGTERM)
        proc.wait(20)
    if proc.stderr:
        proc.stderr.close()


@pytest.mark.slow
def test_sigkill_loses_nothing_and_finish_then_resume_give_the_frfs_of_a_run_without_it(
    tmp_path: Path, database_url: str
) -> None:
    """SIGKILL mid-acquisition, restart: the digitized points and every average completed
    before the kill are still there (readable arrays of every channel), the acquisition and
    its job say ``interrupted``, and the restarted service still refuses anonymous state changes.

    Issue 24: after a kill the kept averages were useless (finish 409, no FRFs, strike all
    again). Now: finish stores the complete inputs' FRFs and names the missing ones; resume
    strikes only the missing averages and ends with the FRFs of a run without the kill: the
    inputs struck before the kill bit for bit, the others to 1e-3 of each response's largest
    value over the scenario's lines (≤ 400 Hz; the strikes after the restart hit an article at
    rest, not one ringing 1e-4 from the previous strike).

    (One test: the loss check was a test of its own that paid for two more service starts and a
    second acquisition on each backend to look at the same kill.)"""
    env = _quiet_lab(tmp_path)
    setup = build_scenario(env["DIMACQ_SCENARIO"]).model.setup
    names = [input_name(e) for e in setup.excitations]  # by line of action: 102-X
    port = free_port()
    proc = _start(tmp_path, port, database_url, env)
    try:
        with _client(port) as c:
            for i in range(6):
                r = c.post(
                    "/api/digitizer/points",
                    json={"label": f"P{i}", "sim_probe": {"tip_m": [0.1 * i - 0.3, 0.05, 1.0]}},
                )
                assert r.status_code == 201, r.text
            sid = c.post("/api/setups", json=dump_setup_dict(setup)).json()["id"]
            # the reference: the same acquisition, not killed (each one its own world, seeded)
            ref = c.post("/api/acquisitions", json={"setup_id": sid, **RESUME_BODY}).json()
            ref = _until(c, ref["id"], lambda a: a["state"] != "running")
            assert ref["state"] == "succeeded", ref
            f_ref, h_ref, in_ref = _frf(c, ref["frf_id"])
            acq = c.post("/api/acquisitions", json={"setup_id": sid, **RESUME_BODY}).json()
            a = _until(c, acq["id"], lambda a: a["averages_accepted"] >= 3)
            assert a["state"] == "running", a  # killed mid-run, not after it
            seen = {av["path"] for av in a["averages"]}
        _stop(proc, kill=True)  # mid-acquisition, no shutdown of any kind
    finally:
        _stop(proc)

    proc = _start(tmp_path, port, database_url, env)
    try:
        with _client(port) as c:
            points = c.get("/api/digitizer/points").json()
            assert [p["label"] for p in points] == [f"P{i}" for i in range(6)]
            a = c.get(f"/api/acquisitions/{acq['id']}").json()
            assert a["state"] == "interrupted", a
            after = {av["path"] for av in a["averages"]}
            assert len(seen) >= 3 and seen <= after  # every average completed before the kill
            store = ArrayStore(tmp_path / "arrays")
            n_out = len(setup.responses) + 6 * len(setup.load_cells)
            for rel in after:
                arrays, attrs = store.read(rel)
                assert arrays["outputs"].shape[0] == n_out and attrs["acquisition_id"] == acq["id"]
            assert c.get(f"/api/jobs/{acq['job_id']}").json()["state"] == "interrupted"
            # the service still refuses anonymous state changes after the restart
            anon = httpx.post(f"http://127.0.0.1:{port}/api/acquisitions/{acq['id']}/stop")
            assert anon.status_code == 401
            kept = a["accepted_per_input"] + [0] * (3 - len(a["accepted_per_input"]))
            # killed at 3 or a little later: the third input not struck yet (0.9 s of slack)
            assert 3 <= sum(kept) <= 8, kept
            # finish: the complete inputs' FRFs, the missing ones named; never "succeeded"
            r = c.post(f"/api/acquisitions/{acq['id']}/finish")
            assert r.status_code == 200, r.text
            done = r.json()
            complete = [j for j in range(3) if kept[j] >= 2]
            assert done["state"] == "incomplete", done
            for j in range(3):
                assert (names[j] in done["message"]) == (j not in complete), done["message"]
            _, h_fin, in_fin = _frf(c, done["frf_id"])
            assert in_fin == [in_ref[j] for j in complete]
            for k, j in enumerate(complete):
                if kept[j] == 4:  # all its averages kept: the reference's numbers exactly
                    np.testing.assert_array_equal(h_fin[:, :, k], h_ref[:, :, j])
            # resume: only the missing averages are struck
            r = c.post(f"/api/acquisitions/{acq['id']}/resume")
            assert r.status_code == 202, r.text
            b = _until(c, r.json()["id"], lambda a: a["state"] != "running")
            assert b["state"] == "succeeded" and b["incomplete_inputs"] == [], b
            assert b["accepted_per_input"] == [4, 4, 4]
            assert len([x for x in b["averages"] if x["accepted"]]) == 12 - sum(kept)
            assert c.get(f"/api/acquisitions/{acq['id']}").json()["state"] == "resumed"
            f, h, inputs = _frf(c, b["frf_id"])
            assert inputs == in_ref
            np.testing.assert_array_equal(f, f_ref)
            for j in range(3):
                if kept[j] == 4:
                    np.testing.assert_array_equal(h[:, :, j], h_ref[:, :, j])
            lines = f <= 400.0
            scale = np.abs(h_ref[lines]).max(axis=0)
            err = np.abs(h[lines] - h_ref[lines]).max(axis=0) / scale
            assert err.max() < 1e-3, err.max()
    finally:
        _stop(proc)
