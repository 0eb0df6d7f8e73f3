"""A stream on its own clock put on the DAQ's sample grid: the host clock as the common time
base, a lower-envelope clock fit, band-limited (4-point Lagrange) resampling, and the FRF phase
that the alignment's uncertainty costs.

Used for a sensor with no sync input that streams numbered samples (an ATI Net F/T's RDT:
``ft_sequence`` counts its own samples). Three clocks meet on the host's monotonic clock ``t``
(wall seconds):

- the **sensor** samples at its own instants ``s_j = s_0 + j / f_s`` (sensor seconds, ``f_s`` its
  configured output rate); its datagrams reach the host after a latency ``d ≥ d_min ≥ 0``, so
  each datagram's arrival bounds its last record's instant from above:
  ``t_arr = A + B s + d``, with ``B`` the host seconds per sensor second (``1/time_scale`` for a
  time-lapse simulation, ``1 ± ppm`` for a real crystal). The **lower envelope** of the
  arrivals, one minimum per window of ``window_s``, is fitted by a line
  (:func:`fit_lower_envelope`): the windows' minima are the datagrams that waited least, and
  their scatter about the line is what the fit cannot tell apart from latency;
- the **DAQ** clocks sample ``k`` at ``t = T0 + k / (f_d · time_scale)``; ``T0`` lies in the
  window the host measured around the request that started its clock (``t_a ≤ T0 ≤ t_b``, its
  midpoint taken, half its width an uncertainty);
- so sensor record ``j`` sits at DAQ sample position ``x_j = (A + B s_j − T0) f_d time_scale``
  — a line in ``j`` — and the DAQ's samples ``k`` are interpolated from the records around
  ``u = (k − x_0) / (x_1 − x_0)`` (:func:`lagrange4`; a record missing there makes the sample
  NaN: a lost datagram is a gap, never bridged).

Alignment error costs phase: a time error ``δ`` multiplies the sensor's FRFs by
``exp(−i 2π f δ)``, a phase error ``φ = 360° f δ`` (:func:`phase_error_deg`) and a relative
error ``|1 − e^{−iφ}| ≈ 2π f δ`` of the load cell's force at frequency ``f`` — 0.1 ms is 3.6°
(6 %) at 100 Hz. The budget here is ``δ = (t_b − t_a)/2 + scatter + d_min`` (``d_min`` the
latency floor, unknown to the host: it biases every sample the same way and is stated, not
estimated); a caller refuses when ``φ`` at the band's top frequency exceeds its limit.
Clock drift between the DAQ and the host is not modelled (the DAQ's crystal against the host's:
~20 ppm is 1.2 ms after a minute): it is the budget's ``daq_ppm`` term.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

__all__ = ["ClockFit", "fit_lower_envelope", "lagrange4", "phase_error_deg"]


@dataclass(frozen=True)
class ClockFit:
    """``t = offset_s + slope · s``: host (wall) seconds of sensor time ``s``.

    Attributes
    ----------
    offset_s : float
        Host time of sensor time 0, s.
    slope : float
        Host seconds per sensor second.
    scatter_s : float
        Robust scatter (1.4826 × MAD) of the windows' minima about the line, s.
    n_windows : int
        Windows that entered the fit (1: offset only, ``slope`` as given).
    """

    offset_s: float
    slope: float
    scatter_s: float
    n_windows: int


def fit_lower_envelope(
    sensor_s: NDArray[np.float64],
    host_s: NDArray[np.float64],
    *,
    nominal_slope: float,
    window_s: float,
    max_ppm: float = 200.0,
    min_windows: int = 8,
) -> ClockFit:
    """The line under the arrivals: one minimum of ``host_s − nominal_slope · sensor_s`` per
    window of ``window_s`` host seconds, a least-squares line through them (windows more than
    3 scatters above it dropped), its slope within the crystal's tolerance; the lowest point
    with ``nominal_slope`` while fewer than ``min_windows`` windows are in.

    Parameters
    ----------
    sensor_s : ndarray, shape (n,)
        Sensor time of each datagram's last record, s.
    host_s : ndarray, shape (n,)
        Its arrival on the host's monotonic clock, s.
    nominal_slope : float
        Host seconds per sensor second as configured (1 / time scale).
    window_s : float
    max_ppm : float
        The slope is kept within ``nominal_slope × (1 ± max_ppm 10⁻⁶)`` (a crystal's
        tolerance): over a short run the scatter would tilt the line more than any clock does;
        the offset is then the median of the windows' minima about that slope.
    """
    s = np.asarray(sensor_s, dtype=float)
    t = np.asarray(host_s, dtype=float)
    if s.size == 0:
        raise ValueError("fit_lower_envelope: no arrivals")
    o = t - nominal_slope * s
    w = np.floor((t - t[0]) / window_s).astype(np.int64)
    order = np.lexsort((o, w))
    first = np.ones(order.size, dtype=bool)
    first[1:] = w[order][1:] != w[order][:-1]
    idx = order[first]  # the lowest offset of each window
    if idx.size < min_windows:  # too short a span to tell a slope from the scatter
        oo = o[idx]
        scatter = 1.4826 * float(np.median(np.abs(oo - np.median(oo)))) if idx.size > 2 else 0.0
        return ClockFit(float(oo.min()), nominal_slope, scatter, int(idx.size))
    ss, oo = s[idx], o[idx]
    keep = np.ones(idx.size, dtype=bool)
    for _ in range(2):
        c1, c0 = np.polyfit(ss[keep] - ss[0], oo[keep], 1)
        r = oo - (c0 + c1 * (ss - ss[0]))
        mad = 1.4826 * float(np.median(np.abs(r[keep] - np.median(r[keep]))))
        keep = r <= 3.0 * max(mad, 1e-9)
        if keep.sum() < 3:
            keep[:] = True
            break
    c1, _ = np.polyfit(ss[keep] - ss[0], oo[keep], 1)
    # a crystal is within max_ppm: a slope beyond is the scatter's, not the clock's
    lim = max_ppm * 1e-6 * nominal_slope
    c1 = float(np.clip(c1, -lim, lim))
    c0 = float(np.median(oo[keep] - c1 * ss[keep]))
    r = oo[keep] - (c0 + c1 * ss[keep])
    scatter = 1.4826 * float(np.median(np.abs(r - np.median(r))))
    return ClockFit(float(c0), float(nominal_slope + c1), scatter, int(keep.sum()))


def lagrange4(y: NDArray[np.float64], u: NDArray[np.float64]) -> NDArray[np.float64]:
    """Values at fractional indices ``u`` of samples ``y`` on a uniform grid: the cubic through
    the four samples ``i − 1 .. i + 2`` (``i = ⌊u⌋``); NaN where one of them is outside ``y`` or
    NaN.

    With ``p = u − i`` the weights are the Lagrange basis on nodes −1, 0, 1, 2:
    ``−p(p−1)(p−2)/6, (p+1)(p−1)(p−2)/2, −(p+1)p(p−2)/2, (p+1)p(p−1)/6``; a sinusoid of ``ν``
    cycles per sample is reproduced to ``O((2πν)^4)`` (1e-4 at ν = 0.03).

    Parameters
    ----------
    y : ndarray, shape (n, m)
        ``n`` samples of ``m`` channels.
    u : ndarray, shape (k,)

    Returns
    -------
    ndarray, shape (k, m)
    """
    y = np.asarray(y, dtype=float)
    u = np.asarray(u, dtype=float)
    i = np.floor(u).astype(np.int64)
    p = (u - i)[:, None]
    ok = (i >= 1) & (i + 2 < y.shape[0])
    ic = np.clip(i, 1, max(1, y.shape[0] - 3))
    w = (
        -p * (p - 1) * (p - 2) / 6,
        (p + 1) * (p - 1) * (p - 2) / 2,
        -(p + 1) * p * (p - 2) / 2,
        (p + 1) * p * (p - 1) / 6,
    )
    if y.shape[0] < 4:
        return np.full((u.size, y.shape[1]), np.nan)
    out = w[0] * y[ic - 1] + w[1] * y[ic] + w[2] * y[ic + 1] + w[3] * y[ic + 2]
    out[~ok] = np.nan
    return out


def phase_error_deg(delay_s: float, frequency_hz: float) -> float:
    """``360 f δ``: the FRF phase error, degrees, of a time error ``δ`` s at ``f`` Hz."""
    return 360.0 * frequency_hz * abs(delay_s)
