"""Figures: every function writes a PNG and an SVG that are what they claim to be."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from _selection_support import forward_case

from dimacq.pipeline.dim import assemble
from dimacq.pipeline.selection.inputs import jackknife_inputs
from dimacq.pipeline.selection.responses import select_responses_frf
from dimacq.pipeline.sensitivity import cube_study
from dimacq.plotting import (
    plot_cmif,
    plot_jackknife,
    plot_parameters_vs_frequency,
    plot_response_errors,
    plot_sensitivity,
)


def _check(paths: list[Path]) -> None:
    assert [p.suffix for p in paths] == [".png", ".svg"]
    assert paths[0].read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert "<svg" in paths[1].read_text()[:2000]


def test_all_figures(tmp_path: Path) -> None:
    c = forward_case(0, triax_error_deg=0.5, n_bad_channels=1, bad_channel_deg=20, n_bad_inputs=1)
    sel, _ = select_responses_frf(c.frf, c.nominal)
    _check(plot_response_errors(sel, c.frf.frequencies_hz, tmp_path))
    jk = jackknife_inputs(assemble(c.frf, c.nominal, response_weights=sel.weights))
    _check(plot_jackknife(jk, tmp_path))
    f = c.frf.frequencies_hz
    pl = np.tile(np.arange(10.0), (f.size, 1))
    _check(
        plot_parameters_vs_frequency(
            f, pl, (50.0, 150.0), tmp_path / "sub", headline=np.arange(10.0)
        )
    )
    _check(plot_cmif(f, np.abs(c.frf.H[:, 0, :3]), tmp_path, band_hz=(50.0, 150.0)))
    res = cube_study(0.01, max_angle_deg=1.0, n_trials=50, seed=0)
    _check(plot_sensitivity(res.samples, res.truth, tmp_path))
