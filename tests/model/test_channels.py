"""Channel names are built in one place."""

from __future__ import annotations

import numpy as np
import pytest

from dimacq.model.channels import (
    N_GAUGES,
    axis_name,
    gauge_name,
    gauge_names,
    input_name,
    load_names,
)
from dimacq.model.setup import Excitation


def test_names() -> None:
    assert axis_name(1103, 2) == "1103+Y" and axis_name(7, -3) == "7-Z"
    assert gauge_names(501) == [f"LC501 g{g:02d}" for g in range(1, 13)] and N_GAUGES == 12
    assert load_names(501) == [
        "LC501 Fx",
        "LC501 Fy",
        "LC501 Fz",
        "LC501 Mx",
        "LC501 My",
        "LC501 Mz",
    ]
    with pytest.raises(ValueError, match="gauge 12"):
        gauge_name(501, 12)


def _struck(direction: int, d: tuple[float, float, float]) -> Excitation:
    return Excitation(node=117, direction=direction, position_m=(0, 0, 0), direction_gcs=d)


def test_input_named_by_its_line_of_action_not_its_uff_label() -> None:
    # UFF direction 1 (+X in the node's system), struck along +Z in the GCS
    assert input_name(_struck(1, (0.0, 0.0, 1.0))) == "117+Z"
    assert input_name(_struck(3, (-1.0, 0.0, 0.0))) == "117-X"
    # 19° off −Y: still −Y; 21° off every axis: its direction cosines
    a = np.radians(19.0)
    assert input_name(_struck(1, (np.sin(a), -np.cos(a), 0.0))) == "117-Y"
    b = np.radians(21.0)
    assert input_name(_struck(1, (np.sin(b), 0.0, np.cos(b)))) == "117(+0.36,+0.00,+0.93)"
    h = np.sqrt(0.5)
    assert input_name(_struck(2, (h, 0.0, -h))) == "117(+0.71,+0.00,-0.71)"
