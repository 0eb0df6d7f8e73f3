"""Chain calibration through the API: a reference-mass solve measures the chain factor, a later
solve applies it by id (``reference_mass`` / ``chain_calibration_id`` of POST /api/solutions)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from _api_support import Api
from _pg_support import SQLITE_ONLY

from dimacq.io.setup_file import dump_setup_dict
from dimacq.io.uff import write_frf_uff
from dimacq.simulators.lab.forward import (
    CALIBRATION_MASS,
    REFERENCE_BLOCK,
    calibration_mass,
    reference_block,
    reference_block_drawing,
)

pytestmark = SQLITE_ONLY  # computation-bound: see _pg_support.SQLITE_ONLY

KAPPA = 1.015  # the hammer's certificate 1.5 % off: every FRF × κ


def _store(api: Api, setup, frf, name: str) -> int:
    sid = api.client.post("/api/setups", json=dump_setup_dict(setup)).json()["id"]
    path = Path(api.settings.data_dir) / f"{name}.uff"
    write_frf_uff(path, frf)
    r = api.client.post("/api/frfs/import", params={"setup_id": sid}, content=path.read_bytes())
    assert r.status_code == 201, r.text
    return int(r.json()["id"])


@pytest.mark.slow
def test_reference_mass_then_applied_by_id(api: Api) -> None:
    f = np.linspace(10.0, 120.0, 56)
    rng = np.random.default_rng(7)

    def noisy(frf):
        H = frf.H * (1 + 0.005 * (rng.standard_normal(frf.H.shape)))
        return frf.replace(H=H).scaled(KAPPA)

    block_fid = _store(api, reference_block_drawing(), noisy(reference_block(2).frf(f)), "block")
    model = calibration_mass(2, support="bungee")
    art_fid = _store(api, model.setup, noisy(model.frf(f)), "article")

    # the article alone: 1.5 % light, and the verdict cannot know it
    plain_out = api.client.post("/api/solutions", json={"frf_id": art_fid}).json()
    plain, plain_id = plain_out["result"], plain_out["id"]
    assert plain["mass_kg"] / CALIBRATION_MASS.mass_kg - 1 == pytest.approx(
        1 / KAPPA - 1, abs=0.002
    )
    assert "chain_calibration" not in plain

    r = api.client.post(
        "/api/solutions",
        json={
            "frf_id": block_fid,
            "reference_mass": {"mass_kg": REFERENCE_BLOCK.mass_kg, "u_kg": 0.005},
        },
    )
    assert r.status_code == 201, r.text
    ref = r.json()
    cal = ref["result"]["chain_calibration"]
    assert cal["role"] == "measured" and ref["result"]["verdict"] != "fail"
    assert abs(cal["factor"] * KAPPA - 1) < 3 * cal["u_rel"] + 1e-4
    assert ref["result"]["transducer_uncertainty"]["force_sensitivity_rel"] == 0.0

    r = api.client.post(
        "/api/solutions", json={"frf_id": art_fid, "chain_calibration_id": ref["id"]}
    )
    assert r.status_code == 201, r.text
    res = r.json()["result"]
    assert res["chain_calibration"]["role"] == "applied"
    assert res["chain_calibration"]["source"] == f"solution {ref['id']} (FRF set {block_fid})"
    assert abs(res["mass_kg"] / CALIBRATION_MASS.mass_kg - 1) < 0.003
    lo, hi = res["uncertainty"]["m"]["ci95"]
    assert lo <= CALIBRATION_MASS.mass_kg <= hi
    assert res["transducer_uncertainty"] == {
        "accel_sensitivity_rel": 0.005,
        "force_sensitivity_rel": pytest.approx(cal["u_rel"]),
        "loadcell_matrix_rel": 0.01,
        "source": "chain",
    }
    sid = r.json()["id"]
    fig = api.client.get(f"/api/solutions/{sid}/figure")
    assert fig.status_code == 200 and fig.content[:4] == b"\x89PNG"

    # refusals: an id that measured nothing, no such id, both at once, a bad mass
    for body, words in (
        ({"frf_id": art_fid, "chain_calibration_id": plain_id}, "measured no chain calibration"),
        ({"frf_id": art_fid, "chain_calibration_id": 10**9}, "no such solution"),
        (
            {
                "frf_id": art_fid,
                "chain_calibration_id": ref["id"],
                "reference_mass": {"mass_kg": 18.0},
            },
            "either",
        ),
        ({"frf_id": art_fid, "reference_mass": {"mass_kg": -1}}, "mass_kg"),
    ):
        r = api.client.post("/api/solutions", json=body)
        assert r.status_code == 422, (body, r.text)
        assert words in r.text, r.text
