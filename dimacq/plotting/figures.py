"""Figure functions: ``figure_*`` builds a figure and returns it (what tests inspect), ``plot_*``
writes it and returns the paths written (``<stem>.png`` and ``<stem>.svg``).

Uses matplotlib's object API on a :class:`~matplotlib.figure.Figure` with an Agg canvas (no
pyplot state, no GUI, thread safe).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Protocol

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from numpy.typing import NDArray

from dimacq.errors import SetupError
from dimacq.model.setup import PARAMETERS

if TYPE_CHECKING:
    from dimacq.model.frf import FrfData
    from dimacq.model.setup import TestSetup
    from dimacq.pipeline.dim import DimResult
    from dimacq.pipeline.selection.inputs import JackknifeSelection
    from dimacq.pipeline.selection.responses import ResponseSelection

__all__ = [
    "figure_cmif",
    "figure_jackknife",
    "figure_parameters_vs_frequency",
    "figure_response_errors",
    "figure_sensitivity",
    "parameters_vs_frequency_figure",
    "plot_cmif",
    "plot_jackknife",
    "plot_parameters_vs_frequency",
    "plot_response_errors",
    "plot_sensitivity",
    "save_figure",
    "write_report_figures",
]

_UNITS = ("kg", "m", "m", "m") + ("kg m²",) * 6


class ReportLike(Protocol):
    """What :func:`write_report_figures` reads of an analysis report (the services' report
    satisfies it; plotting sits below the services and does not import them)."""

    @property
    def result(self) -> DimResult: ...

    @property
    def response_selection(self) -> ResponseSelection | None: ...

    @property
    def input_selection(self) -> JackknifeSelection | None: ...


def _fig(w: float, h: float) -> Figure:
    fig = Figure(figsize=(w, h), layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def save_figure(fig: Figure, directory: Path, stem: str) -> list[Path]:
    """Write ``fig`` as ``directory/stem.png`` and ``.svg``; create the directory if needed."""
    directory = Path(directory)
    try:
        directory.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise SetupError(
            f"cannot create the plots directory {directory}: {err}; give a writable path"
        ) from err
    out = []
    for ext in ("png", "svg"):
        p = directory / f"{stem}.{ext}"
        fig.savefig(p, dpi=110)
        out.append(p)
    return out


def figure_parameters_vs_frequency(
    frequencies_hz: NDArray[np.floating],
    per_line: NDArray[np.floating],
    band_hz: tuple[float, float] | None,
    *,
    headline: NDArray[np.floating] | None = None,
) -> Figure:
    """Ten panels: per-line estimates against frequency, the band shaded, the headline dashed.

    Parameters
    ----------
    frequencies_hz : (n_lines,)
    per_line : (n_lines, 10)
        ``[m, cx, cy, cz, Ixx..Izz]``.
    band_hz : (lo, hi), optional
    headline : (10,), optional
    """
    f = np.asarray(frequencies_hz, float)
    pl = np.asarray(per_line, float)
    fig = _fig(11, 9)
    axes = fig.subplots(5, 2, sharex=True)
    for k, ax in enumerate(axes.T.ravel()):
        ax.plot(f, pl[:, k], lw=0.9)
        if band_hz is not None:
            ax.axvspan(band_hz[0], band_hz[1], color="tab:green", alpha=0.15, lw=0)
            sel = (f >= band_hz[0]) & (f <= band_hz[1]) & np.isfinite(pl[:, k])
            if sel.any():
                lo, hi = np.percentile(pl[sel, k], [1, 99])
                pad = 3 * (hi - lo) + 1e-12 * max(1.0, abs(hi))
                ax.set_ylim(lo - pad, hi + pad)
        if headline is not None:
            ax.axhline(float(headline[k]), color="k", ls="--", lw=0.8)
        ax.set_ylabel(f"{PARAMETERS[k]} [{_UNITS[k]}]")
    for ax in axes[-1]:
        ax.set_xlabel("frequency [Hz]")
    fig.suptitle("DIM estimates per line (band shaded)")
    return fig


#: The name :mod:`dimacq.services.lab.solving` uses.
parameters_vs_frequency_figure = figure_parameters_vs_frequency


def plot_parameters_vs_frequency(
    frequencies_hz: NDArray[np.floating],
    per_line: NDArray[np.floating],
    band_hz: tuple[float, float] | None,
    directory: Path,
    *,
    headline: NDArray[np.floating] | None = None,
    stem: str = "parameters_vs_frequency",
) -> list[Path]:
    """Ten panels: per-line estimates against frequency, the band shaded, the headline dashed. Written as ``directory/stem.png`` and ``.svg`` (:func:`figure_parameters_vs_frequency`)."""
    return save_figure(
        figure_parameters_vs_frequency(frequencies_hz, per_line, band_hz, headline=headline),
        directory,
        stem,
    )


def figure_response_errors(
    selection: ResponseSelection,
    frequencies_hz: NDArray[np.floating],
) -> Figure:
    """Rigid-body error per channel: band bars (initial and final, excluded in red) and per line."""
    names = [c.name for c in selection.channels]
    x = np.arange(len(names))
    fig = _fig(12, 7)
    ax1, ax2 = fig.subplots(2, 1)
    e0 = np.where(np.isfinite(selection.initial.loo_band), selection.initial.loo_band, np.nan)
    e1 = np.where(np.isfinite(selection.final.loo_band), selection.final.loo_band, np.nan)
    colors = ["tab:red" if not k else "tab:blue" for k in selection.keep]
    ax1.bar(x - 0.2, e0, width=0.4, color="0.7", label="all channels")
    ax1.bar(x + 0.2, e1, width=0.4, color=colors, label="after selection (red: excluded)")
    ax1.set_yscale("log")
    ax1.set_xticks(x, names, rotation=90, fontsize=7)
    ax1.set_ylabel("rigid-body error (leave-one-out)")
    ax1.legend(fontsize=8)
    f = np.asarray(frequencies_hz, float)
    for i in range(len(names)):
        ax2.semilogy(
            f,
            selection.final.loo_per_line[:, i],
            lw=1.4 if not selection.keep[i] else 0.6,
            color="tab:red" if not selection.keep[i] else "0.5",
        )
    ax2.set_xlabel("frequency [Hz]")
    ax2.set_ylabel("rigid-body error per line")
    fig.suptitle("Perimeter response selection (Eq. 30–31)")
    return fig


def plot_response_errors(
    selection: ResponseSelection,
    frequencies_hz: NDArray[np.floating],
    directory: Path,
    *,
    stem: str = "response_errors",
) -> list[Path]:
    """Rigid-body error per channel: band bars (initial and final, excluded in red) and per line. Written as ``directory/stem.png`` and ``.svg`` (:func:`figure_response_errors`)."""
    return save_figure(figure_response_errors(selection, frequencies_hz), directory, stem)


def figure_jackknife(selection: JackknifeSelection) -> Figure:
    """Per cycle: the studentised predictive residual of every input with the removal threshold
    (what decides a removal), the scaled-deviation sums (thesis Fig. 11), and the jackknife
    standard-deviation history (thesis Fig. 12)."""
    cyc = selection.cycles
    names = [c.name for c in selection.inputs]
    fig = _fig(12, 11)
    ax0, ax1, ax2 = fig.subplots(3, 1)
    x = np.arange(len(names))
    for k, c in enumerate(cyc[: min(len(cyc), 6)]):
        stat = c.statistic if c.statistic is not None else c.residual
        (ln,) = ax0.semilogy(x, stat, marker="o", ms=3, lw=0.8, label=f"cycle {k + 1}")
        if np.isfinite(c.threshold):
            ax0.axhline(c.threshold, color=ln.get_color(), ls=":", lw=0.8)
        ax1.plot(x, c.score, marker="o", ms=3, lw=0.8, label=f"cycle {k + 1}")
        if c.removed is not None:
            ax0.plot([c.removed], [stat[c.removed]], "kx" if c.justified else "k+", ms=8)
            ax1.plot([c.removed], [c.score[c.removed]], "kx", ms=8)
    ax0.set_xticks(x, names, rotation=90, fontsize=7)
    ax0.set_ylabel("studentised predictive residual")
    ax0.set_title("dotted: removal threshold; x: removed, +: candidate kept", fontsize=8)
    ax0.legend(fontsize=7, ncol=3)
    ax1.set_xticks(x, names, rotation=90, fontsize=7)
    ax1.set_ylabel("scaled-deviation sum")
    ax1.legend(fontsize=7, ncol=3)
    std = selection.std_history
    if std.size:
        rel = std / np.where(std[:1] > 0, std[:1], 1.0)
        for k in range(10):
            ax2.semilogy(
                np.arange(1, len(cyc) + 1), rel[:, k], marker="o", ms=3, label=PARAMETERS[k]
            )
        ax2.axvline(selection.chosen_cycle + 1, color="k", ls="--", lw=0.8)
    ax2.set_xlabel("jackknife cycle (dashed: chosen)")
    ax2.set_ylabel("jackknife std / cycle 1")
    ax2.legend(fontsize=7, ncol=5)
    fig.suptitle("Jackknife excitation selection")
    return fig


def plot_jackknife(
    selection: JackknifeSelection, directory: Path, *, stem: str = "jackknife"
) -> list[Path]:
    """Scaled-deviation sums per cycle and the jackknife standard-deviation history. Written as ``directory/stem.png`` and ``.svg`` (:func:`figure_jackknife`)."""
    return save_figure(figure_jackknife(selection), directory, stem)


def figure_cmif(
    frequencies_hz: NDArray[np.floating],
    cmif_values: NDArray[np.floating],
    *,
    band_hz: tuple[float, float] | None = None,
) -> Figure:
    """CMIF curves (log scale) with the band shaded."""
    fig = _fig(9, 5)
    ax = fig.subplots()
    ax.semilogy(np.asarray(frequencies_hz), np.asarray(cmif_values), lw=0.8)
    if band_hz is not None:
        ax.axvspan(band_hz[0], band_hz[1], color="tab:green", alpha=0.15, lw=0)
    ax.set_xlabel("frequency [Hz]")
    ax.set_ylabel("singular value [(m/s²)/N]")
    ax.set_title("CMIF")
    return fig


def plot_cmif(
    frequencies_hz: NDArray[np.floating],
    cmif_values: NDArray[np.floating],
    directory: Path,
    *,
    band_hz: tuple[float, float] | None = None,
    stem: str = "cmif",
) -> list[Path]:
    """CMIF curves (log scale) with the band shaded. Written as ``directory/stem.png`` and ``.svg`` (:func:`figure_cmif`)."""
    return save_figure(figure_cmif(frequencies_hz, cmif_values, band_hz=band_hz), directory, stem)


def figure_modal_correction(
    frequencies_hz: NDArray[np.floating],
    size: NDArray[np.floating],
    poles_hz: list[tuple[float, bool]],
    *,
    band_hz: tuple[float, float] | None = None,
) -> Figure:
    """The modal correction's size per line (‖correction‖ / ‖H‖ of the kept accelerances, %),
    the band shaded, each pole marked (solid: elastic, taken out; dotted: left in)."""
    fig = _fig(9, 4)
    ax = fig.subplots()
    ax.semilogy(np.asarray(frequencies_hz), 100 * np.asarray(size), lw=0.9)
    if band_hz is not None:
        ax.axvspan(band_hz[0], band_hz[1], color="tab:green", alpha=0.15, lw=0)
    for f, elastic in poles_hz:
        ax.axvline(f, color="tab:red" if elastic else "grey", ls="-" if elastic else ":", lw=0.8)
    ax.set_xlabel("frequency [Hz]")
    ax.set_ylabel("correction / accelerance [%]")
    ax.set_title("modal correction (red: elastic modes taken out)")
    return fig


def figure_sensitivity(
    samples: NDArray[np.floating],
    truth: Sequence[float] | NDArray[np.floating],
    *,
    title: str = "",
) -> Figure:
    """Histograms of Monte Carlo estimates, shape (n_trials, 10), with the true values."""
    s = np.asarray(samples, float)
    fig = _fig(12, 7)
    axes = fig.subplots(2, 5)
    for k, ax in enumerate(axes.ravel()):
        col = s[:, k][np.isfinite(s[:, k])]
        if col.size:
            ax.hist(col, bins=30, color="tab:blue", alpha=0.8)
        ax.axvline(float(truth[k]), color="k", ls="--", lw=0.9)
        ax.set_title(f"{PARAMETERS[k]} [{_UNITS[k]}]", fontsize=9)
        ax.tick_params(labelsize=7)
    fig.suptitle(title or "Monte Carlo sensitivity")
    return fig


def plot_sensitivity(
    samples: NDArray[np.floating],
    truth: Sequence[float] | NDArray[np.floating],
    directory: Path,
    *,
    title: str = "",
    stem: str = "sensitivity",
) -> list[Path]:
    """Histograms of Monte Carlo estimates, shape (n_trials, 10), with the true values. Written as ``directory/stem.png`` and ``.svg`` (:func:`figure_sensitivity`)."""
    return save_figure(figure_sensitivity(samples, truth, title=title), directory, stem)


def write_report_figures(
    report: ReportLike,
    frf: FrfData,
    setup: TestSetup,
    directory: Path,
    response_weights: NDArray[np.floating],
    input_keep: NDArray[np.bool_],
) -> list[Path]:
    """All figures that apply to an analysis report (per-line over the whole span, CMIF, and the
    selection figures when the selections ran)."""
    from dimacq.pipeline.dim import assemble, solve_system
    from dimacq.pipeline.selection.band import cmif

    paths: list[Path] = []
    band = report.result.band_hz
    system = assemble(frf, setup, response_weights=response_weights).select_inputs(
        np.nonzero(input_keep)[0]
    )
    res = solve_system(system, known=report.result.known, check_plausibility=False)
    f_all, per_line = frf.frequencies_hz, res.per_line
    acc = frf.output_index("acceleration")
    sv = cmif(frf.H[:, acc[np.asarray(response_weights) > 0], :][:, :, np.asarray(input_keep)])
    paths += plot_parameters_vs_frequency(
        f_all, per_line, band, directory, headline=report.result.parameters
    )
    paths += plot_cmif(f_all, sv, directory, band_hz=band)
    if report.response_selection is not None:
        rs = report.response_selection
        f_sel = rs.frequencies_hz if rs.frequencies_hz is not None else report.result.frequencies_hz
        paths += plot_response_errors(rs, f_sel, directory)
    if report.input_selection is not None:
        paths += plot_jackknife(report.input_selection, directory)
    return paths
