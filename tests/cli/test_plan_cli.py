"""``dimacq plan``: the command's contract (JSON keys, layout from the candidates, errors), and
the Monte Carlo giving the same JSON in-process and on a Dask cluster for the same seed."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from dimacq.cli.main import main

ROOT = Path(__file__).resolve().parents[2]
CM_SETUP = ROOT / "config" / "plans" / "calibration-mass-candidates.toml"
CM_PROPS = ROOT / "config" / "plans" / "calibration-mass-properties.json"
BOUNDS = {"mass_pct", "cg_mm", "principal_pct"}


def _plan(tmp_path: Path, name: str, *extra: str, k: int = 4, m: int = 8) -> dict:
    out = tmp_path / f"{name}.json"
    rc = main(
        [
            "plan",
            str(CM_SETUP),
            "--properties",
            str(CM_PROPS),
            "--triaxes",
            str(k),
            "--inputs",
            str(m),
            "--json",
            str(out),
            "--quiet",
            *extra,
        ]
    )
    assert rc == 0
    return json.loads(out.read_text())


@pytest.mark.slow
def test_plan_json_contract(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from dimacq.io.setup_file import load_setup

    plan = _plan(tmp_path, "plan")
    assert {"layout", "predicted", "random_median"} <= set(plan)
    setup = load_setup(CM_SETUP)
    nodes = {c.node for c in setup.responses}
    inputs = {e.node for e in setup.excitations}
    lay = plan["layout"]
    assert len(lay["responses"]) == 4 and set(lay["responses"]) <= nodes
    assert len(lay["inputs"]) == 8 and set(lay["inputs"]) <= inputs
    for key in ("predicted", "random_median"):
        assert BOUNDS <= set(plan[key])
        assert all(plan[key][b] > 0 for b in BOUNDS)
    # the chosen layout is at least as good as the median random one on the criterion's targets
    assert plan["predicted"]["principal_pct"] <= plan["random_median"]["principal_pct"]
    assert {"condition_number", "weak_parameters"} <= set(plan["observability"])
    assert {"noise", "sensor_position", "force_gain"} <= set(plan["error_budget"])
    assert {"triax", "input"} <= set(plan["one_more"])
    assert "monte_carlo" not in plan
    text = capsys.readouterr().out
    assert "predicted 95 % bounds" in text and "random layouts (median)" in text


def test_plan_refuses_bad_requests(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    args = ["plan", str(CM_SETUP), "--properties", str(CM_PROPS), "--inputs", "8"]
    assert main([*args, "--triaxes", "40"]) == 2
    assert "--triaxes 40" in capsys.readouterr().err
    assert main([*args, "--triaxes", "4", "--properties", str(tmp_path / "none.json")]) == 2
    assert "does not exist" in capsys.readouterr().err
    assert main([*args, "--triaxes", "4", "--trials", "1", "--scheduler", "nowhere"]) == 2
    assert "--scheduler 'nowhere'" in capsys.readouterr().err


@pytest.fixture(scope="module")
def _dask_offload_thread() -> None:
    """distributed keeps one process-wide offload thread (``Dask-Offload``) alive once used; start
    it before the test so that the leaked-thread check sees it as already there."""
    from distributed.utils import _offload_executor

    _offload_executor.submit(lambda: None).result()


@pytest.mark.slow
@pytest.mark.usefixtures("_dask_offload_thread")
def test_same_seed_same_json_in_process_and_on_a_local_cluster(tmp_path: Path) -> None:
    """Two trials (default solves) in this process, then on a LocalCluster of two workers
    started here (threads, no processes: fast to start): identical JSON."""
    from dask.distributed import LocalCluster

    local = _plan(tmp_path, "inproc", "--trials", "2", "--seed", "3", "--scheduler", "none")
    with LocalCluster(
        n_workers=2,
        threads_per_worker=1,
        processes=False,
        dashboard_address=None,
        # its HTTP server on a free loopback port, not 8787 (another cluster on this PC: a warning)
        scheduler_kwargs={"dashboard_address": "127.0.0.1:0"},
    ) as cluster:
        remote = _plan(
            tmp_path, "cluster", "--trials", "2", "--seed", "3", "--scheduler",
            cluster.scheduler_address,
        )  # fmt: skip
    assert remote == local
    mc = local["monte_carlo"]
    assert mc["n_trials"] == 2 and mc["n_solved"] == 2
    assert BOUNDS <= set(mc["bounds"])
