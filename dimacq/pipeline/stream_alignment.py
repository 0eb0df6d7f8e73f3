"""A stream on its own clock put on the DAQ's sample grid: the host clock as the coarse time
base (a lower-envelope clock fit, band-limited 4-point Lagrange resampling), the residual delay
estimated from the data, and the FRF phase that the alignment's uncertainty costs.

Used for a sensor with no sync input that streams numbered samples (an ATI Net F/T's RDT:
``ft_sequence`` counts its own samples). Three clocks meet on the host's monotonic clock ``t``
(wall seconds):

- the **sensor** samples at its own instants ``s_j = s_0 + j / f_s`` (sensor seconds, ``f_s`` its
  configured output rate); its datagrams reach the host after a latency ``d ≥ d_min ≥ 0``, so
  each datagram's arrival bounds its last record's instant from above:
  ``t_arr = A + B s + d``, with ``B`` the host seconds per sensor second (``1/time_scale`` for a
  time-lapse simulation, ``1 ± ppm`` for a real crystal). The **lower envelope** of the
  arrivals, one minimum per window of ``window_s``, gives the line: the highest line under
  all the minima (:func:`fit_lower_envelope`, a linear programme: it rests on the datagrams
  that waited least, where a least-squares line through the minima moved with every busy
  window; a window held in a queue, more than ``BURST_S`` above it, bounds it without pulling
  it); the minima's scatter above it is what the fit cannot tell apart from latency;
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
(6 %) at 100 Hz. Through the host's clock the budget is ``δ = (t_b − t_a)/2 + scatter + d_min``
(``d_min`` the latency floor, unknown to the host: it biases every sample the same way and is
stated, not estimated); on this project's 2-core machine that is ~100 µs of wall time, 36° at
1 kHz: the host's clock is a **coarse** time base only.

**The residual delay from the data** (:func:`fit_delay`). The hammer's force and the
accelerometers are on the DAQ's clock, the cell's loads on the sensor's; what is left after the
coarse alignment is a delay ``τ`` (constant over one input's averages: the sensor's rate is the
envelope's) that multiplies every cell FRF ``W_m = load m / hammer force`` by ``e^{−iωτ}``. The
physics DIM itself assumes says what ``W`` is without it: the article is rigid in the band and
every force on it other than the hammer's goes through the cells, so Newton–Euler about the
origin, ``M A_O = Φ_j F + Σ_s G_sᵀ B_s W_s``, makes each cell load a **real** linear
combination of the rigid body's accelerations — themselves real combinations of the
accelerometers' FRFs ``A_k`` — and of the hammer's own (real, per unit force) term. Per input::

    W_m(f) e^{iωτ} = Σ_k c_mk A_k(f) + d_m,        c_mk, d_m real                 (1)

whatever the supports (bungee, air springs, bolted through the cells): their stiffness,
damping, resonances and the suspension's swing are in ``A`` and ``W`` alike. (With no
responses at hand the mass-line asymptote of a rigid body on spring-and-dashpot supports gives
the regressors ``(ω0/iω)^n``, n = 0, 1, 2: :func:`mass_line_basis`, equation (2).) ``τ`` is
fitted by variable projection: for a trial ``τ`` the real coefficients are a weighted least
squares fit (the projection on the regressors' range, which does not depend on ``τ``), the cost
``J(τ)`` the weighted residual left; a grid over ``±search_s`` in steps of ``0.05 / f_max`` (no
phase wrap between steps) brackets the minimum, a golden-section search refines it. Its
statistical uncertainty is ``σ_τ² = 2 s² / J''(τ̂)`` (``s²`` the residual variance per degree of
freedom: noise and misfit alike), and ``spread`` is half the difference of the estimates on the
lower and upper half of the lines (each refining the whole band's within ``±20 σ_τ``; a half
whose minimum is at that window's edge counts as that far off) — where (1) does not hold (an
elastic mode, a cell whose loads are lost in noise) the halves disagree.
``uncertainty = √(σ_τ² + spread²)`` is what the phase budget is checked against: a run is
refused when ``360° f_band · uncertainty`` exceeds its limit.

How much the data say depends on how much the cell carries: ``τ`` moves ``W`` by ``ωτ |W|``.
Bolted through its cell (``calibration-mass-ground``) the cell carries the hammer's force and
1 % noise leaves ``σ_τ`` ~0.1 µs; hung on a bungee the cell carries ~0.1 % of it above the
suspension, the suspension's swing and the noise dominate its FRFs, and an input's fit is no
better than ~0.1–1 ms (refused at 2° at 655 Hz). The same ratio makes the cell's share of the
result small there (a 1 % cell error moves the bungee's DIM mass by ~0.001 %), but the budget
is the phase's, as set: a run whose data cannot support it is refused, not assumed.

**One delay for several inputs** (:func:`fit_pooled_delay`): the clocks' delay is one per run
while each input's fit carries its own bias (a cell that carries little of the force), so the
inputs' costs are summed, each scaled by its own residual variance, and the shared ``τ`` is
fitted with its standard error from the jackknife over inputs and its drift between the run's
halves.

Clock drift between the DAQ and the host is not modelled by the coarse alignment (the DAQ's
crystal against the host's: ~20 ppm is 1.2 ms after a minute); a run whose inputs' delays
differ by more than the budget is told by the jackknife and the halves, and each input then
keeps its own fit where that meets the budget.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

__all__ = [
    "BURST_S",
    "ClockFit",
    "DelayBudget",
    "DelayFit",
    "PooledDelayFit",
    "fit_delay",
    "fit_lower_envelope",
    "fit_pooled_delay",
    "lagrange4",
    "mass_line_basis",
    "phase_error_deg",
]


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


def _lower_hull(x: NDArray[np.float64], y: NDArray[np.float64]) -> NDArray[np.intp]:
    """Indices of the lower convex hull of the points ``(x, y)``, ``x`` increasing (Andrew's
    monotone chain: each point pops the vertices it sees from below; one pass, sequential by
    nature, over the windows' minima only)."""
    hull: list[int] = []
    for i in range(x.size):
        while len(hull) >= 2:
            a, b = hull[-2], hull[-1]
            if (x[b] - x[a]) * (y[i] - y[a]) - (y[b] - y[a]) * (x[i] - x[a]) > 0:
                break
            hull.pop()
        hull.append(i)
    return np.asarray(hull, dtype=np.intp)


#: a window whose least-waiting datagram lies this far above the clock line was in a queue (the
#: sender or the network held a burst of datagrams back), host s: it bounds the line from above
#: but does not pull it (:func:`fit_lower_envelope`)
BURST_S = 1e-3
#: steps of :func:`fit_lower_envelope`'s iteration at most (it stops within two or three)
_MAX_STEPS = 20


def fit_lower_envelope(
    sensor_s: NDArray[np.float64],
    host_s: NDArray[np.float64],
    *,
    nominal_slope: float,
    window_s: float,
    max_ppm: float = 200.0,
    min_windows: int = 8,
    burst_s: float = BURST_S,
) -> ClockFit:
    """The line under the arrivals: with ``o = host_s − nominal_slope · sensor_s`` and one
    minimum per window of ``window_s`` host seconds, the line ``o = c0 + c1 s`` that lies under
    every minimum and is as high as it can be on average over the windows that were not held
    in a queue::

        minimise  Σ_w min(r_w, burst_s),   r_w = o_w − (c0 + c1 s_w) ≥ 0 for every window w

    Without the cap this is the linear-programming estimate of clock skew of Moon, Skelly &
    Towsley (1999): latency only ever adds (``o_w = c0 + c1 s_w + d_w``, ``d_w ≥ d_min``), so
    the constraint holds for the true line shifted by ``d_min``; the optimum is the edge of the
    minima's lower convex hull over their mean ``s̄`` (the objective is
    ``Σ o_w − n (c0 + c1 s̄)``), and it rests on the datagrams that waited least — it does not
    move with the bulk of the latency, which a least-squares line through the minima does.

    The cap: a burst of datagrams held back (a sender or a switch that falls behind for
    seconds: every window's minimum then lies milliseconds to seconds above the floor) makes
    those windows most of the uncapped objective, whose optimum then moves to the hull edge
    that climbs into the burst — its slope is the queue's growth, clipped at ``max_ppm``, and
    extrapolated to the newest samples it puts them ``max_ppm ×`` the time since the last
    quiet window off (200 ppm over 12.5 s is 2.5 ms). A window above the line by more than
    ``burst_s`` counts ``burst_s`` whatever its height: it still bounds the line, it no longer
    pulls it. The truncated objective is minimised by the iteration that alternates the
    windows held in a queue (``r_w > burst_s``) and the hull edge over the mean ``s̄`` of the
    others (each step lowers the objective; it starts from the uncapped optimum and stops when
    the set repeats).

    The slope is kept within ``nominal_slope × (1 ± max_ppm 10⁻⁶)`` (a crystal's tolerance;
    beyond, the line through the lowest minimum with that slope); the lowest point with
    ``nominal_slope`` while fewer than ``min_windows`` windows are in.

    Parameters
    ----------
    sensor_s : ndarray, shape (n,)
        Sensor time of each datagram's last record, s (increasing).
    host_s : ndarray, shape (n,)
        Its arrival on the host's monotonic clock, s.
    nominal_slope : float
        Host seconds per sensor second as configured (1 / time scale).
    window_s : float
    max_ppm : float
    min_windows : int
    burst_s : float
        Host s above the line beyond which a window's minimum was held in a queue.

    Returns
    -------
    ClockFit
        ``scatter_s``: 1.4826 × the median absolute deviation of the minima's heights above
        the line over the windows not held in a queue (how far a typical window's least
        latency is from the floor).
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
    idx = np.sort(order[first])  # the lowest offset of each window, in time order
    if idx.size < min_windows:  # too short a span to tell a slope from the scatter
        oo = o[idx]
        scatter = 1.4826 * float(np.median(np.abs(oo - np.median(oo)))) if idx.size > 2 else 0.0
        return ClockFit(float(oo.min()), nominal_slope, scatter, int(idx.size))
    x = s[idx] - s[idx[0]]
    y = o[idx]
    hull = _lower_hull(x, y)
    lim = max_ppm * 1e-6 * nominal_slope
    quiet = np.ones(x.size, dtype=bool)
    seen: set[bytes] = set()
    for _ in range(_MAX_STEPS):
        c1 = _hull_slope(x, y, hull, float(x[quiet].mean()), lim)
        c0 = float(np.min(y - c1 * x))  # the line touches the hull (exactly, unless clipped)
        r = y - (c0 + c1 * x)
        held = r > burst_s
        if held.all():  # nothing but queues: the lowest of them
            held = r > r.min()
        key = np.packbits(held).tobytes()
        if key in seen or np.array_equal(~held, quiet):
            break
        seen.add(key)
        quiet = ~held
    rq = r[quiet]
    scatter = 1.4826 * float(np.median(np.abs(rq - np.median(rq))))
    return ClockFit(float(c0 - c1 * s[idx[0]]), float(nominal_slope + c1), scatter, int(idx.size))


def _hull_slope(
    x: NDArray[np.float64], y: NDArray[np.float64], hull: NDArray[np.intp], at: float, lim: float
) -> float:
    """The slope of the lower hull's edge over ``x = at``, within ``±lim``."""
    if hull.size < 2:
        return 0.0
    e = int(np.clip(np.searchsorted(x[hull], at) - 1, 0, hull.size - 2))
    a, b = hull[e], hull[e + 1]
    # a crystal is within max_ppm: a slope beyond is the scatter's, not the clock's
    return float(np.clip((y[b] - y[a]) / (x[b] - x[a]), -lim, lim))


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


@dataclass(frozen=True)
class DelayFit:
    """The residual delay of a stream's FRFs (:func:`fit_delay`): ``H_measured = H e^{−iωτ}``.

    Attributes
    ----------
    delay_s : float
        ``τ``, s: the stream lags the reference by ``τ`` (multiply its FRFs by ``e^{iωτ}``).
    sigma_s : float
        Statistical 1σ of ``τ`` (curvature of the cost, residual variance), s.
    spread_s : float
        Half the difference of the estimates on the lower and upper half of the lines, s: the
        model's misfit (0 when the lines are too few to split).
    n_lines, n_frfs : int
        Lines and FRFs fitted.
    misfit : float
        ``√(J(τ̂) / Σ w |H|²)``: the weighted residual relative to the data.
    """

    delay_s: float
    sigma_s: float
    spread_s: float
    n_lines: int
    n_frfs: int
    misfit: float

    @property
    def uncertainty_s(self) -> float:
        """``√(σ² + spread²)``, s: what the phase budget is checked against."""
        return float(np.hypot(self.sigma_s, self.spread_s))


@dataclass(frozen=True)
class DelayBudget:
    """What a stream on its own clock asks of the data's delay fit, and its limit.

    Attributes
    ----------
    search_s : float
        ``|τ|`` is sought within this, s (the coarse alignment's uncertainty, with margin).
    lo_hz : float
        The fit's lowest line, Hz (above the suspension's modes); its highest is ``band_hz``.
    band_hz, max_phase_deg : float
        The fit's uncertainty may cost at most ``max_phase_deg`` of FRF phase at ``band_hz``.
    label : str
        The device, for messages.
    """

    search_s: float
    lo_hz: float
    band_hz: float
    max_phase_deg: float
    label: str = "stream"


_GOLDEN = (np.sqrt(5.0) - 1.0) / 2.0


def mass_line_basis(
    frequencies_hz: NDArray[np.float64], n_terms: int = 3
) -> NDArray[np.complex128]:
    """Regressors ``(ω0 / iω)^n``, ``n = 0 .. n_terms − 1`` (``ω0`` the lines' geometric mean):
    equation (2) of the module doc, for a cell with no reference FRFs at hand.

    Returns
    -------
    ndarray, shape (n_lines, n_terms)
    """
    f = np.asarray(frequencies_hz, dtype=float)
    omega = 2 * np.pi * f
    omega0 = 2 * np.pi * float(np.sqrt(f.min() * f.max()))
    return np.stack([(omega0 / (1j * omega)) ** n for n in range(n_terms)], axis=1)


def _cost_fn(
    f: NDArray[np.float64],
    H: NDArray[np.complex128],
    X: NDArray[np.complex128],
    sw: NDArray[np.float64],
) -> tuple[Callable[[NDArray[np.float64]], NDArray[np.float64]], int, float]:
    """The cost ``J(τ)`` of equation (1) on lines ``f`` (``sw = √w`` per line) for an array of
    trial delays, the regressors' rank and ``Σ w |H|²``."""
    omega = 2 * np.pi * f
    n = f.size
    # the real least-squares problem of (1): rows Re, Im of every line, columns the regressors'
    # real coefficients; its range's orthonormal basis Q does not depend on τ
    R = np.concatenate([X.real * sw[:, None], X.imag * sw[:, None]], axis=0)
    U, sv, _ = np.linalg.svd(R, full_matrices=False)
    rank = int((sv > sv[0] * 1e-10).sum()) if sv.size and sv[0] > 0 else 0
    Q = U[:, :rank]
    Hs = H * sw[:, None]
    total = float(np.sum(np.abs(Hs) ** 2))
    # J(τ) = |g|² − |Qᵀg|² with g = [Re; Im] of Hs e^{iωτ}: |g|² is Σ w |H|² whatever τ, and
    # Qᵀg = Re Σ_l (Q_Re,l − i Q_Im,l) ⊗ Hs_l e^{iω_l τ} — one matrix product for all trial τ
    P = ((Q[:n] - 1j * Q[n:])[:, :, None] * Hs[:, None, :]).reshape(n, -1)
    Pr, Pi = np.ascontiguousarray(P.real), np.ascontiguousarray(P.imag)

    def cost(tau: NDArray[np.float64]) -> NDArray[np.float64]:
        t = np.atleast_1d(np.asarray(tau, dtype=float))
        out = np.empty(t.size)
        for i0 in range(0, t.size, 64):
            ph = t[i0 : i0 + 64, None] * omega[None, :]
            # Re(e^{iφ} P) as two real products: 5 times cheaper than one complex one here
            p = np.cos(ph) @ Pr - np.sin(ph) @ Pi
            out[i0 : i0 + 64] = total - np.einsum("tk,tk->t", p, p)
        return out

    return cost, rank, total


def _minimise(
    cost: Callable[[NDArray[np.float64]], NDArray[np.float64]],
    f_max: float,
    search_s: float,
    center_s: float = 0.0,
) -> tuple[float, float, float]:
    """``τ̂`` within ``center_s ± search_s`` (a grid of ``0.05 / f_max``, then golden section),
    ``J(τ̂)`` and the curvature ``J''(τ̂)``."""
    step = min(0.05 / f_max, search_s / 4)  # 18° of phase at the top line between grid points
    grid = center_s + np.arange(-search_s, search_s + step, step)
    J = cost(grid)
    i = int(np.argmin(J))
    a, b = grid[max(i - 1, 0)], grid[min(i + 1, grid.size - 1)]
    while b - a > 1e-5 * step:  # 0.8 ns at 655 Hz
        c, d = b - _GOLDEN * (b - a), a + _GOLDEN * (b - a)
        jc, jd = cost(np.array([c, d]))
        if jc < jd:
            b = d
        else:
            a = c
    tau = 0.5 * (a + b)
    h = 0.01 * step
    jm, j0, jp = cost(np.array([tau - h, tau, tau + h]))
    return float(tau), float(j0), float((jp - 2 * j0 + jm) / h**2)


def _fit_tau(
    f: NDArray[np.float64],
    H: NDArray[np.complex128],
    X: NDArray[np.complex128],
    sw: NDArray[np.float64],
    search_s: float,
    center_s: float = 0.0,
) -> tuple[float, float, float, float]:
    """``τ̂``, ``σ_τ``, ``J(τ̂)`` and ``Σ w |H|²`` on lines ``f`` (``sw = √w`` per line), ``τ``
    sought within ``center_s ± search_s``."""
    cost, rank, total = _cost_fn(f, H, X, sw)
    tau, j0, curv = _minimise(cost, float(f.max()), search_s, center_s)
    s2 = max(j0, 0.0) / _dof(f.size, H.shape[1], rank)
    sigma = float(np.sqrt(2 * s2 / curv)) if curv > 0 else float("inf")
    return tau, sigma, j0, total


def _dof(n_lines: int, n_frfs: int, rank: int) -> int:
    """The residual's degrees of freedom: Re and Im of every line and FRF, less the real
    coefficients and ``τ``."""
    return max(1, 2 * n_lines * n_frfs - rank * n_frfs - 1)


def _usable(
    f: NDArray[np.float64],
    H: NDArray[np.complex128],
    w: NDArray[np.float64],
    regressors: NDArray[np.complex128] | None,
    search_s: float,
) -> tuple[
    NDArray[np.float64], NDArray[np.complex128], NDArray[np.complex128], NDArray[np.float64]
]:
    """The lines with finite FRFs, regressors and weights: ``f, H, X, √w``."""
    f = np.asarray(f, dtype=float)
    Hc = np.asarray(H, dtype=complex)
    w = np.asarray(w, dtype=float)
    X = mass_line_basis(f) if regressors is None else np.asarray(regressors, dtype=complex)
    if Hc.ndim != 2 or Hc.shape[0] != f.size or w.shape != f.shape or X.shape[0] != f.size:
        raise ValueError(
            f"fit_delay: H {Hc.shape}, weights {w.shape}, regressors {X.shape} for {f.size} "
            "lines; give (n_lines, ...) arrays for the lines given"
        )
    ok = np.isfinite(Hc).all(axis=1) & np.isfinite(X).all(axis=1) & np.isfinite(w) & (f > 0)
    f, Hc, X, w = f[ok], Hc[ok], X[ok], np.clip(w[ok], 0.0, None)
    need = X.shape[1] + 2
    if f.size < need or not search_s > 0:
        raise ValueError(
            f"fit_delay: {f.size} usable lines, search {search_s} s; give at least {need} "
            "lines with finite FRFs and a positive search range"
        )
    return f, Hc, X, np.sqrt(w)


def fit_delay(
    frequencies_hz: NDArray[np.float64],
    H: NDArray[np.complex128],
    weights: NDArray[np.float64],
    *,
    search_s: float,
    regressors: NDArray[np.complex128] | None = None,
    line_bandwidth: float = 1.0,
) -> DelayFit:
    """The delay ``τ`` common to FRFs ``H`` of a stream against references on another clock:
    ``H_m(f) e^{iωτ} = Σ_k c_mk X_k(f)`` with real ``c_mk`` (equation (1) of the module doc),
    fitted by weighted least squares over the lines, with its uncertainty and the half-bands'
    disagreement.

    Parameters
    ----------
    frequencies_hz : ndarray, shape (n_lines,)
        Positive.
    H : ndarray, shape (n_lines, n_frfs)
        The stream's FRFs (e.g. a cell's loads per unit hammer force); scale each column to a
        comparable size (the cost sums them).
    weights : ndarray, shape (n_lines,)
        Inverse variance of each line (relative), ≥ 0.
    search_s : float
        ``|τ|`` is sought within this, s (the coarse alignment's uncertainty, with margin).
    regressors : ndarray, shape (n_lines, n_regressors), optional
        ``X_k`` on the reference's clock (the DAQ's responses to the same input and a column of
        ones: equation (1)); None: :func:`mass_line_basis` (equation (2)).
    line_bandwidth : float
        How many adjacent lines share their noise, ``B ≥ 1``: FRFs of records under a window
        ``w`` (an exponential window on a hit's response) have their noise smoothed over the
        window's equivalent noise bandwidth, ``B = N Σw² / (Σw)²`` lines; the residuals then
        hold ``n / B`` independent lines, not ``n``, and ``σ_τ² = B · 2 s² / J''(τ̂)`` (a
        0.25 s window: ``B`` ≈ 2 on 1 s records, 3.6 on 2 s; with 1 taken, the demo's step-0
        fits scattered 2–3 times their σ).

    Raises
    ------
    ValueError
        Shapes disagree, or fewer usable lines than the fit needs.
    """
    f, Hc, X, sw = _usable(frequencies_hz, H, weights, regressors, search_s)
    need = X.shape[1] + 2
    tau, sigma, j0, total = _fit_tau(f, Hc, X, sw, search_s)
    sigma *= float(np.sqrt(max(line_bandwidth, 1.0)))
    spread = 0.0
    if f.size >= 2 * need:
        # each half refines the whole band's estimate (its own search would find the far
        # minima of a half's weaker cost); a half's minimum at the edge of its window counts
        # as that far off
        half = f < np.median(f)
        near = max(20 * sigma, 0.05 / float(f.max())) if np.isfinite(sigma) else search_s
        got = []
        for h in (half, ~half):
            t_h = _fit_tau(f[h], Hc[h], X[h], sw[h], near, tau)[0]
            got.append(tau + near if abs(t_h - tau) > 0.99 * near else t_h)
        spread = 0.5 * abs(got[0] - got[1])
    misfit = float(np.sqrt(max(j0, 0.0) / total)) if total > 0 else 0.0
    return DelayFit(tau, sigma, spread, int(f.size), int(Hc.shape[1]), misfit)


@dataclass(frozen=True)
class PooledDelayFit:
    """One delay shared by several inputs' FRFs (:func:`fit_pooled_delay`).

    Attributes
    ----------
    delay_s : float
        ``τ̂``, s (the convention of :class:`DelayFit`).
    sigma_s : float
        Its statistical 1σ from the joint cost's curvature, s: what the inputs' own noise
        leaves, if each input's fit were unbiased.
    jackknife_s : float
        Its standard error from the leave-one-input-out refits, s: counts how far each input
        pulls the estimate — its noise and its own bias alike — as random.
    loo_delays_s : ndarray, shape (k,)
        The refit without each input, s.
    own_delays_s : ndarray, shape (k,)
        Each input's own minimum less its offset, s (for the record).
    cost : float
        ``C(τ̂)``: the joint cost left (χ²-like: ~ the degrees of freedom when the model and
        the offsets hold), what tells fits of the same data under other offsets apart.
    offsets_used : bool
        The offsets given fitted the data better than none, and were used.
    halves_s : tuple of float, or None
        ``τ̂`` of the first and of the second half of the inputs (in the order given; None
        with fewer than 4).
    """

    delay_s: float
    sigma_s: float
    jackknife_s: float
    loo_delays_s: NDArray[np.float64]
    own_delays_s: NDArray[np.float64]
    cost: float
    offsets_used: bool = False
    halves_s: tuple[float, float] | None = None

    @property
    def n_inputs(self) -> int:
        return int(self.loo_delays_s.size)

    @property
    def uncertainty_s(self) -> float:
        """``max(σ, se_jackknife)``, s: the estimate's error (the jackknife of few inputs
        may come out small by chance; it is never below what the noise alone leaves)."""
        return float(max(self.sigma_s, self.jackknife_s))

    @property
    def scatter_s(self) -> float:
        """How far one input's delay lies from the run's, RMS, s, as the inputs tell it: the
        jackknife's pseudo-values ``p_i = k τ̂ − (k − 1) τ̂_(i)`` are each input's own say
        (their mean is ``τ̂``, their spread over ``√k`` the jackknife's standard error); their
        RMS about ``τ̂`` is the scatter — a drift over the run, a wander between inputs and
        each input's own bias alike — over the inputs within ``5 · 1.4826 · MAD`` of their
        median (an input whose alignment jumped does not count for the others: it is told
        apart on its own). What removing the run's delay leaves in one input. 0 with one
        input."""
        k = self.n_inputs
        if k < 2:
            return 0.0
        pseudo = k * self.delay_s - (k - 1) * self.loo_delays_s
        dev = np.abs(pseudo - np.median(pseudo))
        kept = dev <= 5.0 * 1.4826 * np.median(dev)
        return float(np.sqrt(np.mean((pseudo[kept] - self.delay_s) ** 2)))

    @property
    def drift_s(self) -> float:
        """How far the inputs' delays lie from the run's, RMS, if it drifts over the run, s:
        a drift linear from ``−D/2`` to ``+D/2`` puts the halves' means ``D/2`` apart and the
        inputs an RMS ``D/√12`` from the run's mean, so ``|τ_A − τ_B| / √3`` (the halves' own
        errors included: it errs on the safe side; a bias of single inputs averages out within
        each half). 0 with fewer than 4 inputs."""
        if self.halves_s is None:
            return 0.0
        return float(abs(self.halves_s[0] - self.halves_s[1]) / np.sqrt(3.0))


def fit_pooled_delay(
    frequencies_hz: NDArray[np.float64],
    H: list[NDArray[np.complex128]],
    weights: list[NDArray[np.float64]],
    *,
    search_s: float,
    regressors: list[NDArray[np.complex128] | None],
    line_bandwidth: float = 1.0,
    offsets_s: NDArray[np.float64] | None = None,
) -> PooledDelayFit:
    """One delay ``τ`` common to the FRFs of ``k`` inputs, each input with its own real
    coefficients (equation (1) per input, ``τ`` shared), and its standard error by the
    jackknife over inputs.

    Input ``i``'s cost ``J_i(τ)`` (its variable projection, :func:`fit_delay`) is scaled by its
    own residual variance per degree of freedom at its own minimum, ``s_i² B`` (``B`` the
    lines sharing their noise), so that each is a χ²-like sum and the joint cost is::

        C(τ) = Σ_i J_i(τ) / (s_i² B),     τ̂ = argmin C,     σ_τ² = 2 / C''(τ̂)

    (the inverse-variance combination of the inputs' fits, to second order). ``σ_τ`` holds only
    the noise: a fit that is biased per input (a model that holds per input but not exactly)
    is not in it. The jackknife is: ``τ̂_(i) = argmin Σ_{l≠i} J_l / (s_l² B)`` and
    ``se² = (k − 1)/k Σ_i (τ̂_(i) − τ̂_(·))²`` (Efron & Stein 1981: it estimates the variance of
    a smooth estimator from the data, whatever made the inputs differ). Each ``τ̂_(i)`` is the
    minimum of the summed costs on a grid of 151 points over ``τ̂ ± 0.05 / f_max`` (18° at the
    top line: within it the costs have no other minimum), refined by a parabola; one at the
    grid's edge counts as that far off.

    Parameters
    ----------
    frequencies_hz : ndarray, shape (n_lines,)
    H : list of ndarray, shape (n_lines, n_frfs_i)
        Each input's FRFs on the stream's clock.
    weights : list of ndarray, shape (n_lines,)
    search_s : float
    regressors : list of ndarray, shape (n_lines, n_regressors_i), or None
        Each input's references (None: the mass-line basis).
    line_bandwidth : float
    offsets_s : ndarray, shape (k,), optional
        What may be known of how the inputs' delays differ, s: input ``i``'s delay taken as
        ``τ + offsets_s[i]`` (its cost there). Used when the joint cost left is lower with
        them than without (same parameters: the data tell which holds).

    Raises
    ------
    ValueError
        No input, or an input with too few usable lines.
    """
    if not H or not len(H) == len(weights) == len(regressors):
        raise ValueError(
            f"fit_pooled_delay: {len(H)} inputs' FRFs, {len(weights)} weights, "
            f"{len(regressors)} regressors; give one of each per input"
        )
    B = float(max(line_bandwidth, 1.0))
    k = len(H)
    costs = []
    f_max = 0.0
    for Hi, wi, Xi in zip(H, weights, regressors, strict=True):
        f, Hc, X, sw = _usable(frequencies_hz, Hi, wi, Xi, search_s)
        cost, rank, total = _cost_fn(f, Hc, X, sw)
        _, j0, _ = _minimise(cost, float(f.max()), search_s)
        # noise-free data: a residual at rounding's level (1e-24 of the data's size)
        s2 = max(j0, 1e-24 * total, 1e-300) / _dof(f.size, Hc.shape[1], rank)
        costs.append((cost, 1.0 / (s2 * B)))
        f_max = max(f_max, float(f.max()))
    zero = np.zeros(k)
    fit = _joint_fit(costs, zero, f_max, search_s)
    offs = zero if offsets_s is None else np.asarray(offsets_s, dtype=float)
    if np.any(offs != 0.0):  # the data say whether the offsets hold
        shifted = _joint_fit(costs, offs, f_max, search_s)
        if shifted.cost < fit.cost:
            fit = dataclasses.replace(shifted, offsets_used=True)
    if k < 4:
        return fit
    used = offs if fit.offsets_used else zero
    halves = tuple(
        _minimise(_joint(costs[h], used[h]), f_max, search_s)[0]
        for h in (slice(0, k // 2), slice(k // 2, k))
    )
    return dataclasses.replace(fit, halves_s=(float(halves[0]), float(halves[1])))


def _joint(
    costs: list[tuple[Callable[[NDArray[np.float64]], NDArray[np.float64]], float]],
    offsets: NDArray[np.float64],
) -> Callable[[NDArray[np.float64]], NDArray[np.float64]]:
    """``τ ↦ Σ_i a_i J_i(τ + o_i)``."""

    def joint(tau: NDArray[np.float64]) -> NDArray[np.float64]:
        t = np.atleast_1d(np.asarray(tau, dtype=float))
        return np.sum([a * c(t + o) for (c, a), o in zip(costs, offsets, strict=True)], axis=0)

    return joint


def _joint_fit(
    costs: list[tuple[Callable[[NDArray[np.float64]], NDArray[np.float64]], float]],
    offsets: NDArray[np.float64],
    f_max: float,
    search_s: float,
) -> PooledDelayFit:
    """The joint minimum of :func:`fit_pooled_delay`, its σ and its jackknife over inputs."""
    tau, c_min, curv = _minimise(_joint(costs, offsets), f_max, search_s)
    sigma = float(np.sqrt(2.0 / curv)) if curv > 0 else float("inf")
    half = 0.05 / f_max
    grid = tau + np.linspace(-half, half, 151)
    per = np.array([a * c(grid + o) for (c, a), o in zip(costs, offsets, strict=True)])
    own = grid[np.argmin(per, axis=1)]
    k = len(costs)
    if k < 2:
        return PooledDelayFit(tau, sigma, 0.0, np.array([tau]), own, c_min)
    loo = per.sum(axis=0)[None, :] - per  # (k, n_grid): each input left out
    i = np.argmin(loo, axis=1)
    ic = np.clip(i, 1, grid.size - 2)
    r = np.arange(k)
    jm, j0, jp = loo[r, ic - 1], loo[r, ic], loo[r, ic + 1]
    den = jm - 2 * j0 + jp
    dx = np.where(den > 0, 0.5 * (jm - jp) / np.where(den > 0, den, 1.0), 0.0)
    tau_loo = grid[ic] + np.clip(dx, -1.0, 1.0) * (grid[1] - grid[0])
    tau_loo = np.where((i == 0) | (i == grid.size - 1), grid[i], tau_loo)
    se = float(np.sqrt((k - 1) / k * np.sum((tau_loo - tau_loo.mean()) ** 2)))
    return PooledDelayFit(tau, sigma, se, tau_loo, own, c_min)
