"""Figures of a real solve: each is written (PNG and SVG) and shows the report's own numbers."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from _selection_support import forward_case
from matplotlib.figure import Figure

import dimacq.plotting.figures as figures
from dimacq.model.setup import PARAMETERS
from dimacq.pipeline.sensitivity import cube_study
from dimacq.services.solve.analysis import AnalysisOptions, analyse


def _line_data(ax) -> list[np.ndarray]:  # type: ignore[no-untyped-def]
    return [np.asarray(ln.get_ydata(), float) for ln in ax.get_lines()]


@pytest.fixture(scope="module")
def solved(tmp_path_factory: pytest.TempPathFactory):  # type: ignore[no-untyped-def]
    """One analysis with plots: a bad channel and a bad input, the figures captured as drawn."""
    c = forward_case(0, triax_error_deg=0.5, n_bad_channels=1, bad_channel_deg=20, n_bad_inputs=1)
    drawn: dict[str, Figure] = {}
    save = figures.save_figure

    def capture(fig: Figure, directory: Path, stem: str) -> list[Path]:
        drawn[stem] = fig
        return save(fig, directory, stem)

    mp = pytest.MonkeyPatch()
    mp.setattr(figures, "save_figure", capture)
    out = tmp_path_factory.mktemp("plots")
    try:
        rep = analyse(c.frf, c.nominal, AnalysisOptions(plots_dir=out, band_hz=(50.0, 150.0)))
    finally:
        mp.undo()
    return c, rep, drawn, out


@pytest.mark.slow
def test_report_figures_written(solved) -> None:  # type: ignore[no-untyped-def]
    _c, rep, drawn, out = solved
    stems = {"parameters_vs_frequency", "cmif", "response_errors", "jackknife"}
    assert set(drawn) == stems
    assert sorted(p.name for p in rep.plots) == sorted(
        f"{s}.{e}" for s in stems for e in ("png", "svg")
    )
    for s in stems:
        assert (out / f"{s}.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
        assert "<svg" in (out / f"{s}.svg").read_text()[:2000]


def test_parameters_figure_shows_the_solution(solved) -> None:  # type: ignore[no-untyped-def]
    _c, rep, drawn, _ = solved
    fig = drawn["parameters_vs_frequency"]
    axes = fig.axes
    assert len(axes) == 10
    r = rep.result
    for i, ax in enumerate(axes):
        row, col = divmod(i, 2)
        k = 5 * col + row  # 5 × 2 panels, parameters down the first column then the second
        curve, headline = ax.get_lines()
        f = np.asarray(curve.get_xdata(), float)
        inband = (f >= r.band_hz[0]) & (f <= r.band_hz[1])
        # the per-line estimates drawn in the band are the solution's own per-line estimates
        np.testing.assert_allclose(f[inband], r.frequencies_hz)
        np.testing.assert_allclose(
            np.asarray(curve.get_ydata(), float)[inband], r.per_line[:, k], rtol=1e-9, atol=1e-12
        )
        assert np.asarray(headline.get_ydata(), float)[0] == pytest.approx(r.parameters[k])
        assert ax.get_ylabel().startswith(f"{PARAMETERS[k]} [")
        x0, x1 = ax.patches[0].get_bbox().x0, ax.patches[0].get_bbox().x1  # the band, shaded
        assert (x0, x1) == pytest.approx(r.band_hz)


def test_cmif_and_selection_figures_show_the_selection(solved) -> None:  # type: ignore[no-untyped-def]
    c, rep, drawn, _ = solved
    # CMIF: the largest singular value of the kept data, per line
    geo_out = c.frf.output_index("acceleration")
    bad_ch = {(e["node"], e["direction"]) for e in rep.excluded_responses}
    bad_in = {(e["node"], e["direction"]) for e in rep.excluded_inputs}
    keep_o = [
        i for i in geo_out if (c.frf.outputs[i].node, c.frf.outputs[i].direction) not in bad_ch
    ]
    keep_i = [j for j, ch in enumerate(c.frf.inputs) if (ch.node, ch.direction) not in bad_in]
    sv = np.linalg.svd(c.frf.H[:, keep_o][:, :, keep_i], compute_uv=False)
    curves = _line_data(drawn["cmif"].axes[0])
    np.testing.assert_allclose(curves[0], sv[:, 0], rtol=1e-10)
    assert len(curves) == sv.shape[1]
    # response errors: final bars are the final leave-one-out errors, red exactly where excluded
    rs = rep.response_selection
    ax1 = drawn["response_errors"].axes[0]
    n = len(rs.channels)
    final = ax1.patches[n : 2 * n]
    np.testing.assert_allclose(
        [p.get_height() for p in final], rs.final.loo_band, rtol=1e-12, equal_nan=True
    )
    red = {i for i, p in enumerate(final) if p.get_facecolor()[0] > 0.8 > p.get_facecolor()[2]}
    assert red == {i for i, k in enumerate(rs.keep) if not k}
    assert {(rs.channels[i].node, rs.channels[i].direction) for i in red} == set(c.bad_channels)
    # jackknife: the decision statistic per input, the removed input marked above its threshold
    js = rep.input_selection
    ax0 = drawn["jackknife"].axes[0]
    cyc0 = js.cycles[0]
    lines = ax0.get_lines()
    np.testing.assert_allclose(np.asarray(lines[0].get_ydata(), float), cyc0.statistic)
    thr = [ln for ln in lines if ln.get_linestyle() == ":"]
    assert np.asarray(thr[0].get_ydata(), float)[0] == pytest.approx(cyc0.threshold)
    mark = next(ln for ln in lines if ln.get_marker() == "x")
    assert int(np.asarray(mark.get_xdata())[0]) == cyc0.removed
    assert (js.inputs[cyc0.removed].node, js.inputs[cyc0.removed].direction) in set(c.bad_inputs)
    assert cyc0.statistic[cyc0.removed] > cyc0.threshold


@pytest.mark.slow
def test_sensitivity_histograms_count_the_samples(tmp_path: Path) -> None:
    res = cube_study(0.01, max_angle_deg=1.0, n_trials=50, seed=0)
    fig = figures.figure_sensitivity(res.samples, res.truth)
    for k, ax in enumerate(fig.axes):
        heights = [p.get_height() for p in ax.patches]
        assert sum(heights) == np.isfinite(res.samples[:, k]).sum() == 50
        assert np.asarray(ax.get_lines()[0].get_xdata(), float)[0] == pytest.approx(res.truth[k])
    paths = figures.plot_sensitivity(res.samples, res.truth, tmp_path)
    assert [p.suffix for p in paths] == [".png", ".svg"]
