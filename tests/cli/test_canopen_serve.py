"""``dimacq serve`` with the load cell on the CANopen backend, configured only through
``DIMACQ_LOADCELL = "canopen-simulated"``: the devices check names the node, a bench calibration
through the API (the virtual dead-weight bench behind the CANopen simulator) meets the native
backend's limits. (The impact test on this backend: tests/backends/test_canopen_backend.py in
process, and the whole demo through the service: tests/scripts/canopen_must_show.py.)"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest
from _serve_support import Service

from dimacq.api.server import free_port


@pytest.mark.slow
def test_canopen_load_cell_through_dimacq_serve(tmp_path: Path) -> None:
    port = free_port()
    env = {
        "DIMACQ_LOADCELL": "canopen-simulated",
        "DIMACQ_DIGITIZER_URL": f"simdigitizer://co{port}",
    }
    svc = Service(tmp_path / "data", port, "tok", env=env)
    c = svc.client
    try:
        lc = c.get("/api/devices/loadcell").json()
        assert lc["connected"], lc
        assert "canopen-simulated" in str(lc)
        # the CANopen simulator is the virtual lab: simulated, in the status too (issue 17)
        assert lc["simulated"] is True, lc
        st = c.get("/api/status").json()["devices"]["loadcell"]
        assert st["simulated"] is True and st["connected"] is True, st
        assert c.get("/api/simulation/article").status_code == 200
        # bench calibration: the native backend's limits (tests/cli/test_acquire_cli.py)
        r = c.post(
            "/api/calibrations/runs",
            json={"method": "static", "plan": "minimal", "circular_check": False},
        )
        assert r.status_code == 202, r.text
        assert r.json()["simulated"] is True
        job = r.json()["job_id"]
        deadline = time.monotonic() + 240
        while (st := c.get(f"/api/jobs/{job}").json())["state"] not in (
            "succeeded",
            "failed",
            "cancelled",
        ):
            assert time.monotonic() < deadline, st
            time.sleep(0.2)
        assert st["state"] == "succeeded", st
        res = st["result"]
        assert res["matrix_error_rel"] < 1e-3, res["matrix_error_rel"]
        np.testing.assert_allclose(res["nonlinearity_pct_fs"], 0.05, rtol=0.1)
        np.testing.assert_allclose(res["hysteresis_pct_fs"], 0.03, rtol=0.1)
        assert res["verdict"] == "ok", res["reasons"]
    finally:
        svc.stop()
