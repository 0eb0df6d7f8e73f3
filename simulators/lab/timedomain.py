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
local ``[f; m]`` through a 12×6 sensitivity matrix: AC-coupled (piezo-like, volts, with noise and
a slow zero drift; the loads are the dynamic part only) or, for the cells given in ``bridges``,
DC-coupled strain-gauge bridges in mV/V (:mod:`dimacq.simulators.lab.bridge`: they also carry
the static load of gravity on the article, their zero offset and its temperature drift, and the
nonlinearity of the cell).
"""

from __future__ import annotations

import math
from collections import OrderedDict
from dataclasses import dataclass, field
from functools import lru_cache
from typing import Literal

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation
from scipy.special import erfc

from dimacq.errors import SetupError
from dimacq.model.channels import N_GAUGES, axis_name, gauge_names, load_names
from dimacq.simulators.lab.bridge import BridgeState, StrainGaugeCell, default_gauge_matrix
from dimacq.simulators.lab.forward import ForwardModel

__all__ = [
    "Hammer",
    "LabNoise",
    "ShakerSignal",
    "VirtualLab",
    "foh_coefficients",
    "modal_foh_filter",
    "state_space",
    "static_support_loads",
]

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
    line_of_action_error_deg : float
        Standard deviation of each strike's angle from the input's line of action, degrees
        (a new random direction per strike, seeded).
    """

    peak_n: float = 200.0
    sigma_s: float | None = None
    double_hit_probability: float = 0.0
    double_hit_delay_s: float = 0.004
    double_hit_ratio: float = 0.4
    line_of_action_error_deg: float = 0.0


@dataclass(frozen=True)
class LabNoise:
    """Transducer imperfections (standard deviations)."""

    accel_noise_ms2: float = 0.0
    force_noise_n: float = 0.0
    gauge_noise_v: float = 0.0
    gauge_drift_v_per_s: float = 0.0
    sensitivity_error: float = 0.0  # relative, per accelerometer channel
    cross_axis: float = 0.0  # fraction of the other two axes of the triax


