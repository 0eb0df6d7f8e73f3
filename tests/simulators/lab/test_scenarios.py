"""Scenario files: every bundled one loads and is deterministic; bad files are refused naming
the item and the fix."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from pydantic import ValidationError

from dimacq.errors import SetupError
from dimacq.simulators.lab.scenarios import (
    Scenario,
    build_scenario,
    gross_errors,
    list_scenarios,
    load_scenario,
    nominal_setup,
)

NAMES = (
    "calibration-mass-bungee",
    "calibration-mass-air-ride",
    "calibration-mass-ground",
    "x38",
    "cube-0.02",
    "cube-2",
    "cube-200",
)

GOOD = """
schema_version = 1
name = "t"
[article]
model = "calibration-mass"
support = "bungee"
[band]
lo_hz = 20.0
hi_hz = 60.0
"""


def test_the_issue_s_scenarios_are_bundled_and_build() -> None:
    assert set(NAMES) <= set(list_scenarios())
    for name in NAMES:
        b = build_scenario(name)
        assert b.spec.name == name
        lo, hi = b.band_hz
        f = b.frequencies_hz()
        assert f[0] > 0 and f[0] <= lo < hi <= f[-1]
        if b.model.supports and b.spec.article.support != "ground":
            assert b.model.suspension_frequencies_hz().max() < lo / 3  # band above the supports


def test_scenarios_are_deterministic_and_seeded() -> None:
    a = build_scenario("calibration-mass-bungee").model_frf(noise=0.01)
    b = build_scenario("calibration-mass-bungee").model_frf(noise=0.01)
    assert np.array_equal(a.H, b.H)
    c = build_scenario("calibration-mass-bungee", seed=5)
    assert not np.allclose(
        c.setup.response_positions,
        build_scenario("calibration-mass-bungee").setup.response_positions,
    )


def test_x38_scenario_has_the_thesis_layout() -> None:
    b = build_scenario("x38")
    s = b.setup
    assert len({c.node for c in s.responses}) == 21 and len(s.excitations) == 22
    assert len(s.load_cells) == 3
    for lc in s.load_cells:  # no cell aligned with the GCS
        assert np.abs(np.abs(lc.rotation_matrix) - np.eye(3)).max() > 0.05
    assert {m.frequency_hz for m in b.model.modes} == {4.8, 5.3, 23.0}
    assert b.spec.analysis.exclude_nodes == (1019, 1020, 1021)
    assert b.truth.mass_kg == pytest.approx(8089.0)


def test_nominal_geometry_errors_have_the_requested_size() -> None:
    true = build_scenario("x38").model.setup
    from dimacq.simulators.lab.scenarios import ErrorsSpec

    nom = nominal_setup(
        true, ErrorsSpec(position_m=0.01, orientation_deg=2.0, line_of_action_deg=3.0), 4
    )
    dp = nom.response_positions - true.response_positions
    assert 0.005 < dp.std() < 0.015
    ang = np.degrees(
        np.arccos(np.clip(np.sum(nom.input_directions * true.input_directions, 1), -1, 1))
    )
    assert 1.0 < np.sqrt(np.mean(ang**2)) < 6.0
    assert nominal_setup(true, ErrorsSpec(), 4) is true


@pytest.mark.parametrize(
    ("edit", "item", "fix"),
    [
        (lambda t: t + "colour = 'red'\n", "band.colour", "remove it"),
        (lambda t: t.replace("hi_hz = 60.0", "hi_hz = 10.0"), "band", "lo_hz < hi_hz"),
        (lambda t: t.replace("[band]\nlo_hz = 20.0\nhi_hz = 60.0\n", ""), "band", "add it"),
        (lambda t: t + "[hammer]\npeak_n = -5\n", "hammer.peak_n", "peak hammer force"),
        (
            lambda t: t.replace('support = "bungee"', 'support = "trampoline"'),
            "article.support",
            "bungee, air-ride",
        ),
        (lambda t: t.replace('support = "bungee"\n', ""), "article", "needs article.support"),
        (
            lambda t: t.replace("schema_version = 1", "schema_version = 7"),
            "schema_version",
            "version: 1",
        ),
        (lambda t: t + "[frequency_axis]\nmax_hz = 50.0\n", "(file)", "raise max_hz"),
        (
            lambda t: t + "[acquisition]\naverages = 0\n",
            "acquisition.averages",
            "averages per input",
        ),
    ],
)
def test_bad_scenario_files_are_refused_with_item_and_fix(tmp_path: Path, edit, item, fix) -> None:
    p = tmp_path / "bad.toml"
    p.write_text(edit(GOOD))
    with pytest.raises(SetupError) as info:
        load_scenario(p)
    msg = str(info.value)
    assert f"item '{item}" in msg and fix in msg and "fix:" in msg, msg


def test_unknown_names_syntax_errors_and_bad_exclusions(tmp_path: Path) -> None:
    with pytest.raises(SetupError, match=r"unknown; use one of .*calibration-mass-bungee"):
        load_scenario("moon-lander")
    p = tmp_path / "broken.toml"
    p.write_text("schema_version = = 1")
    with pytest.raises(SetupError, match="not valid TOML"):
        load_scenario(p)
    p.write_text(GOOD + "[analysis]\nexclude_nodes = [999]\n")
    with pytest.raises(SetupError, match=r"exclude_nodes lists \[999\]"):
        build_scenario(p)


def test_gross_errors_are_what_the_nominal_setup_states() -> None:
    """Mis-mounted axes and bad impacts: exactly the chosen items differ grossly from the truth,
    by the stated angles, and the setup states the small error levels (not the gross ones)."""
    built = build_scenario("calibration-mass-realistic", seed=5)
    truth, told = built.model.setup, built.setup
    bad_ch, bad_in = gross_errors(truth, built.spec.errors, 5)
    assert len(bad_ch) == 2 and len(bad_in) == 2

    def angle(a: object, b: object) -> float:
        c = float(np.clip(np.dot(np.asarray(a), np.asarray(b)), -1.0, 1.0))
        return float(np.degrees(np.arccos(c)))

    ch_angles = [
        angle(t.direction_gcs, n.direction_gcs)
        for t, n in zip(truth.responses, told.responses, strict=True)
    ]
    in_angles = [
        angle(t.direction_gcs, n.direction_gcs)
        for t, n in zip(truth.excitations, told.excitations, strict=True)
    ]
    # gross = the stated angle composed with the ordinary N(0, 0.5°)/N(0, 1°) error: within 5°
    assert sorted(np.argsort(ch_angles)[-2:].tolist()) == list(bad_ch)
    assert all(abs(ch_angles[k] - 15.0) < 5.0 for k in bad_ch)
    assert max(a for k, a in enumerate(ch_angles) if k not in bad_ch) < 4.0
    assert sorted(np.argsort(in_angles)[-2:].tolist()) == list(bad_in)
    assert all(abs(in_angles[j] - 20.0) < 6.0 for j in bad_in)
    gu = told.geometry_uncertainty
    assert (gu.sensor_orientation_deg, gu.line_of_action_deg, gu.source) == (0.5, 1.0, "stated")
    assert gu.sensor_position_m == pytest.approx(0.002)


def test_x38_elastic_and_suspension_frequencies_are_settable() -> None:
    spec = load_scenario("x38").model_dump()
    spec["article"].update(chute_modes_hz=(4.0, 6.0), deformation_mode_hz=8.0, suspension_hz=1.5)
    built = build_scenario(Scenario.model_validate(spec), seed=1)
    assert [m.frequency_hz for m in built.model.modes] == [4.0, 6.0, 8.0]
    # the bounce modes of three 1.5 Hz air rides under the vehicle sit near 1.5 Hz
    assert 1.2 < built.model.suspension_frequencies_hz()[-1] < 2.0
    spec["article"].update(model="cube", half_size_m=2.0)
    with pytest.raises(ValidationError, match="applies to the x38 only"):
        Scenario.model_validate(spec)
