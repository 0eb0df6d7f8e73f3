"""One vocabulary for impact-test settings."""

from __future__ import annotations

import pytest
from pydantic import ValidationError

from dimacq.io.rig_file import RigFile
from dimacq.model.impact import ImpactOverrides, ImpactSettings


def test_overrides_are_the_user_facing_settings() -> None:
    assert set(ImpactOverrides.model_fields) <= set(ImpactSettings.model_fields)
    for name, f in ImpactOverrides.model_fields.items():
        assert f.description == ImpactSettings.model_fields[name].description, name


def test_layers_later_wins_and_none_is_not_given() -> None:
    rig = ImpactOverrides(record_samples=4096, averages_per_input=5, trigger_level_n=8.0)
    request = {"setup_id": 3, "averages_per_input": 2, "trigger_level_n": None}
    fixed = {"hit_delay_samples": 256}
    s = ImpactSettings.layered(rig, request, fixed)
    assert (s.record_samples, s.averages_per_input, s.trigger_level_n) == (4096, 2, 8.0)
    assert s.hit_delay_samples == 256 and s.pretrigger_samples == 32  # built-in default


def test_bounds_are_checked_once_for_every_source() -> None:
    with pytest.raises(ValidationError, match="averages_per_input"):
        ImpactOverrides(averages_per_input=0)
    with pytest.raises(ValidationError, match="averages_per_input"):
        ImpactSettings.layered({"averages_per_input": 0})
    assert RigFile.model_fields["acquisition"].annotation is ImpactOverrides
