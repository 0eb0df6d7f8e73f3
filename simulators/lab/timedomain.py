"""Time-domain virtual lab: the signals every simulated transducer sees, on one sample clock.

Model
-----
The forward model (:mod:`dimacq.simulators.lab.forward`) is written in state space per input,
``ẋ = A x + B f``, ``y = C x + D f``:

- rigid body on its supports, ``x = [q; q̇]`` (q = motion of the GCS origin):
  ``A = [[0, E], [−M⁻¹K, −M⁻¹C]]``, ``B_j = [0; M⁻¹φ_j]``; accelerometer i reads
  ``ψ_i q̈ = ψ_i M⁻¹(−K q − C q̇ + φ_j f)``; a load cell reads ``−B_sᵀ(K_s G_s q + C_s G_s q̇)``;
- each flexible mode adds ``η̈ + 2ζω_k η̇ + ω_k² η = b_j f`` with accelerometer reading
  ``a_i η̈``.

With ``A = V Λ V⁻¹`` the response to a force ``f(t)`` is ``y = D f + Σ_k R_k (e^{λ_k t} * f)`` with
residues ``R_k = (C V)_{:,k} (V⁻¹ B)_{k,:}`` (complex-conjugate pairs; the sum is real). The
hammer pulse is Gaussian, ``f(t) = F exp(−(t − t_h)²/(2σ²))``, whose spectrum
``exp(−ω²σ²/2)`` is negligible above the Nyquist frequency — the lab's stand-in for the DAQ's
anti-alias filter, applied alike to every channel. Its convolution with ``e^{λt}`` is exact:

    g(u) = F σ √(π/2) · exp(λu + λ²σ²/2) · erfc(−(u + λσ²)/(σ√2)),   u = t − t_h,

which becomes ``F σ √(2π) exp(λu + λ²σ²/2)`` once the pulse is over; from then on a hit is carried
from block to block as one complex amplitude per pole (``c ← c e^{λ T_block}``). So the lab is exact
at any sample rate, costs O(channels × poles) per sample, and a reading of any counter range gives
the same samples every time (noise from a counter-based generator per block).

Free-free bodies (no supports) have no states: the accelerations are ``D f`` exactly.

Transducers: accelerometer sensitivity error and cross-axis sensitivity (mixing within a triax),
Gaussian noise per channel, the hammer's own force channel, and each load cell's 12 gauges from its
local ``[f; m]`` through a 12×6 sensitivity matrix, with noise and a slow zero drift.
"""

from __future__ import annotations

import math
from collections import OrderedDict
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray
from scipy.special import erfc

from dimacq.simulators.lab.forward import ForwardModel

__all__ = ["Hammer", "LabNoise", "VirtualLab", "state_space"]

FloatArray = NDArray[np.float64]
ComplexArray = NDArray[np.complex128]


@dataclass(frozen=True)
class Hammer:
    """Impact hammer.

    Attributes
    ----------
    peak_n : float
        Peak force of a hit, N.
    sigma_s : float
        Gaussian pulse width (standard deviation), s; ``None`` picks 0.33/fs·... (see VirtualLab).
    double_hit_probability : float
        Probability that a strike bounces back for a second hit.
    double_hit_delay_s, double_hit_ratio : float
        Delay and relative amplitude of the second hit.
    """

    peak_n: float = 200.0
    sigma_s: float | None = None
    double_hit_probability: float = 0.0
    double_hit_delay_s: float = 0.004
    double_hit_ratio: float = 0.4


@dataclass(frozen=True)
class LabNoise:
    """Transducer imperfections (standard deviations)."""

    accel_noise_ms2: float = 0.0
    force_noise_n: float = 0.0
    gauge_noise_v: float = 0.0
    gauge_drift_v_per_s: float = 0.0
    sensitivity_error: float = 0.0  # relative, per accelerometer channel
    cross_axis: float = 0.0  # fraction of the other two axes of the triax


