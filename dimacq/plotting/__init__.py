"""Figures of the DIM analysis (matplotlib, Agg backend, each written as PNG and SVG).

- :func:`plot_parameters_vs_frequency` — per-line estimates with the band (thesis Fig. 25)
- :func:`plot_response_errors` — rigid-body error per channel (thesis Figs. 21–22)
- :func:`plot_jackknife` — jackknife cycles: studentised predictive residuals with the
  removal threshold, scaled deviations and standard-deviation history
  (thesis Figs. 11–12, 23–24)
- :func:`plot_cmif` — CMIF with the band (thesis Fig. 37)
- :func:`plot_sensitivity` — histograms of a Monte Carlo sensitivity study (thesis Fig. 7)
- :func:`write_report_figures` — all that apply to an analysis report

Each ``plot_*`` has a ``figure_*`` twin that returns the :class:`~matplotlib.figure.Figure`
instead of writing it.
"""

from __future__ import annotations

from dimacq.plotting.figures import (
    figure_cmif,
    figure_jackknife,
    figure_parameters_vs_frequency,
    figure_response_errors,
    figure_sensitivity,
    plot_cmif,
    plot_jackknife,
    plot_parameters_vs_frequency,
    plot_response_errors,
    plot_sensitivity,
    save_figure,
    write_report_figures,
)

__all__ = [
    "figure_cmif",
    "figure_jackknife",
    "figure_parameters_vs_frequency",
    "figure_response_errors",
    "figure_sensitivity",
    "plot_cmif",
    "plot_jackknife",
    "plot_parameters_vs_frequency",
    "plot_response_errors",
    "plot_sensitivity",
    "save_figure",
    "write_report_figures",
]