def state_space(
    model: ForwardModel, loads: FloatArray | None = None
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray, int]:
    """``A`` (n, n), ``B`` (n, n_in), ``C`` (n_out, n), ``D`` (n_out, n_in), n_acc outputs first.

    ``loads`` (n_dof, n_in) replaces the setup's inputs by other generalised forces (e.g. unit
    forces along X, Y, Z at each input point, :meth:`ForwardModel.generalised_loads`).

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
    q = model.input_loads() if loads is None else np.asarray(loads, float)  # (n_dof, n_in)
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


@dataclass(frozen=True)
class ShakerSignal:
    """The drive of one shaker (force at its stinger, N), defined on the lab's sample clock.

    The shaker amplifier's DAC updates at the lab's sample rate; between its samples the force
    is linear (first-order hold), which the lab integrates exactly (:func:`foh_coefficients`).
    ``rel`` below counts samples from the start of the drive; record ``r = rel // record_samples``
    holds position ``p = rel % record_samples``.

    Attributes
    ----------
    kind : {"random", "burst-random", "swept-sine"}
        ``random``: Gaussian samples of rms ``level_n`` (counter-based, reproducible per
        ``seed``), white or, with ``band_limited``, Gaussian white noise through a linear-phase
        FIR band-pass ``f_lo_hz``–``f_hi_hz`` (Hamming, transition about ``f_lo_hz / 2``, taps
        normalised to ``Σh² = 1``) so that suspension modes below the band are hardly driven
        (their response would leak into the band through the analysis window); periodic:
        an exact band mask on one record's spectrum; ``burst-random``: the same during the first ``burst_fraction`` of each record,
        zero for the rest (the response decays inside the record); ``swept-sine``: one chirp per
        record, ``level_n · sin φ(t)``, ``t = p / fs``, ``T_r = record_samples / fs``, linear
        ``φ = 2π (f_lo t + (f_hi − f_lo) t² / (2 T_r))`` or logarithmic
        ``φ = 2π f_lo (e^{k t} − 1) / k``, ``k = ln(f_hi / f_lo) / T_r``.
    level_n : float
        RMS force of the random kinds, amplitude of the sine, N.
    record_samples : int
        Record (burst, sweep and period) length in samples.
    periodic : bool
        Random kinds: repeat the same realisation every record (periodic random).
    burst_fraction : float
        Fraction of each record driven (burst random), 0–1.
    f_lo_hz, f_hi_hz : float
        Sweep range; band of the random kinds if ``band_limited``.
    band_limited : bool
        Random kinds: band-pass the noise to ``f_lo_hz``–``f_hi_hz``.
    sweep : {"linear", "log"}
    polarity : tuple of float
        Factor on record ``r``: ``polarity[r % len(polarity)]`` (a Hadamard row per shaker makes
        simultaneous sweeps of several shakers separable).
    seed : int
        Seed of the random kinds (give each shaker its own: independent signals).
    """

    kind: Literal["random", "burst-random", "swept-sine"] = "random"
    level_n: float = 20.0
    record_samples: int = 4096
    periodic: bool = False
    burst_fraction: float = 0.5
    f_lo_hz: float = 2.0
    f_hi_hz: float = 400.0
    sweep: Literal["linear", "log"] = "linear"
    polarity: tuple[float, ...] = (1.0,)
    seed: int = 0
    band_limited: bool = False

    def __post_init__(self) -> None:
        if self.kind not in ("random", "burst-random", "swept-sine"):
            raise SetupError(
                f"shaker signal kind {self.kind!r} is unknown; use random, burst-random or swept-sine"
            )
        if self.record_samples < 2:
            raise SetupError(f"shaker record_samples = {self.record_samples}; give at least 2")
        if not 0 < self.burst_fraction <= 1:
            raise SetupError(f"shaker burst_fraction = {self.burst_fraction}; give 0 < it ≤ 1")
        if not 0 < self.f_lo_hz < self.f_hi_hz:
            raise SetupError(
                f"shaker sweep {self.f_lo_hz}–{self.f_hi_hz} Hz; give 0 < f_lo_hz < f_hi_hz"
            )
        if self.sweep not in ("linear", "log"):
            raise SetupError(f"shaker sweep {self.sweep!r} is unknown; use linear or log")
        if not self.polarity:
            raise SetupError("shaker polarity is empty; give at least one factor, e.g. (1.0,)")

    def samples(self, rel: NDArray[np.int64], sample_rate_hz: float) -> FloatArray:
        """Force at samples ``rel ≥ 0`` counted from the start of the drive, N."""
        from scipy.signal import oaconvolve  # lazy: scipy.signal is slow to import

        rel = np.asarray(rel, dtype=np.int64)
        N = self.record_samples
        rec, pos = np.divmod(rel, N)
        pol = np.asarray(self.polarity, float)[rec % len(self.polarity)]
        if self.kind == "swept-sine":
            t, Tr = pos / sample_rate_hz, N / sample_rate_hz
            f0, f1 = self.f_lo_hz, self.f_hi_hz
            if self.sweep == "linear":
                ph = 2 * np.pi * (f0 * t + (f1 - f0) * t**2 / (2 * Tr))
            else:
                k = math.log(f1 / f0) / Tr
                ph = 2 * np.pi * f0 * np.expm1(k * t) / k
            out: FloatArray = self.level_n * np.sin(ph) * pol
            return out
        if not self.band_limited:
            v = _white(self.seed, pos if self.periodic else rel)
        elif self.periodic:
            v = _periodic_band_noise(self.seed, N, self.f_lo_hz, self.f_hi_hz, sample_rate_hz)[pos]
        else:
            h = _band_fir(self.f_lo_hz, self.f_hi_hz, sample_rate_hz)
            lo, hi = int(rel.min()) - h.size + 1, int(rel.max())
            m = np.arange(lo, hi + 1, dtype=np.int64)
            w = np.where(m >= 0, _white(self.seed, np.maximum(m, 0)), 0.0)
            v = oaconvolve(w, h, mode="valid")[rel - int(rel.min())]
        v = v * self.level_n
        if self.kind == "burst-random":
            v = v * (pos < round(self.burst_fraction * N))
        return np.asarray(v * pol, dtype=np.float64)


_CHUNK = 4096


@lru_cache(maxsize=16)
def _band_fir(f_lo_hz: float, f_hi_hz: float, fs: float) -> FloatArray:
    """Band-pass FIR taps (Hamming window, ``Σh² = 1``), transition about ``f_lo / 2``."""
    from scipy.signal import firwin  # lazy: scipy.signal is slow to import

    n = math.ceil(3.3 * fs / (0.5 * f_lo_hz)) | 1
    n = min(n, 1 << 15 | 1)
    h = firwin(n, [f_lo_hz, min(f_hi_hz, 0.49 * fs)], pass_zero=False, fs=fs)
    h = h / np.sqrt(np.sum(h**2))
    h.flags.writeable = False
    return np.asarray(h, dtype=np.float64)


@lru_cache(maxsize=64)
def _periodic_band_noise(
    seed: int, n: int, f_lo_hz: float, f_hi_hz: float, fs: float
) -> FloatArray:
    """One record of periodic band-limited noise (unit rms): white noise, spectrum masked."""
    spec = np.fft.rfft(_white(seed, np.arange(n, dtype=np.int64)))
    f = np.arange(spec.size) * fs / n
    spec[(f < f_lo_hz) | (f > f_hi_hz)] = 0.0
    v = np.fft.irfft(spec, n)
    v = v / np.sqrt(np.mean(v**2))
    v.flags.writeable = False
    return np.asarray(v, dtype=np.float64)


@lru_cache(maxsize=64)
def _noise_chunk(seed: int, chunk: int) -> FloatArray:
    arr = np.random.default_rng([seed, 61, chunk]).standard_normal(_CHUNK)
    arr.flags.writeable = False
    return arr


def _white(seed: int, m: NDArray[np.int64]) -> FloatArray:
    """Unit Gaussian white samples at counters ``m`` (counter-based: the same ``m``, the same value)."""
    out = np.empty(m.shape)
    chunks = m // _CHUNK
    for c in np.unique(chunks):
        sel = chunks == c
        out[sel] = _noise_chunk(seed, int(c))[m[sel] % _CHUNK]
    return out


def _phi(x: ComplexArray, k: int) -> ComplexArray:
    """``φ_k(x) = Σ_{i≥0} x^i / (i + k)!`` (``φ_1 = (eˣ − 1)/x``, ``φ_2 = (eˣ − 1 − x)/x²``),
    by its series for small ``|x|`` and the closed form elsewhere."""
    x = np.asarray(x, complex)
    small = np.abs(x) < 0.1
    xs = np.where(small, x, 0.0)
    series = np.zeros_like(x)
    term = np.full_like(x, 1.0 / math.factorial(k))
    for i in range(14):
        series += term
        term = term * xs / (i + k + 1)
    xl = np.where(small, 1.0, x)
    closed = np.expm1(xl) / xl if k == 1 else (np.expm1(xl) - xl) / xl**2
    return np.where(small, series, closed)


def foh_coefficients(lam: ComplexArray, dt_s: float) -> tuple[ComplexArray, ComplexArray]:
    """``(β0, β1)`` of the exact discrete update of ``ż = λ z + u(t)`` under a first-order hold.

    Between ``t_n`` and ``t_{n+1} = t_n + T`` let ``u(t_n + s) = u_n + (u_{n+1} − u_n) s / T``.
    Variation of constants gives

        z_{n+1} = e^{λT} z_n + ∫₀ᵀ e^{λ(T−s)} u(t_n + s) ds = e^{λT} z_n + β0 u_n + β1 u_{n+1}

    with ``I0 = ∫₀ᵀ e^{λ(T−s)} ds = (e^{λT} − 1)/λ = T φ1(λT)`` and
    ``I1 = (1/T) ∫₀ᵀ e^{λ(T−s)} s ds = (e^{λT} − 1 − λT)/(λ² T) = T φ2(λT)``:
    ``β1 = I1 = T φ2(λT)``, ``β0 = I0 − I1 = T (φ1(λT) − φ2(λT))``. Exact for any ``λ`` (no
    approximation beyond the hold itself); ``φ_k`` by series for ``|λT| < 0.1`` (no cancellation).

    Parameters
    ----------
    lam : ndarray, shape (P,), complex
        Poles, 1/s.
    dt_s : float
        Step ``T``, s.

    Returns
    -------
    beta0, beta1 : ndarray, shape (P,), complex
    """
    x: ComplexArray = np.asarray(np.asarray(lam, complex) * dt_s, dtype=np.complex128)
    p1, p2 = _phi(x, 1), _phi(x, 2)
    return dt_s * (p1 - p2), dt_s * p2


def modal_foh_filter(
    lam: ComplexArray, u: FloatArray, dt_s: float, zi: ComplexArray | None = None
) -> tuple[ComplexArray, ComplexArray]:
    """States ``z_p[n]`` of ``ż_p = λ_p z_p + u(t)`` for a first-order-hold input, exactly.

    ``z[n] = e^{λT} z[n−1] + β1 u[n] + β0 u[n−1]`` (:func:`foh_coefficients`) is the IIR filter
    ``b = [β1, β0]``, ``a = [1, −e^{λT}]`` run by :func:`scipy.signal.lfilter` per pole (complex
    coefficients) on all rows of ``u`` at once.

    Parameters
    ----------
    lam : (P,) complex
    u : (R, N) float
        Input samples (rows: independent inputs), the hold's knots at ``t = n T``.
    dt_s : float
    zi : (P, R) complex, optional
        Filter state from the previous call (``β0 u_last + e^{λT} z_last``: the state at the
        next sample if the input stays zero); zero: input and state zero before ``u[:, 0]``.

    Returns
    -------
    z : (P, R, N) complex
    zf : (P, R) complex
        State to pass as ``zi`` to the call for the following samples.
    """
    from scipy.signal import lfilter  # lazy: scipy.signal is slow to import

    lam = np.asarray(lam, complex)
    u = np.atleast_2d(np.asarray(u, float))
    P, (R, N) = lam.size, u.shape
    b0, b1 = foh_coefficients(lam, dt_s)
    a = np.exp(lam * dt_s)
    z = np.empty((P, R, N), complex)
    zf = np.empty((P, R), complex)
    z0 = np.zeros((P, R), complex) if zi is None else np.asarray(zi, complex)
    for p in range(P):
        z[p], f = lfilter([b1[p], b0[p]], [1.0, -a[p]], u, axis=-1, zi=z0[p][:, None])
        zf[p] = f[:, 0]
    return z, zf


def _modal_residues(
    A: FloatArray, B: FloatArray, C: FloatArray
) -> tuple[ComplexArray, ComplexArray]:
    """Poles ``λ`` (P,) of ``A = V Λ V⁻¹`` and residues ``R_obp = (C V)_op (V⁻¹ B)_pb``
    (n_out, n_basis, P); none for a model without states."""
    if not A.shape[0]:
        return np.zeros(0, complex), np.zeros((C.shape[0], B.shape[1], 0), complex)
    lam, V = np.linalg.eig(A)
    W = np.linalg.solve(V, B)  # (P, n_basis)
    CV = C @ V  # (n_out, P)
    return lam, CV[:, None, :] * W.T[None, :, :]  # (n_out, n_basis, P)


@dataclass
class _Hit:
    input_index: int
    t_s: float  # pulse centre
    peak_n: float
    weights: FloatArray  # (n_basis,): the force's components in the lab's input basis
    R: ComplexArray  # (n_phys, P) residues of this strike
    Dv: FloatArray  # (n_phys,) direct term of this strike


@dataclass
class _Drive:
    shaker: int
    input_index: int
    signal: ShakerSignal
    start: int  # force 0 at `start`, ramping to the signal's sample 1 at start + 1
    stop: int | None  # force 0 from `stop` on
    weights: FloatArray
    R: ComplexArray  # (n_phys, P)
    Dv: FloatArray  # (n_phys,)
    retired: int | None = None  # first block whose carry holds this drive's free decay


@dataclass
class VirtualLab:
    """The analogue world behind the lab's sample clock; implements ``SampleSource``.

    Channels: one per response (``"1103+Y"``, m/s²), ``"hammer"`` (N, the force of whichever input
    is struck), and for each load cell ``"LC501 g01" .. "LC501 g12"`` (V, or mV/V for a
    strain-gauge cell of ``bridges``) followed by
    ``"LC501 Fx" .. "LC501 Mz"`` (N, N·m: the cell's local loads before the gauges, for tests),
    then ``"shaker1" .. "shakerN"`` (N, each shaker's force) if ``n_shakers > 0``.

    Shakers (:meth:`drive`): shaker ``k`` drives an input with a :class:`ShakerSignal` whose samples
    are joined by a first-order hold. Each pole is a first-order recursion, integrated exactly
    for that force (:func:`modal_foh_filter`) at ``oversample × fs``; an anti-alias low-pass
    (Butterworth, order 8, at 0.45 fs) then acts alike on the shaker force and on every response
    before decimation to ``fs``, as the DAQ's filter does: it removes the hold's spectral images,
    so the ratio of response to measured force is ``H(iω)`` on the lines below the cut-off,
    up to the images above ``oversample × fs / 2`` that alias (relative weight about
    ``(f / (oversample · fs))²``). Some time after a drive stops, its state joins the carried free
    decay of the hammer strikes (``c ← c + L(e^{λT}) z``, ``L`` the filter's gain on that decay).

    Parameters
    ----------
    model : ForwardModel
        The TRUE article, supports and transducer geometry.
    sample_rate_hz : float
    hammer : Hammer
    noise : LabNoise
    gauge_sensitivity : dict node → (12, 6) V per N / N·m, optional
        Default: a seeded 4-spoke-like matrix of full rank.
    bridges : dict node → StrainGaugeCell, optional
        Load cells with DC-coupled strain-gauge bridges (mV/V); their ``sensitivity_mvv`` is the
        cell's gauge matrix. The others are AC-coupled (piezo-like, V).
    gravity_mps2 : float
        Gravity along −Z of the GCS: the static load the bridges carry (the article's weight
        shared by the supports, from the supports' static stiffness).
    seed : int
    block_samples : int
        Internal block length (samples) of the exact block recursion.
    n_shakers : int
        Shakers (force channels) available to :meth:`drive`.
    oversample : int
        Internal rate factor of the shaker integration.
    anti_alias : bool
        Apply the anti-alias low-pass to shaker signals (off: the raw first-order-hold response
        at the sample instants, exact, for tests).
    cache_blocks : int
        Blocks kept for re-reading (older ones are recomputed from the stored block states).
    """

    model: ForwardModel
    sample_rate_hz: float = 2048.0
    hammer: Hammer = field(default_factory=Hammer)
    noise: LabNoise = field(default_factory=LabNoise)
    gauge_sensitivity: dict[int, FloatArray] | None = None
    seed: int = 0
    block_samples: int = 256
    n_shakers: int = 0
    oversample: int = 4
    anti_alias: bool = True
    cache_blocks: int = 4096
    bridges: dict[int, StrainGaugeCell] | None = None
    gravity_mps2: float = 9.80665

    def __post_init__(self) -> None:
        fs = float(self.sample_rate_hz)
        self.sigma_s = self.hammer.sigma_s if self.hammer.sigma_s is not None else 1.4 / fs
        if math.exp(-((2 * np.pi * fs / 2 * self.sigma_s) ** 2) / 2) > 1e-3:
            raise ValueError(
                f"hammer pulse sigma {self.sigma_s * 1e3:.3g} ms is too short for {fs:g} S/s: its "
                "spectrum above the Nyquist frequency aliases; use sigma ≥ 1.2/fs"
            )
        if self.n_shakers < 0 or self.oversample < 1 or self.cache_blocks < 1:
            raise ValueError("n_shakers ≥ 0, oversample ≥ 1 and cache_blocks ≥ 1 are required")
        setup = self.model.setup
        n_in = len(setup.excitations)
        self._dirs = np.asarray(setup.input_directions, float).reshape(n_in, 3)
        loads, W_in = self._input_basis()
        self._W_in = W_in  # (n_basis, n_in): input j in the basis
        A, B, C, D, n_acc = state_space(self.model, loads)
        self._n_acc = n_acc
        self._lam, R_basis = _modal_residues(A, B, C)  # R_basis: (n_out, n_basis, P)
        self._R = np.einsum("obp,bj->ojp", R_basis, W_in)  # (n_out, n_in, P)
        self._D = D @ W_in
        rng = np.random.default_rng([self.seed, 7])
        n_out = D.shape[0]
        X = self._transducer_mixing(rng, n_out)
        names = [c.label or axis_name(c.node, c.direction) for c in setup.responses]
        units = ["m/s^2"] * n_acc
        names.append("hammer")
        units.append("N")
        rows: list[FloatArray] = [X[:n_acc]]
        hammer_row = n_acc
        bridges = dict(self.bridges or {})
        rows += self._load_cell_rows(bridges, n_out, names, units)
        self._shaker_rows = np.arange(len(names), len(names) + self.n_shakers)
        names += [f"shaker{k + 1}" for k in range(self.n_shakers)]
        units += ["N"] * self.n_shakers
        mix = np.vstack(rows)  # (n_phys = channels − hammer − shakers, n_out)
        self._mix = mix
        self._R_ch = np.einsum("co,obp->cbp", mix, R_basis)  # (n_phys, n_basis, P)
        self._D_ch = mix @ D  # (n_phys, n_basis)
        self._hammer_row = hammer_row
        phys = np.ones(len(names), bool)
        phys[hammer_row] = False
        phys[self._shaker_rows] = False
        self._phys_rows = np.flatnonzero(phys)
        self.channel_names = tuple(names)
        self.channel_units = tuple(units)
        self._is_gauge = np.array([u == "V" for u in units])  # AC-coupled gauges
        self._noise_std = self._channel_noise(names, units, bridges)
        self._drift = np.where(
            self._is_gauge, self.noise.gauge_drift_v_per_s * rng.uniform(-1, 1, len(names)), 0.0
        )
        self._hits: list[_Hit] = []
        self._hit_rng = np.random.default_rng([self.seed, 13])
        self._loa_rng = np.random.default_rng([self.seed, 19])
        self.hit_directions: list[FloatArray] = []
        n_basis = W_in.shape[0]
        self._carry: list[ComplexArray] = [np.zeros((len(self._lam), n_basis), complex)]
        self._cache: OrderedDict[int, FloatArray] = OrderedDict()
        self._frontier = 0  # first sample not yet generated
        self._block_decay = np.exp(self._lam * (self.block_samples / fs))
        # e^{λ (t − t0)} over one block: the same for every block (t − t0 = k / fs)
        self._block_exp = np.exp(np.outer(self._lam, np.arange(self.block_samples) / fs))
        self.double_hits: list[int] = []
        self._shaker_filter(fs)
        self._drives: list[_Drive] = []
        self._sh_state: list[dict[int, tuple[ComplexArray, ComplexArray | None]]] = [{}]

    def _input_basis(self) -> tuple[FloatArray | None, FloatArray]:
        """The generalised loads of the lab's input basis (None: the inputs themselves) and
        ``W_in`` (n_basis, n_in), input ``j`` in that basis.

        With a line-of-action error the basis is unit forces along X, Y, Z at each input point:
        responses are linear in the force direction, so a strike along ``d`` has the residues
        ``Σ_a d_a R_{·,3j+a}``.
        """
        setup = self.model.setup
        n_in = len(setup.excitations)
        if self.hammer.line_of_action_error_deg <= 0:
            return None, np.eye(n_in)
        loads = self.model.generalised_loads(
            [e.node for e in setup.excitations for _ in range(3)],
            np.repeat(np.asarray(setup.input_positions, float).reshape(n_in, 3), 3, axis=0),
            np.tile(np.eye(3), (n_in, 1)),
        )
        W_in = np.zeros((3 * n_in, n_in))
        for j in range(n_in):
            W_in[3 * j : 3 * j + 3, j] = self._dirs[j]
        return loads, W_in

    def _transducer_mixing(self, rng: np.random.Generator, n_out: int) -> FloatArray:
        """``X`` (n_out, n_out): each accelerometer's sensitivity error on the diagonal and
        the cross-axis sensitivity to the other axes of its own triax."""
        X = np.eye(n_out)
        nodes = [c.node for c in self.model.setup.responses]
        for i, node in enumerate(nodes):
            X[i, i] = 1.0 + self.noise.sensitivity_error * rng.standard_normal()
            for k, other in enumerate(nodes):
                if other == node and k != i:
                    X[i, k] = self.noise.cross_axis * rng.uniform(-1, 1)
        return X

    def _load_cell_rows(
        self,
        bridges: dict[int, StrainGaugeCell],
        n_out: int,
        names: list[str],
        units: list[str],
    ) -> list[FloatArray]:
        """Rows of the channel mix (n_out columns) for each load cell: its 12 gauges ``S F``
        (V, or mV/V for a strain-gauge cell of ``bridges``), then its 6 local loads; appends
        their names and units and sets the cells' gauge matrices and bridge states (hung
        long before the test, under the article's weight)."""
        n_acc = self._n_acc
        rows: list[FloatArray] = []
        self._gauge_matrix: dict[int, FloatArray] = {}
        unknown = sorted(set(bridges) - {s.node for s in self.model.supports})
        if unknown:
            raise ValueError(f"bridges for load cells {unknown} that the model does not have")
        preload = static_support_loads(self.model, self.gravity_mps2) if bridges else None
        #: strain-gauge cells: node → (state, gauge channel rows, load channel rows)
        self._bridges: dict[int, tuple[BridgeState, NDArray[np.intp], NDArray[np.intp]]] = {}
        n_rows = n_acc + 1
        for s_i, s in enumerate(self.model.supports):
            S = (self.gauge_sensitivity or {}).get(s.node)
            cell = bridges.get(s.node)
            if cell is not None:
                S = cell.sensitivity_mvv
            if S is None:
                # A property of the cell (its serial number), not of the test: the same in every run.
                S = default_gauge_matrix(np.random.default_rng([11, s.node]))
            self._gauge_matrix[s.node] = np.asarray(S, float)
            sel = np.zeros((6, n_out))
            sel[:, n_acc + 6 * s_i : n_acc + 6 * s_i + 6] = np.eye(6)
            rows.append(self._gauge_matrix[s.node] @ sel)
            names += gauge_names(s.node)
            units += ["V" if cell is None else "mV/V"] * N_GAUGES
            if cell is not None:
                assert preload is not None
                state = BridgeState(cell)
                state.place(preload[s_i], -1e9, settle=True)  # hung long before the test
                self._bridges[s.node] = (
                    state,
                    np.arange(n_rows, n_rows + N_GAUGES),
                    np.arange(n_rows + N_GAUGES, n_rows + N_GAUGES + 6),
                )
            n_rows += N_GAUGES + 6
            rows.append(sel)
            names += load_names(s.node)
            units += ["N", "N", "N", "N*m", "N*m", "N*m"]
        return rows

    def _channel_noise(
        self, names: list[str], units: list[str], bridges: dict[int, StrainGaugeCell]
    ) -> FloatArray:
        """Noise standard deviation of each channel, by its unit (and a bridge's own)."""
        return np.array(
            [
                self.noise.accel_noise_ms2
                if u == "m/s^2"
                else self.noise.force_noise_n
                if u == "N" and (n == "hammer" or n.startswith("shaker"))
                else self.noise.gauge_noise_v
                if u == "V"
                else bridges[int(n[2 : n.index(" ")])].noise_mvv
                if u == "mV/V"
                else 0.0
                for n, u in zip(names, units, strict=True)
            ]
        )

    def _shaker_filter(self, fs: float) -> None:
        """The shakers' integration step ``1/(K fs)``, the anti-alias low-pass (Butterworth,
        order 8, at 0.45 fs; None when off or without shakers) and its gain ``L(e^{λ T_int})``
        on each pole's free decay."""
        K = self.oversample
        self._dt_int = 1.0 / (K * fs)
        self._sos: FloatArray | None = None
        if self.anti_alias and self.n_shakers:
            # here: scipy.signal, with the scipy.stats and scipy.optimize it loads, holds about
            # 40 MB that an impact test's simulator does not need
            from scipy.signal import butter

            self._sos = butter(8, 0.45 * fs, fs=K * fs, output="sos")
        if self._sos is not None:
            zq = np.exp(self._lam * self._dt_int) ** -1
            num = self._sos[:, 0, None] + self._sos[:, 1, None] * zq + self._sos[:, 2, None] * zq**2
            den = self._sos[:, 3, None] + self._sos[:, 4, None] * zq + self._sos[:, 5, None] * zq**2
            self._decay_gain = np.prod(num / den, axis=0)  # L(e^{λ T_int}), (P,)
        else:
            self._decay_gain = np.ones(len(self._lam), complex)

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

    def _weights(self, w: FloatArray) -> tuple[FloatArray, ComplexArray, FloatArray]:
        """A force with basis components ``w``: its residues (n_phys, P) and direct term."""
        return w, np.einsum("cbp,b->cp", self._R_ch, w), self._D_ch @ w

    @property
    def frontier(self) -> int:
        """The first sample not yet read by anyone (a strike can start here or later)."""
        return int(self._frontier)

    def excite(self, input_index: int, at_sample: int) -> None:
        """Strike input ``input_index``; the pulse rises from ``at_sample`` (peak 6σ later).

        With ``hammer.line_of_action_error_deg`` each strike's direction is the input's turned by
        an angle ``N(0, σ)`` about a random axis normal to it (seeded; kept in
        :attr:`hit_directions`).
        """
        if not 0 <= input_index < self.n_inputs:
            raise ValueError(f"input index {input_index} out of range 0..{self.n_inputs - 1}")
        if at_sample < self._frontier:
            raise ValueError(
                f"cannot strike at sample {at_sample}: samples up to {self._frontier - 1} were already "
                "read; strike at or after the present sample"
            )
        fs = self.sample_rate_hz
        t = at_sample / fs + 6 * self.sigma_s
        d = self._dirs[input_index]
        if self.hammer.line_of_action_error_deg > 0:
            axis = self._loa_rng.normal(size=3)
            axis -= (axis @ d) * d
            axis /= np.linalg.norm(axis)
            ang = np.deg2rad(self.hammer.line_of_action_error_deg) * self._loa_rng.standard_normal()
            d_hit = Rotation.from_rotvec(ang * axis).apply(d)
            w = np.zeros(self._W_in.shape[0])
            w[3 * input_index : 3 * input_index + 3] = d_hit
        else:
            d_hit = d
            w = self._W_in[:, input_index].copy()
        self.hit_directions.append(np.asarray(d_hit, float))
        hit_w = self._weights(w)
        self._hits.append(_Hit(input_index, t, self.hammer.peak_n, *hit_w))
        if (
            self.hammer.double_hit_probability > 0
            and self._hit_rng.uniform() < self.hammer.double_hit_probability
        ):
            self._hits.append(
                _Hit(
                    input_index,
                    t + self.hammer.double_hit_delay_s,
                    self.hammer.peak_n * self.hammer.double_hit_ratio,
                    *hit_w,
                )
            )
            self.double_hits.append(at_sample)

    def drive(
        self,
        shaker: int,
        input_index: int,
        signal: ShakerSignal,
        at_sample: int,
        until_sample: int | None = None,
    ) -> None:
        """Shaker ``shaker`` drives input ``input_index`` (along its line of action) with
        ``signal`` from ``at_sample`` (force 0 there, the signal's samples after it) until
        ``until_sample`` (force 0 from there on; default: until the shaker's next drive).

        A shaker's earlier open drive ends at ``at_sample``. Drives of different shakers
        superpose (multiple-input test).
        """
        if not 0 <= shaker < self.n_shakers:
            raise ValueError(
                f"shaker {shaker} does not exist; this lab has {self.n_shakers} (n_shakers)"
            )
        if not 0 <= input_index < self.n_inputs:
            raise ValueError(f"input index {input_index} out of range 0..{self.n_inputs - 1}")
        if at_sample < self._frontier:
            raise ValueError(
                f"cannot drive from sample {at_sample}: samples up to {self._frontier - 1} were "
                "already read; start at or after the present sample"
            )
        if until_sample is not None and until_sample <= at_sample:
            raise ValueError(f"until_sample {until_sample} must come after at_sample {at_sample}")
        for d in self._drives:
            if d.shaker == shaker and (d.stop is None or d.stop > at_sample):
                if d.start >= at_sample:
                    raise ValueError(
                        f"shaker {shaker} already has a drive from sample {d.start}; schedule "
                        "drives in time order"
                    )
                if at_sample <= self._frontier:
                    raise ValueError(
                        f"shaker {shaker} is driving; end its drive after sample {self._frontier}"
                    )
                d.stop = at_sample
        w = self._W_in[:, input_index].copy()
        self._drives.append(
            _Drive(shaker, input_index, signal, int(at_sample), until_sample, *self._weights(w))
        )

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
                self._sh_state.append({})
                self._frontier = (k + 1) * self.block_samples
            else:
                self._generate(k)
        data = self._generate(b)
        return data

    def _live(self, b: int) -> list[int]:
        """Drives whose force or un-retired state touches block ``b``."""
        end = (b + 1) * self.block_samples
        return [
            i
            for i, d in enumerate(self._drives)
            if d.start < end and (d.retired is None or b < d.retired)
        ]

    def _quiet(self, b: int) -> bool:
        """True if no hammer pulse (±6σ about its centre) and no shaker drive touches block ``b``."""
        Bn, fs, sig = self.block_samples, self.sample_rate_hz, self.sigma_s
        t_first, t_last = b * Bn / fs, (b * Bn + Bn - 1) / fs
        return not self._live(b) and all(
            t_first - h.t_s > 6 * sig or t_last - h.t_s < -6 * sig for h in self._hits
        )

    def _drive_force(self, d: _Drive, n: NDArray[np.int64]) -> FloatArray:
        rel = n - d.start
        on = (rel > 0) & (n < (d.stop if d.stop is not None else np.iinfo(np.int64).max))
        u = np.zeros(n.shape)
        if np.any(on):
            u[on] = d.signal.samples(rel[on], self.sample_rate_hz)
        return u

    def _shakers(
        self, b: int, frontier: bool, next_carry: ComplexArray
    ) -> tuple[FloatArray, FloatArray] | None:
        """Shaker contributions to block ``b``: (n_phys, Bn) responses, (n_shakers, Bn) forces.

        At the frontier, stores the drives' states for block ``b + 1`` and hands the free decay
        of drives stopped more than a block ago to ``next_carry``.
        """
        live = self._live(b)
        if not live:
            if frontier:
                self._sh_state.append({})
            return None
        from scipy.signal import sosfilt  # here: only a shaker's drive needs scipy.signal

        Bn, K, lam = self.block_samples, self.oversample, self._lam
        P, S = lam.size, len(live)
        n0 = b * Bn
        n = n0 + np.arange(Bn + 1, dtype=np.int64)  # one look-ahead sample for the hold
        U = np.stack([self._drive_force(self._drives[i], n) for i in live])  # (S, Bn+1)
        if K > 1:
            frac = np.arange(K) / K
            Ui = (U[:, :-1, None] * (1 - frac) + U[:, 1:, None] * frac).reshape(S, Bn * K)
        else:
            Ui = U[:, :-1]
        states = self._sh_state[b]
        n_sec = 0 if self._sos is None else self._sos.shape[0]
        zl = np.zeros((P, S), complex)
        zs = np.zeros((n_sec, S, P + 1, 2), complex)
        for s, i in enumerate(live):
            st = states.get(i)
            if st is not None:
                zl[:, s] = st[0]
                if st[1] is not None:
                    zs[:, s] = st[1]
        X = np.empty((S, P + 1, Bn * K), complex)
        if P:
            z, zl_next = modal_foh_filter(lam, Ui, self._dt_int, zl)
            X[:, :P] = z.transpose(1, 0, 2)
        else:
            zl_next = zl
        X[:, P] = Ui
        zs_next = zs
        if self._sos is not None:
            X, zs_next = sosfilt(self._sos, X, axis=-1, zi=zs)
        Xd = X[:, :, ::K]  # (S, P+1, Bn) at the lab's samples
        Rcat = np.concatenate([self._drives[i].R for i in live], axis=1)  # (n_phys, S·P)
        y = _real_matmul(Rcat, Xd[:, :P].reshape(S * P, Bn)) if P else 0.0
        Dcat = np.stack([self._drives[i].Dv for i in live], axis=1)  # (n_phys, S)
        y = y + Dcat @ Xd[:, P].real
        force = np.zeros((self.n_shakers, Bn))
        for s, i in enumerate(live):
            force[self._drives[i].shaker] += Xd[s, P].real
        if frontier:
            nxt: dict[int, tuple[ComplexArray, ComplexArray | None]] = {}
            for s, i in enumerate(live):
                d = self._drives[i]
                if d.stop is not None and d.stop + Bn <= n0:
                    # Force off for over a block: the filter's transient is gone and the state
                    # is a free decay, carried like a hammer strike's.
                    next_carry += np.outer(self._decay_gain * zl_next[:, s], d.weights)
                    d.retired = b + 1
                else:
                    nxt[i] = (zl_next[:, s].copy(), None if n_sec == 0 else zs_next[:, s].copy())
            self._sh_state.append(nxt)
        return np.asarray(y, float), force

    def _generate(self, b: int) -> FloatArray:
        Bn, fs, sig = self.block_samples, self.sample_rate_hz, self.sigma_s
        t = (b * Bn + np.arange(Bn)) / fs
        lam = self._lam
        P = lam.size
        n_ch = len(self.channel_names)
        y = np.zeros((n_ch, Bn))
        carry = self._carry[b]
        n_phys = self._phys_rows.size
        if P:
            E = self._block_exp  # e^{λ (t − t0)}, (P, Bn)
            Mx = np.einsum("cjp,pj->cp", self._R_ch, carry)
            y_ns = _real_matmul(Mx, E)
        else:
            y_ns = np.zeros((n_phys, Bn))
        force = np.zeros(Bn)
        next_carry = carry * np.exp(lam * (Bn / fs))[:, None] if P else carry.copy()
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
            y_ns += np.outer(hit.Dv, pulse)
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
                y_ns[:, active] += _real_matmul(hit.R, g)
            if frontier and P and t_end - hit.t_s > 6 * sig:  # carried from the next block on
                amp = hit.peak_n * amp_scale * np.exp(lam * (t_end - hit.t_s) + lam**2 * sig**2 / 2)
                next_carry += np.outer(amp, hit.weights)
        shaken = self._shakers(b, frontier, next_carry)
        if shaken is not None:
            y_ns += shaken[0]
            y[self._shaker_rows] = shaken[1]
        if frontier:
            self._carry.append(next_carry)
            self._frontier = (b + 1) * Bn
        y[self._phys_rows] = y_ns
        y[self._hammer_row] = force
        for state, g_rows, f_rows in self._bridges.values():
            # DC-coupled bridges: static level + dynamic load, through the cell's nonlinearity.
            y[g_rows] = state.readings(t, y[f_rows])
        # Noise (counter-based: block b always gets the same draws) and gauge drift.
        if np.any(self._noise_std > 0):
            rng = np.random.default_rng([self.seed, 17, b])
            y += self._noise_std[:, None] * rng.standard_normal((n_ch, Bn))
        if np.any(self._drift != 0):
            y += self._drift[:, None] * t[None, :]
        self._cache[b] = y
        if len(self._cache) > self.cache_blocks:
            self._cache.popitem(last=False)
        return y

    def gauge_matrix(self, node: int) -> FloatArray:
        """The 12×6 gauge sensitivity (V per N, N·m) of load cell ``node``."""
        return self._gauge_matrix[node]


def static_support_loads(model: ForwardModel, gravity_mps2: float) -> FloatArray:
    """Each support's local load (n_supports, 6) under gravity ``g`` along −Z of the GCS.

    The article's weight ``w = m g (−ẑ)`` at its CG is the generalised force
    ``q = [w; c × w; 0]``; statics ``K z = q`` with the supports' stiffness, and each cell reads
    ``−sign K_s A'_s z`` (:func:`state_space`'s load cell rows with ``ż = 0``): the steady
    output ``y = (D − C A⁻¹ B) q``.
    """
    props = model.properties
    w = np.array([0.0, 0.0, -props.mass_kg * gravity_mps2])
    q = np.zeros((model.n_dof, 1))
    q[:3, 0] = w
    q[3:6, 0] = np.cross(np.asarray(props.cg_m, float), w)
    A, B, C, D, n_acc = state_space(model, q)
    y = D - C @ np.linalg.solve(A, B) if A.shape[0] else D
    return np.asarray(y[n_acc:, 0].reshape(-1, 6), dtype=np.float64)


def _real_matmul(a: ComplexArray, b: ComplexArray) -> FloatArray:
    """``Re(a @ b)`` with two real products (complex GEMM is far slower on some BLAS builds)."""
    out: FloatArray = a.real @ b.real - a.imag @ b.imag
    return out