def state_space(model: ForwardModel) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray, int]:
    """``A`` (n, n), ``B`` (n, n_in), ``C`` (n_out, n), ``D`` (n_out, n_in), n_acc outputs first.

    From the forward model's ``M z̈ + C_z ż + K z = q f`` (:meth:`ForwardModel.dynamic_matrices`,
    ``z = [U; η]``, elastic modes coupled to the rigid body through the supports) with the state
    ``x = [z; ż]``: ``A = [[0, E], [−M⁻¹K, −M⁻¹C_z]]``, ``B = [0; M⁻¹q]``. Accelerometers read
    ``S z̈ = S M⁻¹(−K z − C_z ż + q f)`` (``S`` from :meth:`ForwardModel.output_matrices` at
    ``ω² = 1``), load cells ``−sign (k_s A'_s z + c_s A'_s ż)`` with ``A'_s = B_sᵀ [G_s, Ψ_s]``.
    A free-free body (no supports) keeps only the elastic modes as states; its rigid motion is
    the direct term ``S_rb M_rb⁻¹ φ``. Outputs: every response channel (m/s²), then each
    support's 6 local loads (N, N·m) with the cell's sign.
    """
    setup = model.setup
    M, Cd, K = model.dynamic_matrices()
    q = model.input_loads()  # (n_dof, n_in)
    S = model.output_matrices(np.array([1.0 / (2 * np.pi)]))[0].real  # rows at ω = 1
    n_acc = len(setup.responses)
    n_in = q.shape[1]
    S_acc = -S[:n_acc]  # output_matrices holds −ω² S for accelerometers
    n_rc = 6 * len(model.supports)
    D = np.zeros((n_acc + n_rc, n_in))
    if not model.supports:
        # Free-free: rigid and elastic coordinates decouple (block-diagonal M, C, K).
        keep = np.arange(6, model.n_dof)
        D[:n_acc] = S_acc[:, :6] @ np.linalg.solve(M[:6, :6], q[:6])
        M, Cd, K, q, S_acc = (
            M[np.ix_(keep, keep)],
            Cd[np.ix_(keep, keep)],
            K[np.ix_(keep, keep)],
            q[keep],
            S_acc[:, keep],
        )
    n = M.shape[0]
    if n == 0:
        return np.zeros((0, 0)), np.zeros((0, n_in)), np.zeros((n_acc + n_rc, 0)), D, n_acc
    if model.supports and np.linalg.matrix_rank(K) < n:
        raise ValueError(
            "the supports do not restrain every rigid-body DOF; give each a full 6×6 stiffness"
        )
    Minv = np.linalg.inv(M)
    A = np.block([[np.zeros((n, n)), np.eye(n)], [-Minv @ K, -Minv @ Cd]])
    B = np.vstack([np.zeros((n, n_in)), Minv @ q])
    C = np.zeros((n_acc + n_rc, 2 * n))
    C[:n_acc] = S_acc @ Minv @ np.hstack([-K, -Cd])
    D[:n_acc] += S_acc @ Minv @ q
    for s_i, s in enumerate(model.supports):
        sign = 1.0 if s.sign == "on_structure" else -1.0
        Ap = s.B().T @ model._A(s.node, s.position_m)
        rows = slice(n_acc + 6 * s_i, n_acc + 6 * s_i + 6)
        C[rows] = -sign * np.hstack([s.stiffness @ Ap, s.damping @ Ap])
    return A, B, C, D, n_acc


@dataclass
class _Hit:
    input_index: int
    t_s: float  # pulse centre
    peak_n: float


