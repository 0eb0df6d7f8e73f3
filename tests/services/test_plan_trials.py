"""The plan's Monte Carlo trial (dimacq.services.solve.planning.run_trial): a simulated test of a layout
solved by the default ``dimacq solve``. With (almost) no noise and no geometry or transducer
error, the solve returns the expected properties; trial i's draws do not depend on the others."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from dimacq.io.setup_file import load_setup
from dimacq.model.properties import RigidBodyProperties
from dimacq.pipeline import planning as pl
from dimacq.services.solve.planning import TrialSpec, layout_setup, run_trial

ROOT = Path(__file__).resolve().parents[2]


def _spec(**errors: float) -> TrialSpec:
    import json

    setup = load_setup(ROOT / "config" / "plans" / "calibration-mass-candidates.toml")
    props = RigidBodyProperties.from_json(
        json.loads((ROOT / "config" / "plans" / "calibration-mass-properties.json").read_text())
    )
    cand = pl.candidates_from_setup(setup)
    lay = pl.Layout((0, 2, 4, 6, 8, 12), tuple(range(0, 24, 2)))
    em = replace(pl.ErrorModel.from_setup(setup, noise=0.01, n_lines=41), **errors)
    return TrialSpec(cand, lay, layout_setup(setup, cand, lay), props, em, seed=4)


def test_exact_test_gives_the_expected_properties() -> None:
    spec = _spec(
        noise=1e-6,
        sensor_position_m=0.0,
        sensor_orientation_deg=0.0,
        accel_gain_rel=0.0,
        input_position_m=0.0,
        line_of_action_deg=0.0,
        force_gain_rel=0.0,
    )
    row = np.array(run_trial(spec, 0))
    assert np.all(np.abs(row[[0, 4, 5, 6]]) < 1e-3)  # mass, principal moments: %
    assert np.all(np.abs(row[1:4]) < 1e-3)  # CG: mm
    assert row[14] < 3  # an answer


def test_trial_draws_depend_only_on_seed_and_index() -> None:
    spec = _spec()
    cand, lay, props, em = spec.candidates, spec.layout, spec.properties, spec.errors
    a, _ = pl.simulated_frf(cand, lay, props, em, 5, np.random.default_rng(
        np.random.SeedSequence(4, spawn_key=(3,))))  # fmt: skip
    b, _ = pl.simulated_frf(cand, lay, props, em, 5, np.random.default_rng(
        np.random.SeedSequence(4).spawn(10)[3]))  # fmt: skip
    np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize(("n_trials", "workers"), [(1, 2), (7, 2), (100, 2), (1000, 2), (1000, 8)])
def test_trial_batches_cover_every_trial_once_in_order(n_trials: int, workers: int) -> None:
    from dimacq.services.solve.planning import BATCH_MAX, trial_batches

    batches = trial_batches(n_trials, workers)
    assert [i for b in batches for i in b] == list(range(n_trials))
    assert all(1 <= len(b) <= BATCH_MAX for b in batches)
    assert len(batches) >= min(n_trials, 8 * workers)  # enough tasks to keep the workers busy
