"""What a plot or a report shows of an FRF set, without the set: magnitude envelopes and mean
coherences.

A plot `w` pixels wide cannot show more than `w` lines per channel pair, and a report's data
quality table needs one mean coherence per pair; sending every line (complex H and coherence,
(n_lines, n_responses, n_inputs)) to draw those costs the service and the browser seconds for a
large set. :func:`magnitude_envelope` reduces the set on the service.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

__all__ = ["MagnitudeEnvelope", "magnitude_envelope"]


@dataclass(frozen=True)
class MagnitudeEnvelope:
    """The envelope of |H| over groups of consecutive lines.

    Attributes
    ----------
    frequencies_hz : (n_points,) float
        Centre of each group's frequency range, Hz.
    f_lo_hz, f_hi_hz : (n_points,) float
        First and last line of each group, Hz.
    magnitude_max, magnitude_min : (n_points, n_responses, n_inputs) float
        Largest and smallest |H| in the group (units of H).
    coherence_mean : (n_responses, n_inputs) float or None
        Mean coherence over every line given (NaN lines left out; NaN where no line has one);
        None when the set has no coherence.
    lines_per_point : int
        The largest group's number of lines.
    """

    frequencies_hz: NDArray[np.float64]
    f_lo_hz: NDArray[np.float64]
    f_hi_hz: NDArray[np.float64]
    magnitude_max: NDArray[np.float64]
    magnitude_min: NDArray[np.float64]
    coherence_mean: NDArray[np.float64] | None
    lines_per_point: int


def magnitude_envelope(
    frequencies_hz: NDArray[np.float64],
    h: NDArray[np.complex128],
    coherence: NDArray[np.float64] | None,
    points: int,
) -> MagnitudeEnvelope:
    """Split the lines into ``min(points, n_lines)`` groups of consecutive lines (sizes differ by
    at most one) and give each group's max and min |H| per channel pair; with the mean coherence
    of each pair over all lines.

    For group g holding lines l ∈ [s_g, e_g):

        max_g = max_l |H_l|,  min_g = min_l |H_l|,  f_g = (f_{s_g} + f_{e_g − 1}) / 2

    and  γ̄² = Σ_l γ²_l [γ²_l finite] / Σ_l [γ²_l finite]  over all lines (NaN when the count is 0).
    The max keeps every resonance peak a plot of all lines would show (to within one group's
    width in frequency); the min keeps the antiresonances.

    Parameters
    ----------
    frequencies_hz : (n_lines,) float
        Line frequencies, Hz, increasing.
    h : (n_lines, n_responses, n_inputs) complex
        FRFs.
    coherence : (n_lines, n_responses, n_inputs) float or None
        Multiple coherence (NaN where undefined), or None.
    points : int
        Most groups wanted, ≥ 1.

    Returns
    -------
    MagnitudeEnvelope
    """
    if points < 1:
        raise ValueError(f"points {points}: give at least 1")
    f = np.asarray(frequencies_hz, dtype=float)
    n = f.size
    if h.shape[0] != n:
        raise ValueError(f"H has {h.shape[0]} lines, frequencies_hz {n}")
    if n == 0:
        empty = np.zeros((0, *h.shape[1:]))
        return MagnitudeEnvelope(f, f, f, empty, empty, None, 0)
    groups = min(points, n)
    edges = np.rint(np.linspace(0, n, groups + 1)).astype(np.intp)
    starts, ends = edges[:-1], edges[1:]
    mag = np.abs(h)
    mean: NDArray[np.float64] | None = None
    if coherence is not None:
        ok = np.isfinite(coherence)
        count = ok.sum(axis=0)
        total = np.where(ok, coherence, 0.0).sum(axis=0)
        mean = np.full(count.shape, np.nan)
        np.divide(total, count, out=mean, where=count > 0)
    return MagnitudeEnvelope(
        frequencies_hz=0.5 * (f[starts] + f[ends - 1]),
        f_lo_hz=f[starts],
        f_hi_hz=f[ends - 1],
        magnitude_max=np.maximum.reduceat(mag, starts, axis=0),
        magnitude_min=np.minimum.reduceat(mag, starts, axis=0),
        coherence_mean=mean,
        lines_per_point=int((ends - starts).max()),
    )
