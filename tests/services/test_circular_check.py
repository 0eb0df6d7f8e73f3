"""How much the circular check can see of the cell (``cell_sensitivity``), on the true FRFs of
the calibration mass (the forward model, noise-free): hung on bungees (modes ≤ 2.1 Hz) the
cell carries only the suspension force above 20 Hz, about ``(f_s/f)² ≤ 1 %`` of the inertial
force, so its matrix hardly moves DIM's mass; standing on the cell (modes ≥ 137 Hz) the cell
carries nearly the whole hammer force below its mounted resonance, and DIM's mass is the small
difference of two large forces: a 1 % error of the cell moves it by far more than 1 %."""

from __future__ import annotations

import numpy as np

from dimacq.services.inertial_calibration import MIN_CELL_SENSITIVITY, cell_sensitivity
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
