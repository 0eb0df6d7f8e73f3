"""On demand: the load cell on the CANopen backend against the native
(CAN FD) one, each through its own ``dimacq serve`` process configured only by
``DIMACQ_LOADCELL`` (``simulated`` | ``canopen-simulated``):

1. the whole simulated DIM test (``dimacq demo``'s client: digitizing, setup, 24 inputs × N
   averages through the simulated DAQ and load cell, solve) against the scenario's truth as the
   rig file's certificates see it (``calibration_scale``), with the accepted / rejected averages
   and the wall time;
2. a bench calibration through the API (static, minimal plan, virtual dead-weight bench behind
   the backend's amplifier simulator): matrix error against the simulated cell's ``pinv(S)``,
   nonlinearity and hysteresis against the simulated 0.05 % and 0.03 %.

    python tests/scripts/canopen_must_show.py [--averages 3] [--results PATH]

The table goes to ``canopen_must_show_results.md`` beside this script (``--results`` elsewhere)
with the command, date, commit and machine load.
"""

from __future__ import annotations

import argparse
import secrets
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from _acq_support import calibration_scale
from _results import Results, add_results_argument
from _serve_support import Service

from dimacq.api.server import free_port
from dimacq.cli.commands import demo
from dimacq.config import load_settings, scenario_rig_file
from dimacq.simulators.lab.scenarios import build_scenario

SCENARIO = "calibration-mass-bungee"


def run(backend: str, averages: int, root: Path) -> dict[str, float | str]:
    built = build_scenario(SCENARIO, None)
    port = free_port()
    token = secrets.token_urlsafe(12)
    rig = scenario_rig_file(SCENARIO)
    env = {
        "DIMACQ_LOADCELL": backend,
        "DIMACQ_SCENARIO": SCENARIO,
        "DIMACQ_RIG_FILE": rig,
        "DIMACQ_DIGITIZER_URL": f"simdigitizer://must{port}?seed={built.seed}",
    }
    (root / backend).mkdir(parents=True)
    svc = Service(root / backend / "data", port, token, env=env)
    try:
        args = argparse.Namespace(
            averages=averages,
            full=True,  # the rig file's [acquisition], as before dimacq demo's own cut
            record_samples=None,
            data_dir=None,
            geometry="digitizer",
            json=None,
            model_frfs=False,
            no_chain_calibration=True,
            photos=40,
            noise=0.005,
            quiet=True,
            rig_file=None,
            scenario=SCENARIO,
            scenario_band=False,
            seed=None,
        )
        t0 = time.perf_counter()
        p = demo.run_demo(svc.url, token, built, args, lambda m: None)
        demo_s = time.perf_counter() - t0
        acq = svc.client.get("/api/acquisitions").json()[-1]
        t0 = time.perf_counter()
        r = svc.client.post("/api/calibrations/runs", json={"method": "static", "plan": "minimal"})
        job = r.json()["job_id"]
        while (st := svc.client.get(f"/api/jobs/{job}").json())["state"] == "running" or st[
            "state"
        ] == "queued":
            time.sleep(0.2)
        cal_s = time.perf_counter() - t0
        res = st["result"]
    finally:
        svc.stop()
    scale = calibration_scale(load_settings(rig_file=rig).rig_path)
    t = p["truth"]
    moments = np.asarray(p["principal_moments_kgm2"]) / (
        scale * np.asarray(t["principal_moments_kgm2"])
    )
    return {
        "backend": backend,
        "mass_err_pct": 100 * (p["mass_kg"] / (scale * t["mass_kg"]) - 1),
        "cg_err_mm": 1e3 * float(np.linalg.norm(np.subtract(p["cg_m"], t["cg_m"]))),
        "moment_err_pct_max": float(100 * np.max(np.abs(moments - 1))),
        "verdict": p["verdict"],
        "accepted": acq.get("averages_accepted", "?"),
        "rejected": acq.get("averages_rejected", "?"),
        "demo_s": demo_s,
        "cal_state": st["state"],
        "matrix_error_rel": res["matrix_error_rel"],
        "nonlinearity_pct_fs_max": max(res["nonlinearity_pct_fs"]),
        "hysteresis_pct_fs_max": max(res["hysteresis_pct_fs"]),
        "cal_verdict": res["verdict"],
        "cal_s": cal_s,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--averages", type=int, default=3)
    add_results_argument(ap, __file__)
    a = ap.parse_args()
    out = Results(__file__, "The load cell on the CANopen backend against CAN FD", a.results)
    backends = ("simulated", "canopen-simulated")
    with tempfile.TemporaryDirectory(prefix="dimacq-canopen-") as tmp:
        rows = [run(b, a.averages, Path(tmp)) for b in backends]
    keys = list(rows[0])
    table = []
    for k in keys:
        vals = [f"{r[k]:.4g}" if isinstance(r[k], float) else str(r[k]) for r in rows]
        print(f"{k:<26}" + "".join(f"{v:>22}" for v in vals))
        table.append((k, *vals))
    out.table(["figure", *(f"`DIMACQ_LOADCELL={b}`" for b in backends)], table)
    out.write()


if __name__ == "__main__":
    main()