@dataclass
class VirtualLab:
    """The analogue world behind the lab's sample clock; implements ``SampleSource``.

    Channels: one per response (``"1103+Y"``, m/s²), ``"hammer"`` (N, the force of whichever input
    is struck), and for each load cell ``"LC501 g01" .. "LC501 g12"`` (V) followed by
    ``"LC501 Fx" .. "LC501 Mz"`` (N, N·m: the cell's local loads before the gauges, for tests).

    Parameters
    ----------
    model : ForwardModel
        The TRUE article, supports and transducer geometry.
    sample_rate_hz : float
    hammer : Hammer
    noise : LabNoise
    gauge_sensitivity : dict node → (12, 6) V per N / N·m, optional
        Default: a seeded 4-spoke-like matrix of full rank.
    seed : int
    block_samples : int
        Internal block length (samples) of the exact block recursion.
    """

    model: ForwardModel
    sample_rate_hz: float = 2048.0
    hammer: Hammer = field(default_factory=Hammer)
    noise: LabNoise = field(default_factory=LabNoise)
    gauge_sensitivity: dict[int, FloatArray] | None = None
    seed: int = 0
    block_samples: int = 256

    def __post_init__(self) -> None:
        fs = float(self.sample_rate_hz)
        self.sigma_s = self.hammer.sigma_s if self.hammer.sigma_s is not None else 1.4 / fs
        if math.exp(-((2 * np.pi * fs / 2 * self.sigma_s) ** 2) / 2) > 1e-3:
            raise ValueError(
                f"hammer pulse sigma {self.sigma_s * 1e3:.3g} ms is too short for {fs:g} S/s: its "
                "spectrum above the Nyquist frequency aliases; use sigma ≥ 1.2/fs"
            )
        A, B, C, D, n_acc = state_space(self.model)
        self._n_acc = n_acc
        if A.shape[0]:
            lam, V = np.linalg.eig(A)
            W = np.linalg.solve(V, B)  # (P, n_in)
            CV = C @ V  # (n_out, P)
            self._lam = lam
            self._R = CV[:, None, :] * W.T[None, :, :]  # (n_out, n_in, P)
        else:
            self._lam = np.zeros(0, complex)
            self._R = np.zeros((C.shape[0], B.shape[1], 0), complex)
        self._D = D
        rng = np.random.default_rng([self.seed, 7])
        setup = self.model.setup
        # Transducer mixing: sensitivity error and cross-axis within each triax.
        n_out = D.shape[0]
        X = np.eye(n_out)
        nodes = [c.node for c in setup.responses]
        for i, node in enumerate(nodes):
            X[i, i] = 1.0 + self.noise.sensitivity_error * rng.standard_normal()
            for k, other in enumerate(nodes):
                if other == node and k != i:
                    X[i, k] = self.noise.cross_axis * rng.uniform(-1, 1)
        names = [
            c.label or f"{c.node}{'+-'[c.direction < 0]}{'XYZ'[abs(c.direction) - 1]}"
            for c in setup.responses
        ]
        units = ["m/s^2"] * n_acc
        names.append("hammer")
        units.append("N")
        rows: list[FloatArray] = [X[:n_acc]]
        hammer_row = n_acc
        self._gauge_matrix: dict[int, FloatArray] = {}
        for s_i, s in enumerate(self.model.supports):
            S = (self.gauge_sensitivity or {}).get(s.node)
            if S is None:
                S = _default_gauge_matrix(np.random.default_rng([self.seed, 11, s.node]))
            self._gauge_matrix[s.node] = np.asarray(S, float)
            sel = np.zeros((6, n_out))
            sel[:, n_acc + 6 * s_i : n_acc + 6 * s_i + 6] = np.eye(6)
            rows.append(self._gauge_matrix[s.node] @ sel)
            names += [f"LC{s.node} g{g + 1:02d}" for g in range(12)]
            units += ["V"] * 12
            rows.append(sel)
            names += [f"LC{s.node} {q}" for q in ("Fx", "Fy", "Fz", "Mx", "My", "Mz")]
            units += ["N", "N", "N", "N*m", "N*m", "N*m"]
        mix = np.vstack(rows)  # (n_channels − 1 hammer, n_out)
        self._mix = mix
        self._R_ch = np.einsum("co,ojp->cjp", mix, self._R)  # (n_ch_no_hammer, n_in, P)
        self._D_ch = mix @ D
        self._hammer_row = hammer_row
        self.channel_names = tuple(names)
        self.channel_units = tuple(units)
        self._is_gauge = np.array([u == "V" for u in units])
        self._noise_std = np.array(
            [
                self.noise.accel_noise_ms2
                if u == "m/s^2"
                else self.noise.force_noise_n
                if u == "N" and n == "hammer"
                else self.noise.gauge_noise_v
                if u == "V"
                else 0.0
                for n, u in zip(names, units, strict=True)
            ]
        )
        self._drift = np.where(
            self._is_gauge, self.noise.gauge_drift_v_per_s * rng.uniform(-1, 1, len(names)), 0.0
        )
        self._hits: list[_Hit] = []
        self._hit_rng = np.random.default_rng([self.seed, 13])
        self._carry: list[ComplexArray] = [np.zeros((len(self._lam), self._R.shape[1]), complex)]
        self._cache: OrderedDict[int, FloatArray] = OrderedDict()
        self._frontier = 0  # first sample not yet generated
        self._block_decay = np.exp(self._lam * (self.block_samples / fs))
        self.double_hits: list[int] = []

    # SampleSource ----------------------------------------------------------------------------
    @property
    def n_inputs(self) -> int:
        return self._R.shape[1]

    def channel_index(self, name: str) -> int:
        try:
            return self.channel_names.index(name)
        except ValueError as err:
            raise KeyError(
                f"virtual lab has no channel {name!r}; it has {', '.join(self.channel_names)}"
            ) from err

    def excite(self, input_index: int, at_sample: int) -> None:
        """Strike input ``input_index``; the pulse rises from ``at_sample`` (peak 6σ later)."""
        if not 0 <= input_index < self.n_inputs:
            raise ValueError(f"input index {input_index} out of range 0..{self.n_inputs - 1}")
        if at_sample < self._frontier:
            raise ValueError(
                f"cannot strike at sample {at_sample}: samples up to {self._frontier - 1} were already "
                "read; strike at or after the present sample"
            )
        fs = self.sample_rate_hz
        t = at_sample / fs + 6 * self.sigma_s
        self._hits.append(_Hit(input_index, t, self.hammer.peak_n))
        if (
            self.hammer.double_hit_probability > 0
            and self._hit_rng.uniform() < self.hammer.double_hit_probability
        ):
            self._hits.append(
                _Hit(
                    input_index,
                    t + self.hammer.double_hit_delay_s,
                    self.hammer.peak_n * self.hammer.double_hit_ratio,
                )
            )
            self.double_hits.append(at_sample)

    def read(self, channels: NDArray[np.intp], start: int, n: int) -> FloatArray:
        ch = np.asarray(channels, dtype=np.intp)
        if n <= 0:
            return np.zeros((ch.size, 0))
        if start < 0:
            raise ValueError("sample counter starts at 0")
        B = self.block_samples
        first, last = start // B, (start + n - 1) // B
        parts = [self._block(b)[ch] for b in range(first, last + 1)]
        out = np.concatenate(parts, axis=1)
        off = start - first * B
        return out[:, off : off + n]

    # Internals -------------------------------------------------------------------------------
    def _block(self, b: int) -> FloatArray:
        cached = self._cache.get(b)
        if cached is not None:
            self._cache.move_to_end(b)
            return cached
        while len(self._carry) <= b:  # advance block by block up to b (carries every boundary)
            k = len(self._carry) - 1
            if k < b and self._quiet(k):
                # No pulse touches block k and nobody reads it: only the carried free decay
                # crosses it, c ← c e^{λ T_block} (the samples are made if it is read later).
                self._carry.append(self._carry[k] * self._block_decay[:, None])
                self._frontier = (k + 1) * self.block_samples
            else:
                self._generate(k)
        data = self._generate(b)
        return data

    def _quiet(self, b: int) -> bool:
        """True if no hammer pulse (±6σ about its centre) overlaps block ``b``."""
        Bn, fs, sig = self.block_samples, self.sample_rate_hz, self.sigma_s
        t_first, t_last = b * Bn / fs, (b * Bn + Bn - 1) / fs
        return all(t_first - h.t_s > 6 * sig or t_last - h.t_s < -6 * sig for h in self._hits)

    def _generate(self, b: int) -> FloatArray:
        Bn, fs, sig = self.block_samples, self.sample_rate_hz, self.sigma_s
        t = (b * Bn + np.arange(Bn)) / fs
        t0 = b * Bn / fs
        lam = self._lam
        P = lam.size
        n_ch = len(self.channel_names)
        y = np.zeros((n_ch, Bn))
        carry = self._carry[b]
        if P:
            E = np.exp(np.outer(lam, t - t0))  # (P, Bn)
            Mx = np.einsum("cjp,pj->cp", self._R_ch, carry)
            y_ns = _real_matmul(Mx, E)
        else:
            y_ns = np.zeros((n_ch - 1, Bn))
        force = np.zeros(Bn)
        next_carry = carry * np.exp(lam * (Bn / fs))[:, None] if P else carry
        t_end = (b + 1) * Bn / fs
        amp_scale = sig * math.sqrt(2 * math.pi)
        frontier = len(self._carry) == b + 1
        for hit in self._hits:
            u = t - hit.t_s
            if u[0] > 6 * sig:  # pulse over before this block: in the carry
                continue
            if u[-1] < -6 * sig:  # not started yet
                continue
            pulse = hit.peak_n * np.exp(-0.5 * (u / sig) ** 2)
            force += pulse
            y_ns += np.outer(self._D_ch[:, hit.input_index], pulse)
            if P:
                active = u > -6 * sig
                ua = u[active]
                arg = np.outer(lam, ua) + (lam**2 * sig**2 / 2)[:, None]
                g = (
                    hit.peak_n
                    * sig
                    * math.sqrt(math.pi / 2)
                    * np.exp(arg)
                    * erfc(-(ua[None, :] + (lam * sig**2)[:, None]) / (sig * math.sqrt(2)))
                )
                y_ns[:, active] += _real_matmul(self._R_ch[:, hit.input_index, :], g)
            if frontier and P and t_end - hit.t_s > 6 * sig:  # carried from the next block on
                next_carry[:, hit.input_index] += (
                    hit.peak_n * amp_scale * np.exp(lam * (t_end - hit.t_s) + lam**2 * sig**2 / 2)
                )
        if frontier:
            self._carry.append(next_carry)
            self._frontier = (b + 1) * Bn
        y[np.arange(n_ch) != self._hammer_row] = y_ns
        y[self._hammer_row] = force
        # Noise (counter-based: block b always gets the same draws) and gauge drift.
        if np.any(self._noise_std > 0):
            rng = np.random.default_rng([self.seed, 17, b])
            y += self._noise_std[:, None] * rng.standard_normal((n_ch, Bn))
        if np.any(self._drift != 0):
            y += self._drift[:, None] * t[None, :]
        self._cache[b] = y
        if len(self._cache) > 4096:
            self._cache.popitem(last=False)
        return y

    def gauge_matrix(self, node: int) -> FloatArray:
        """The 12×6 gauge sensitivity (V per N, N·m) of load cell ``node``."""
        return self._gauge_matrix[node]


def _real_matmul(a: ComplexArray, b: ComplexArray) -> FloatArray:
    """``Re(a @ b)`` with two real products (complex GEMM is far slower on some BLAS builds)."""
    out: FloatArray = a.real @ b.real - a.imag @ b.imag
    return out


def _default_gauge_matrix(rng: np.random.Generator) -> FloatArray:
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
