"""Test setup model: every bad item is refused with its name and the fix."""

from __future__ import annotations

import numpy as np
import pytest
from pydantic import ValidationError

from dimacq.model.setup import Excitation, KnownProperties, LoadCell, ResponseChannel, TestSetup


def _resp(
    node: int = 1, direction: int = 1, d: tuple[float, float, float] = (1.0, 0.0, 0.0)
) -> ResponseChannel:
    return ResponseChannel(
        node=node, direction=direction, position_m=(0.1, 0.2, 0.3), direction_gcs=d
    )


def test_direction_not_unit_is_refused_with_node_and_fix() -> None:
    with pytest.raises(ValidationError) as err:
        _resp(node=1103, direction=2, d=(0.0, 2.0, 0.0))
    text = str(err.value)
    assert "1103+Y" in text and "length 2" in text and "give a unit vector" in text


def test_excitation_without_line_of_action_is_refused() -> None:
    with pytest.raises(ValidationError, match="no line of action"):
        Excitation(node=21, position_m=(0.0, 0.0, 0.0))


def test_load_cell_rotation_must_be_proper() -> None:
    reflect = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, -1.0))
    with pytest.raises(ValidationError, match="load cell 501: rotation is not a proper rotation"):
        LoadCell(node=501, position_m=(0.0, 0.0, 0.0), rotation=reflect)
    skewed = ((1.0, 0.1, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))
    with pytest.raises(ValidationError, match="orthonormal"):
        LoadCell(node=501, position_m=(0.0, 0.0, 0.0), rotation=skewed)


def test_duplicate_channels_and_empty_sets_are_refused() -> None:
    ex = Excitation(node=21, position_m=(0.0, 0.0, 0.0), direction_gcs=(0.0, 0.0, 1.0))
    with pytest.raises(ValidationError, match="appears twice"):
        TestSetup(responses=(_resp(), _resp()), excitations=(ex,))
    with pytest.raises(ValidationError, match="responses is empty"):
        TestSetup(responses=(), excitations=(ex,))


def test_known_properties_as_dict_and_sign_factor() -> None:
    k = KnownProperties(m=2.0, cy=0.1, Ixy=0.0)
    assert k.as_dict() == {"m": 2.0, "cy": 0.1, "Ixy": 0.0}
    cell = LoadCell(node=1, position_m=(0.0, 0.0, 0.0), sign="on_support")
    assert cell.sign_factor == -1.0
    assert np.allclose(cell.rotation_matrix, np.eye(3))
    with pytest.raises(ValidationError):
        KnownProperties(m=-1.0)
