"""Channel names are built in one place."""

from __future__ import annotations

import pytest

from dimacq.model.channels import N_GAUGES, axis_name, gauge_name, gauge_names, load_names


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
