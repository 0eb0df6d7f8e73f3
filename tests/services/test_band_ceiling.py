"""The second automatic band pass stays below the first's upper edge when the first found an
elastic mode above its band (dimacq.services.solve.selection_steps.below_first_elastic_ceiling)."""

from __future__ import annotations

import numpy as np

from dimacq.pipeline.selection.band import BandSuggestion
from dimacq.services.solve.selection_steps import below_first_elastic_ceiling

F = np.arange(1, 161) * 0.125  # 0.125 … 20 Hz


def suggestion(band: tuple[float, float], elastic: tuple[float, ...] = ()) -> BandSuggestion:
    n = F.size
    return BandSuggestion(
        band_hz=band,
        reason="test",
        frequencies_hz=F,
        cmif=np.ones((n, 1)),
        rigid_body_error=np.linspace(0.0, 0.1, n),
        roughness=np.zeros(n),
        usable=np.ones(n, bool),
        suspension_peaks_hz=(),
        deformation_peaks_hz=elastic,
        per_line=np.zeros((n, 10)),
        residual=np.linspace(0.0, 0.2, n),
    )


def test_second_pass_is_clipped_to_the_first_upper_edge() -> None:
    first = suggestion((7.5, 8.75), elastic=(17.0, 24.0))
    out = below_first_elastic_ceiling(suggestion((6.0, 15.0)), first)
    assert out.band_hz == (6.0, 8.75)
    assert "17" in out.reason and "stays below" in out.reason
    inside = (F >= 6.0) & (F <= 8.75)
    assert out.band_rigid_body_error == np.max(np.linspace(0.0, 0.1, F.size)[inside])


def test_second_pass_entirely_above_falls_back_to_the_first_band() -> None:
    first = suggestion((7.5, 8.75), elastic=(17.0,))
    assert below_first_elastic_ceiling(suggestion((11.375, 15.125)), first).band_hz == (7.5, 8.75)


def test_no_elastic_mode_above_leaves_the_second_pass_alone() -> None:
    second = suggestion((6.0, 15.0))
    assert below_first_elastic_ceiling(second, suggestion((7.5, 8.75))) is second
    below = suggestion((5.0, 8.0))
    assert below_first_elastic_ceiling(below, suggestion((7.5, 8.75), (17.0,))) is below
