"""Strain-gauge bridges of a 6-DOF load cell: what its 12 full bridges read, in mV/V.

A DC-coupled strain-gauge cell (the default of the virtual lab's load cells; the AC-coupled,
piezo-like gauges of the thesis's cell stay available, see :class:`~dimacq.simulators.lab.
timedomain.VirtualLab`) turns the load ``F = [f; m]`` (N, N·m, cell frame) on its elastic body
into 12 bridge outputs. The amplifier excites every bridge with ``E`` volts and reads the ratio
``V_out / E`` (ratiometric, 6-wire sense), so excitation changes cancel; its input noise ``e_n``
(µV rms per sample) becomes ``1e-3 e_n / E`` mV/V.

Model (per sample, ``x = F / F_rated`` per axis, all terms in the cell's load space except the
zero terms)::

    r = S (F + δ_nl + δ_h + δ_creep + δ_swing) + r_0 + α (T(t) − T_ref) + noise      [mV/V]

    δ_nl,i   = n_i F_rated,i x_i²                                 (nonlinearity, even in x)
    δ_h,i    = σ_i (h_i / 2) F_rated,i φ(|x_i|) sign(x_i),  φ(u) = 4 u (1 − u) on [0, 1]
    δ_creep  = Σ_k c ΔF_k (1 − exp(−(t − t_k) / τ_c))             (creep after each load change)
    δ_swing  = Σ_k a_s ΔF_k exp(−(t − t_k) / τ_s) cos(2π f_s (t − t_k))   (hanger swing)
    T(t)     = T_0 + ramp · t

``S`` (12 × 6, mV/V per N and per N·m) carries the crosstalk between bridges (each spoke's bridge
sees several load components). ``σ_i`` is −1 while ``|x_i|`` was last increased (loading: the
reading lags) and +1 after it was last decreased (unloading); it changes only when the
quasi-static load level set by the operator moves by more than ``dead_band`` of full scale, so
vibrations about a level (the inertial bench) form no loop. On a full-scale loading / unloading
cycle the up/down difference at ``|x| = 0.5`` is ``h_i`` of full scale and the deviation of the
mean of the two branches from the straight line at ``|x| = 1`` is ``n_i`` of full scale: the
hysteresis and nonlinearity a calibration certificate reports for that axis.

The hysteresis and creep act on the *quasi-static* level the operator sets (:class:`BridgeState`
records the placements); a vibrating load on top of it (the virtual lab's dynamics) passes
through ``S`` and the nonlinearity only.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

__all__ = [
    "BridgeState",
    "StrainGaugeCell",
    "default_gauge_matrix",
    "default_strain_gauge_cell",
]

FloatArray = NDArray[np.float64]

#: Rated loads of the default cell: Fx, Fy, Fz in N, Mx, My, Mz in N·m.
DEFAULT_RATED_LOAD = (500.0, 500.0, 1000.0, 50.0, 50.0, 50.0)


@dataclass(frozen=True, eq=False)
class StrainGaugeCell:
    """The 12 bridges of one DC-coupled strain-gauge cell (see the module docstring).

    Attributes
    ----------
    sensitivity_mvv : ndarray, shape (12, 6)
        ``S``: mV/V per N (columns Fx, Fy, Fz) and per N·m (Mx, My, Mz).
    rated_load : ndarray, shape (6,)
        Full scale per axis, N and N·m.
    nonlinearity : ndarray, shape (6,)
        ``n_i``, fraction of full scale (quadratic, at full scale).
    hysteresis : ndarray, shape (6,)
        ``h_i``, fraction of full scale (up/down difference at half scale).
    dead_band : float
        Level change (fraction of full scale) that reverses the hysteresis state.
    creep : float
        ``c``: final creep as a fraction of each load change.
    creep_tau_s : float
    swing : float
        ``a_s``: initial swing of the hanger as a fraction of the load change.
    swing_tau_s, swing_hz : float
    zero_offset_mvv : ndarray, shape (12,)
    zero_tc_mvv_per_k : ndarray, shape (12,)
        Zero drift with temperature.
    temperature_c, temperature_ramp_k_per_s, reference_temperature_c : float
    excitation_v : float
    noise_uv : float
        Amplifier input noise, µV rms per sample.
    """

    sensitivity_mvv: FloatArray
    rated_load: FloatArray = field(default_factory=lambda: np.array(DEFAULT_RATED_LOAD))
    nonlinearity: FloatArray = field(default_factory=lambda: np.full(6, 5e-4))
    hysteresis: FloatArray = field(default_factory=lambda: np.full(6, 3e-4))
    dead_band: float = 0.005
    creep: float = 3e-4
    creep_tau_s: float = 8.0
    swing: float = 0.02
    swing_tau_s: float = 1.5
    swing_hz: float = 1.2
    zero_offset_mvv: FloatArray = field(default_factory=lambda: np.zeros(12))
    zero_tc_mvv_per_k: FloatArray = field(default_factory=lambda: np.zeros(12))
    temperature_c: float = 21.0
    temperature_ramp_k_per_s: float = 0.0
    reference_temperature_c: float = 21.0
    excitation_v: float = 10.0
    noise_uv: float = 0.05

    def __post_init__(self) -> None:
        S = np.asarray(self.sensitivity_mvv, float)
        if S.shape != (12, 6) or np.linalg.matrix_rank(S) < 6:
            raise ValueError(f"sensitivity_mvv has shape {S.shape}; give a rank-6 12x6 matrix")
        for name, shape in (
            ("rated_load", (6,)),
            ("nonlinearity", (6,)),
            ("hysteresis", (6,)),
            ("zero_offset_mvv", (12,)),
            ("zero_tc_mvv_per_k", (12,)),
        ):
            v = np.broadcast_to(np.asarray(getattr(self, name), float), shape).copy()
            object.__setattr__(self, name, v)
        object.__setattr__(self, "sensitivity_mvv", S)
        if np.any(self.rated_load <= 0) or self.excitation_v <= 0:
            raise ValueError("rated_load and excitation_v must be positive")

    @property
    def noise_mvv(self) -> float:
        """Input noise as a bridge ratio, mV/V rms per sample: ``1e-3 e_n / E``."""
        return 1e-3 * self.noise_uv / self.excitation_v

    def temperature(self, t_s: FloatArray) -> FloatArray:
        """Bench temperature at times ``t_s``, °C."""
        return self.temperature_c + self.temperature_ramp_k_per_s * np.asarray(t_s, float)

    def nonlinear_part(self, loads: FloatArray) -> FloatArray:
        """``δ_nl`` of loads (6, n): ``n_i F_rated,i x_i²``."""
        L = np.asarray(loads, float)
        R = self.rated_load.reshape((6,) + (1,) * (L.ndim - 1))
        n = self.nonlinearity.reshape(R.shape)
        out: FloatArray = n * L**2 / R
        return out

    def hysteresis_part(self, level: FloatArray, state: FloatArray) -> FloatArray:
        """``δ_h`` (6,) of a quasi-static level (6,) in hysteresis state ``σ`` (6,) of ±1."""
        x = np.asarray(level, float) / self.rated_load
        u = np.clip(np.abs(x), 0.0, 1.0)
        out: FloatArray = (
            state * self.hysteresis / 2 * self.rated_load * 4 * u * (1 - u) * np.sign(x)
        )
        return out

    def zero(self, t_s: FloatArray) -> FloatArray:
        """Zero terms ``r_0 + α (T(t) − T_ref)``, shape (12, n)."""
        dT = self.temperature(np.asarray(t_s, float)) - self.reference_temperature_c
        out: FloatArray = self.zero_offset_mvv[:, None] + self.zero_tc_mvv_per_k[:, None] * dT
        return out


@dataclass
class _Placement:
    t_s: float
    delta: FloatArray  # (6,) change of the quasi-static level


@dataclass
class BridgeState:
    """The quasi-static history of one cell: the levels set by the operator and what follows.

    ``place(level, t_s)`` sets a new quasi-static load (6,) from time ``t_s``; :meth:`effective`
    gives the load the bridges feel at times ``t_s`` (6, n) on top of a dynamic part.
    """

    cell: StrainGaugeCell
    level: FloatArray = field(default_factory=lambda: np.zeros(6))
    sigma: FloatArray = field(default_factory=lambda: -np.ones(6))
    anchor: FloatArray = field(default_factory=lambda: np.zeros(6))
    placements: list[_Placement] = field(default_factory=list)
    hyst: FloatArray = field(default_factory=lambda: np.zeros(6))
    #: hysteresis offset in force before each placement (time, value), for reads of the past
    history: list[tuple[float, FloatArray, FloatArray]] = field(default_factory=list)

    def __post_init__(self) -> None:
        self.history.append((-np.inf, self.level.copy(), self.hyst.copy()))

    def place(self, level: FloatArray, t_s: float, *, settle: bool = False) -> None:
        """A new quasi-static level from ``t_s`` on (``settle``: no swing or creep, e.g. a
        preload applied long before)."""
        new = np.asarray(level, float).copy()
        c = self.cell
        mag_new = np.abs(new) / c.rated_load
        mag_anchor = self.anchor
        # Reverse the state when the level moved beyond the dead band from the last turning point.
        up = mag_new > mag_anchor + c.dead_band
        down = mag_new < mag_anchor - c.dead_band
        moved = up | down
        self.sigma = np.where(up, -1.0, np.where(down, 1.0, self.sigma))
        self.anchor = np.where(moved, mag_new, self.anchor)
        if not settle:
            self.placements.append(_Placement(float(t_s), new - self.level))
        self.level = new
        self.hyst = c.hysteresis_part(new, self.sigma)
        self.history.append((float(t_s), self.level.copy(), self.hyst.copy()))

    def effective(self, t_s: FloatArray, dynamic: FloatArray | None = None) -> FloatArray:
        """Load felt by the bridges at times ``t_s`` (n,), shape (6, n): the level (with its
        hysteresis, creep and swing) plus ``dynamic`` (6, n), through the nonlinearity."""
        t = np.asarray(t_s, float)
        c = self.cell
        times = np.array([h[0] for h in self.history])
        k = np.searchsorted(times, t, side="right") - 1  # which level holds at each time
        levels = np.stack([h[1] for h in self.history])[k].T  # (6, n)
        hyst = np.stack([h[2] for h in self.history])[k].T
        F = levels if dynamic is None else levels + dynamic
        out = F + c.nonlinear_part(F) + hyst
        for pl in self.placements:
            dt = t - pl.t_s
            on = dt >= 0
            if not on.any():
                continue
            dto = np.where(on, dt, 0.0)
            w = on * (
                c.creep * (1 - np.exp(-dto / c.creep_tau_s))
                + c.swing * np.exp(-dto / c.swing_tau_s) * np.cos(2 * np.pi * c.swing_hz * dto)
            )
            out += pl.delta[:, None] * w[None, :]
        return out

    def readings(
        self,
        t_s: FloatArray,
        dynamic: FloatArray | None = None,
        rng: np.random.Generator | None = None,
    ) -> FloatArray:
        """Bridge readings (12, n), mV/V (noise from ``rng`` if given)."""
        c = self.cell
        r: FloatArray = c.sensitivity_mvv @ self.effective(t_s, dynamic) + c.zero(t_s)
        if rng is not None and c.noise_mvv > 0:
            r = r + c.noise_mvv * rng.standard_normal(r.shape)
        return r


def default_strain_gauge_cell(
    sensitivity_mvv: FloatArray, rng: np.random.Generator, **overrides: float
) -> StrainGaugeCell:
    """A cell with the given ``S`` and seeded zero offsets (±0.05 mV/V) and zero temperature
    coefficients (±2e-5 mV/V per K, about 0.002 % of rated output per K); ``overrides`` set the
    other attributes."""
    kw: dict[str, object] = dict(
        zero_offset_mvv=rng.uniform(-0.05, 0.05, 12),
        zero_tc_mvv_per_k=rng.uniform(-2e-5, 2e-5, 12),
    )
    kw.update(overrides)
    return StrainGaugeCell(np.asarray(sensitivity_mvv, float), **kw)  # type: ignore[arg-type]


def strain_gauge_cell(node: int, rated_scale: float = 1.0, **overrides: float) -> StrainGaugeCell:
    """The virtual lab's strain-gauge cell ``node`` (its serial number): the lab's 4-spoke
    sensitivity for that cell (:func:`default_gauge_matrix`
    seeded by the node, read as mV/V per N and N·m; the same in every run, as a real cell is)
    and :func:`default_strain_gauge_cell`'s zero terms.

    ``rated_scale`` sizes the cell for its article, as a lab chooses its cells: rated loads
    ``rated_scale ×`` :data:`DEFAULT_RATED_LOAD` and a sensitivity ``1/rated_scale`` as large (the
    same mV/V at full scale). An 8-t vehicle on three cells loads each with ~26 kN: a 1-kN cell
    would sit 26 times past its range and every strike would overload."""
    if rated_scale <= 0:
        raise ValueError("rated_scale must be positive")
    S = default_gauge_matrix(np.random.default_rng([11, node])) / rated_scale
    overrides.setdefault("rated_load", np.asarray(DEFAULT_RATED_LOAD) * rated_scale)  # type: ignore[arg-type]
    return default_strain_gauge_cell(S, np.random.default_rng([23, node]), **overrides)


def default_gauge_matrix(rng: np.random.Generator) -> FloatArray:
    """A 12×6 sensitivity of a 4-spoke strain-gauge cell (V per N and per N·m), well conditioned.

    Each spoke carries three gauges sensing mostly one combination of loads; a seeded perturbation
    makes every cell different. Condition number about 3–6.
    """
    base = np.zeros((12, 6))
    for spoke in range(4):
        ang = spoke * np.pi / 2
        c, s = math.cos(ang), math.sin(ang)
        base[3 * spoke + 0] = [c, s, 0.0, 0.0, 0.0, 2.0]  # tangential bending: Fx/Fy and Mz
        base[3 * spoke + 1] = [0.0, 0.0, 1.0, 2.0 * s, -2.0 * c, 0.0]  # vertical: Fz, Mx, My
        base[3 * spoke + 2] = [-s, c, 0.3, 0.0, 0.0, -1.0]
    S = base * 1e-3 + rng.normal(scale=1e-4, size=(12, 6))
    S[:, 3:] *= 10.0  # moments in N·m give a larger strain per unit
    return S
