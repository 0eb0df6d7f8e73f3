"""Adding a DAQ kind is one backend entry and one driver module.

The driver module is ``tests/_second_daq.py`` (a fixed-range panel DAQ that nothing in
``dimacq`` knows); the entry is the setting ``daq = "_second_daq:open_daq"``. A real ``dimacq
serve`` process configured only through ``DIMACQ_*`` variables opens it through the backend
table, builds the rig from the rig file with the one rig builder, and acquires an impact test
through the HTTP API; the FRFs it stores are the closed-form FRFs of the device's source.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest
from _acq_support import ImpulseSource
from _lab_rig_support import IMPULSE_SETUP

from dimacq.api.server import free_port
from dimacq.backends import lookup

TESTS = Path(__file__).resolve().parents[1]

RIG = """schema_version = 1
[daq]
sample_rate_hz = 2048.0
[[hammers]]
physical_channel = 0
sensitivity_mv_per_n = 2.25
range_v = 5.0
inputs = ["10+X"]
[[hammers]]
physical_channel = 1
sensitivity_mv_per_n = 2.25
range_v = 5.0
inputs = ["11+X"]
[acquisition]
record_samples = 2048
pretrigger_samples = 32
averages_per_input = 2
"""


def test_factory_path_is_looked_up_like_a_table_entry() -> None:
    import _second_daq

    assert lookup("daq", "_second_daq:open_daq") is _second_daq.open_daq


@pytest.mark.slow
def test_second_daq_kind_through_dimacq_serve(tmp_path: Path) -> None:
    rig = tmp_path / "rig.toml"
    text = RIG
    for k, c in enumerate(IMPULSE_SETUP.responses):
        text += (
            f"[[responses]]\nnode = {c.node}\ndirection = {c.direction}\n"
            f"physical_channel = {2 + k}\nsensitivity_mv_per_g = 100.0\nrange_v = 5.0\n"
        )
    rig.write_text(text, encoding="utf-8")
    port = free_port()
    env = {
        **os.environ,
        "PYTHONPATH": os.pathsep.join([str(TESTS), os.environ.get("PYTHONPATH", "")]),
        "DIMACQ_TOKEN": "tok",
        "DIMACQ_DAQ": "_second_daq:open_daq",
        "DIMACQ_RIG_FILE": str(rig),
        "DIMACQ_DIGITIZER_URL": f"simdigitizer://second{port}",
    }
    proc = subprocess.Popen(
        [sys.executable, "-m", "dimacq.cli.main", "serve", "--port", str(port)]
        + ["--data-dir", str(tmp_path / "data")],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        env=env,
        text=True,
    )
    url = f"http://127.0.0.1:{port}"
    try:
        deadline = time.monotonic() + 120  # a guard: returns as soon as it answers
        while True:
            try:
                st = httpx.get(f"{url}/api/status", timeout=1).json()
                break
            except httpx.TransportError:
                assert proc.poll() is None, proc.stderr.read() if proc.stderr else ""
                assert time.monotonic() < deadline, "dimacq serve did not start"
                time.sleep(0.1)
        assert st["devices"]["daq"]["connected"], st
        c = httpx.Client(base_url=url, headers={"Authorization": "Bearer tok"}, timeout=30)
        try:
            data = _acquire(c, deadline)
        finally:
            c.close()
    finally:
        proc.send_signal(signal.SIGINT)
        proc.communicate(timeout=20)
    f = np.asarray(data["frequencies_hz"])
    H = np.asarray(data["real"]) + 1j * np.asarray(data["imag"])
    assert H.shape == (f.size, 3, 2)
    H_true = ImpulseSource(n_inputs=2, n_responses=3, response_gain=0.01).frf(f)
    band = (f > 20) & (f < 400)
    rel = np.abs(H[band] - H_true[band]) / np.abs(H_true[band])
    assert np.median(rel) < 1e-3 and rel.max() < 0.02, (np.median(rel), rel.max())


def _acquire(c: httpx.Client, deadline: float) -> dict[str, Any]:
    daq = c.get("/api/devices/daq").json()
    assert daq["identity"]["model"] == "panel DAQ" and not daq["simulated"], daq
    sid = c.post("/api/setups", json=IMPULSE_SETUP.model_dump(mode="json")).json()["id"]
    acq = c.post("/api/acquisitions", json={"setup_id": sid})
    assert acq.status_code == 202, acq.text
    aid = acq.json()["id"]
    while True:
        a = c.get(f"/api/acquisitions/{aid}").json()
        if a["state"] != "running":
            break
        assert time.monotonic() < deadline + 60, a
        time.sleep(0.1)
    assert a["state"] == "succeeded", a
    assert a["averages_accepted"] == 4  # the rig file's 2 averages × 2 inputs
    return c.get(f"/api/frfs/{a['frf_id']}/data").json()
