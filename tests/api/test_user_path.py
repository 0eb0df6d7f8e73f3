"""The page's and the CLI's solve are one path (issue 22, "the demo is the user's path"): the
service's defaults (``POST /api/solutions`` with only the FRF set, what the demo and the page
send) and ``dimacq solve`` with no flags give the same answer on the same data."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from _api_support import Api
from _pg_support import SQLITE_ONLY

from dimacq.cli.main import main
from dimacq.io.setup_file import dump_setup_dict
from dimacq.io.uff import write_frf_uff
from dimacq.simulators.lab.scenarios import build_scenario

pytestmark = SQLITE_ONLY  # computation-bound: see _pg_support.SQLITE_ONLY


@pytest.mark.slow
def test_service_defaults_and_plain_cli_solve_agree(api: Api, tmp_path: Path) -> None:
    built = build_scenario("calibration-mass-realistic", 1)  # stated geometry with errors
    frf = built.model_frf(noise=0.01)
    r = api.client.post("/api/setups", json=dump_setup_dict(built.setup))
    assert r.status_code == 201, r.text
    sid = r.json()["id"]
    path = tmp_path / "frf.uff"
    write_frf_uff(path, frf)
    r = api.client.post("/api/frfs/import", params={"setup_id": sid}, content=path.read_bytes())
    assert r.status_code == 201, r.text
    fid = r.json()["id"]
    r = api.client.post("/api/solutions", json={"frf_id": fid}, timeout=300)
    assert r.status_code == 201, r.text
    served = r.json()["result"]
    whole = tmp_path / "test.uff"  # the set as the lab exports it: setup and FRFs in one file
    whole.write_bytes(api.client.get(f"/api/frfs/{fid}/uff").content)
    out = tmp_path / "cli.json"
    assert main(["solve", str(whole), "--json", str(out)]) in (0, 3)
    cli = json.loads(out.read_text())
    assert cli["verdict"] == served["verdict"] and cli["band_hz"] == served["band_hz"]
    assert cli["mass_kg"] == pytest.approx(served["mass_kg"], rel=1e-9)
    assert cli["cg_m"] == pytest.approx(served["cg_m"], rel=1e-9, abs=1e-12)
    assert np_close(cli["inertia_cg_kgm2"], served["inertia_cg_kgm2"])
    for k in ("m", "cx", "Ixx"):
        assert cli["uncertainty"][k]["ci95"] == pytest.approx(
            served["uncertainty"][k]["ci95"], rel=1e-6
        )


def np_close(a: list[list[float]], b: list[list[float]]) -> bool:
    import numpy as np

    return bool(np.allclose(a, b, rtol=1e-9, atol=1e-12))
