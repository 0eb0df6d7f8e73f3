"""The real inertial-calibration path and the circular check, end to end by configuration.

As the acquisition's real branch is tested (``tests/services/test_rig_real.py``): ``daq =
"dimacq-usb"`` with ``daq_backend`` naming a pyusb backend factory that returns the USB DAQ
simulator, ``loadcell = "dimacq-can"`` on ``loadcell_interface = "virtual"`` with the amplifier
simulator listening; the rig file maps the cabling, the bench file's ``[inertial]`` table names
the calibration mass's setup with its certified properties. The world is the calibration mass on
its cell on the inertial bench (struck on the cell's support side); the test operator strikes
when the service asks. The cell has no calibration file yet (a new cell). Checks: the matrix
against the simulated cell's ``pinv(S)``, the download read back from the amplifier, the
versioned files, and then — on a second world where the mass is struck directly, read through
the installed file — the circular check against the certificate.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from _real_rig_support import VirtualWorld, installed

from dimacq.config import load_settings
from dimacq.errors import SetupError
from dimacq.io.loadcell_calibration import read_calibration
from dimacq.io.rig_file import load_rig_file
from dimacq.io.setup_file import save_setup
from dimacq.model.setup import KnownProperties
from dimacq.services.calibration.circular_check import circular_check
from dimacq.services.calibration.inertial_calibration import (
    install_inertial,
    run_inertial_calibration,
    select_cell,
)
from dimacq.services.calibration.loadcell_calibration import download_and_verify

FACTORY = "_real_rig_support:daq_backend"
INPUTS = tuple(range(0, 24, 3))  # 8 impact points on the three faces
PROMPT = re.compile(r"^strike input (\d+): ")

BENCH = """schema_version = 1
rated_load = [500.0, 500.0, 1000.0, 50.0, 50.0, 50.0]
[inertial]
setup_file = "calibration_mass.toml"
band_hz = [5.0, 800.0]
check_band_hz = [20.0, 400.0]
averages_per_input = 2
"""


def _settings(tmp_path: Path, world: VirtualWorld, rig_file: Path) -> Any:
    return load_settings(
        data_dir=tmp_path / "data",
        token="t",
        daq_backend=FACTORY,
        loadcell_interface="virtual",
        loadcell_virtual_ok=True,  # a simulator on python-can's in-process bus
        loadcell_channel=world.channel,
        rig_file=str(rig_file),
    )


def _operator(world: VirtualWorld, asked: list[int]) -> Any:
    def on_progress(_fraction: float, message: str) -> None:
        m = PROMPT.match(message)
        if m:
            asked.append(int(m.group(1)) - 1)
            world.strike(int(m.group(1)) - 1)  # the test operator, when asked

    return on_progress


def _write_bench(world: VirtualWorld) -> None:
    """The bench file and the calibration mass's setup beside the rig file; the certificate is
    the article's mass, CG and inertia (a machined block's drawing and weighing)."""
    props = world.built.truth
    I = props.inertia_about(np.zeros(3))
    idx = {"Ixx": (0, 0), "Ixy": (0, 1), "Ixz": (0, 2), "Iyy": (1, 1), "Iyz": (1, 2), "Izz": (2, 2)}
    known = KnownProperties(
        mass_kg=props.mass_kg,
        cg_m=tuple(float(c) for c in props.cg_m),
        inertia_kgm2={k: float(I[i, j]) for k, (i, j) in idx.items()},
    )
    folder = world.rig_file.parent
    save_setup(world.setup.model_copy(update={"known": known}), folder / "calibration_mass.toml")
    (folder / "loadcell_bench.toml").write_text(BENCH, encoding="utf-8")


@pytest.mark.slow
def test_inertial_calibration_and_circular_check_of_the_configured_cell(tmp_path: Path) -> None:
    bench_world = VirtualWorld(
        "calibration-mass-bungee", INPUTS, tmp_path / "rig", node_id=4, bench_node=501
    )
    rig_file = bench_world.rig_file
    _write_bench(bench_world)
    C_true = np.linalg.pinv(bench_world.lab.gauge_matrix(501))
    cal_path = bench_world.cal_files[0]
    cal_path.unlink()  # a new cell: no calibration file yet
    asked: list[int] = []
    requests: list[Any] = []
    with installed(bench_world):
        settings = _settings(tmp_path, bench_world, rig_file)
        assert (settings.daq, settings.loadcell) == ("dimacq-usb", "dimacq-can")
        run, check = run_inertial_calibration(
            settings,
            on_progress=_operator(bench_world, asked),
            download=download_and_verify,
            on_strike=requests.append,
        )
        sim_matrix = bench_world.sims[0].matrix.copy()
    C = run.matrix
    assert np.linalg.norm(C - C_true) / np.linalg.norm(C_true) < 5e-3
    assert run.fit.rank_used == 6 and run.n_inputs == len(INPUTS)
    # the rig file states the simulated hammer's true sensitivity here: the ratio is 1
    assert run.hammer_ratio is not None and abs(run.hammer_ratio[0] - 1) < 3e-3, run.hammer_ratio
    assert asked == [j for j, _ in bench_world.strikes] and len(asked) >= 2 * len(INPUTS)
    # every strike asked as a request too: the input's point and line of action, the average
    ins = bench_world.setup.excitations
    assert [r.input_index for r in requests] == asked
    for r in requests:
        e = ins[r.input_index]
        assert (r.node, r.direction, r.n_inputs, r.averages) == (e.node, e.direction, len(ins), 2)
        np.testing.assert_allclose(r.direction_gcs, e.direction_gcs)
        assert 1 <= r.average <= 2 and r.message.startswith(f"strike input {r.input_index + 1}:")
    assert [r.request for r in requests] == list(range(1, len(requests) + 1))
    # the accelerometers' relative gains found on the rigid mass; the rig file states the
    # simulated transducers' true sensitivities here: the gains are 1 within their uncertainty
    g = run.gains
    assert g is not None and g.identified
    assert np.all(np.abs(np.log(g.gains)) < 4 * g.relative_std + 2e-4), g.gains
    assert np.linalg.norm(C - C_true) / np.linalg.norm(C_true) < run.matrix_uncertainty_rel()
    # downloaded and read back: the amplifier holds the float32 matrix, all 72 verified
    assert check.verified == 72
    np.testing.assert_array_equal(sim_matrix, C.astype("<f4").astype(float))
    rig = load_rig_file(rig_file)
    inst = install_inertial(rig, select_cell(rig, None), run)
    assert inst.version == 1
    for p in (inst.json_path, inst.xml_path):
        kept = read_calibration(p)
        assert kept.method == "inertial" and kept.version == 1
        np.testing.assert_allclose(kept.matrix, C, rtol=1e-6)
    assert read_calibration(cal_path).version == 1

    # the circular check: the same mass on the same cell, struck on the mass, read through
    # the installed file (a second world: no bench, its own CAN channel, same cabling)
    check_world = VirtualWorld("calibration-mass-bungee", INPUTS, tmp_path / "w2", node_id=4)
    with installed(check_world):
        settings = _settings(tmp_path, check_world, rig_file)
        chk = circular_check(settings, on_progress=_operator(check_world, []))
    e = chk.errors_pct
    assert chk.calibration_version == 1
    assert abs(e["mass_pct"]) < 0.5, e
    assert e["cg_error_mm"] < 2.0 and max(abs(e[f"I{k}_pct"]) for k in (1, 2, 3)) < 2.0, e
    assert chk.to_json()["circular_mass_error_pct"] == e["mass_pct"]
    # hung on bungees the cell carries only the suspension force in the band: the check passes
    # on the mass but cannot vouch for the cell, and says so
    assert chk.cell_sensitivity < 0.05 and chk.verdict == "inconclusive", chk.reasons


def test_inertial_bench_needs_the_certified_calibration_mass(tmp_path: Path) -> None:
    world = VirtualWorld("calibration-mass-bungee", INPUTS, tmp_path / "rig", node_id=5)
    _write_bench(world)
    setup_file = world.rig_file.parent / "calibration_mass.toml"
    save_setup(world.setup, setup_file)  # no [known]: not a certificate
    with installed(world):
        settings = _settings(tmp_path, world, world.rig_file)
        with pytest.raises(SetupError, match=r"\[known\] lacks m, cx"):
            run_inertial_calibration(settings, on_progress=lambda f, m: None)
        (world.rig_file.parent / "loadcell_bench.toml").write_text(
            BENCH.split("[inertial]")[0], encoding="utf-8"
        )
        with pytest.raises(SetupError, match=r"no \[inertial\] table"):
            circular_check(settings, on_progress=lambda f, m: None)
