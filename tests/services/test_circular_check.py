"""How much the circular check can see of the cell (``cell_sensitivity``), on the true FRFs of
the calibration mass (the forward model, noise-free): hung on bungees (modes ≤ 2.1 Hz) the
cell carries only the suspension force above 20 Hz, about ``(f_s/f)² ≤ 1 %`` of the inertial
force, so its matrix hardly moves DIM's mass; standing on the cell (modes ≥ 137 Hz) the cell
carries nearly the whole hammer force below its mounted resonance, and DIM's mass is the small
difference of two large forces: a 1 % error of the cell moves it by far more than 1 %."""

from __future__ import annotations

import numpy as np
import pytest

from dimacq.services.calibration.circular_check import MIN_CELL_SENSITIVITY, cell_sensitivity
from dimacq.simulators.lab.scenarios import build_scenario


def _sensitivity(scenario: str) -> float:
    built = build_scenario(scenario, None)
    frf = built.model.frf(np.arange(20.0, 100.5, 0.5))
    return cell_sensitivity(frf, built.setup, (20.0, 100.0))


def test_the_bungee_check_cannot_see_the_cell() -> None:
    s = _sensitivity("calibration-mass-bungee")
    assert s < (2.1 / 20.0) ** 2 and s < MIN_CELL_SENSITIVITY


def test_standing_on_the_cell_the_check_amplifies_it() -> None:
    assert _sensitivity("calibration-mass-ground") > 1.0


def test_the_bench_checks_on_the_mass_standing_on_the_cell(tmp_path) -> None:
    """The shipped bench file stands the calibration mass on the cell for the check (its own
    setup: the same mass and sensors, the cell underneath); the simulated lab's world of the
    check is then the scenario where it stands on the cell, a real rig stays as configured, and
    a bench without ``check_setup_file`` checks on the calibration's own mounting."""
    from dimacq.config import Settings, default_config_file
    from dimacq.io.loadcell_bench import load_bench_file
    from dimacq.services.calibration.circular_check import SIMULATED_ON_CELL_SCENARIO, check_world
    from dimacq.services.calibration.inertial_calibration import calibration_mass

    bench = load_bench_file(default_config_file().parent / "loadcell_bench.toml")
    hung, props = calibration_mass(bench, 501)
    stands, props_check = calibration_mass(bench, 501, check=True)
    assert props_check.mass_kg == props.mass_kg
    np.testing.assert_allclose(props_check.cg_m, props.cg_m)
    np.testing.assert_allclose(stands.response_positions, hung.response_positions)
    assert stands.load_cells[0].position_m[2] < min(np.asarray(stands.response_positions)[:, 2])
    truth = build_scenario(SIMULATED_ON_CELL_SCENARIO, None).setup.load_cells[0]
    np.testing.assert_allclose(stands.load_cells[0].position_m, truth.position_m)
    sim = Settings(daq="simulated", loadcell="simulated", rig_file="", data_dir=tmp_path)
    assert check_world(sim, bench).scenario == SIMULATED_ON_CELL_SCENARIO
    real = Settings(daq="dimacq-usb", loadcell="dimacq-can", rig_file="", data_dir=tmp_path)
    assert check_world(real, bench) is real
    same = bench.model_copy(
        update={"inertial": bench.inertial.model_copy(update={"check_setup_file": ""})}
    )
    assert same.check_setup_path() == same.inertial_setup_path()
    assert check_world(sim, same) is sim


def test_the_chain_weighs_as_the_cell_says() -> None:
    """Hung, DIM's mass is the hammer's force over the acceleration (+1, −1); on the cell the
    hammer's weight is 1 − the cell's (hammer and cell read high together: every force
    scaled), so the check compares the cell with the hammer–accelerometer chain."""
    from dimacq.services.calibration.circular_check import chain_sensitivities

    for scenario, band in (
        ("calibration-mass-bungee", (20.0, 100.0)),
        ("calibration-mass-ground", (20.0, 400.0)),
    ):
        built = build_scenario(scenario, None)
        frf = built.model.frf(np.arange(band[0], band[1] + 0.5, 0.5))
        s_c = cell_sensitivity(frf, built.setup, band)
        s_h, s_a = chain_sensitivities(frf, built.setup, band)
        assert s_a == pytest.approx(-1 / 1.01, rel=1e-3)
        assert s_h == pytest.approx(1 - s_c, abs=0.02)
