"""Physics of the 3D sonic digitizer in the virtual lab (method.md §1).

A hand-held probe carries two ultrasonic emitters on one line; the tip lies on that line a known
distance ``L_tip`` beyond emitter 1::

    p_e1 = p_tip - L_tip * u,      p_e2 = p_tip - (L_tip + s) * u,      |u| = 1

where ``u`` points from emitter 2 towards the tip and ``s`` is the emitter spacing. A receiver
array of ``M`` microphones at ``m_k`` (digitizer array coordinate system, DACS, metres) hears each
emitter. A calibration bar (emitter and receiver a fixed ``L_bar`` apart) is fired with every shot.

The speed of sound in dry air at temperature ``T`` (°C) is

    c(T) = 331.3 * sqrt(1 + T / 273.15)  m/s.

A hardware counter clocked at ``f_clk`` starts when an emitter fires and stops when its pulse
arrives; it also counts a fixed electronic delay ``tau_0``::

    n_ek = floor((tau_0 + |p_e - m_k| / c + eps) * f_clk),     eps ~ N(0, sigma_t²)

(floor: the counter counts whole clock periods; the decoder takes the middle of the period).
With averaging ``A`` each emitter fires ``A`` times and the counter reports the sum of the ``A``
counts. Echoes and reverberation: with probability ``echo_probability`` a shot is corrupted, one to
three of its emitter × microphone paths arrive late by an extra path uniform in
``echo_extra_path_m`` (the thesis saw jumps of up to 8 feet, 2.44 m). The bar is fired
``n_bar`` times per shot; it may echo too (``bar_echo_probability``). A path longer than
``max_range_m`` gives no arrival: the counter saturates at ``2**counter_bits - 1``.

Everything here is pure physics over numpy arrays; the wire protocol lives in the simulator.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

__all__ = [
    "SonicArray",
    "SonicEnvironment",
    "SonicLab",
    "SonicProbe",
    "SonicShot",
    "default_array",
    "speed_of_sound_m_s",
]

FloatArray = NDArray[np.float64]


def speed_of_sound_m_s(temperature_c: float | FloatArray) -> float | FloatArray:
    """Speed of sound in dry air, ``c = 331.3 sqrt(1 + T/273.15)`` m/s, ``T`` in °C."""
    return 331.3 * np.sqrt(1.0 + np.asarray(temperature_c, dtype=float) / 273.15)


@dataclass(frozen=True)
class SonicArray:
    """The receiver array and the counter electronics.

    Attributes
    ----------
    microphones_m : ndarray, shape (M, 3)
        Microphone positions in the DACS, metres.
    bar_length_m : float
        Emitter-to-receiver distance of the calibration bar.
    delay_s : float
        Fixed electronic delay ``tau_0`` included in every counter value.
    clock_hz : float
        Counter clock.
    counter_bits : int
        Counter width; the saturated value ``2**bits - 1`` means "no arrival".
    max_range_m : float
        Longest path that still gives an arrival.
    """

    microphones_m: FloatArray
    bar_length_m: float = 1.0
    delay_s: float = 50e-6
    clock_hz: float = 10e6
    counter_bits: int = 24
    max_range_m: float = 6.0

    @property
    def counter_max(self) -> int:
        return int(2**self.counter_bits - 1)


@dataclass(frozen=True)
class SonicProbe:
    """Probe geometry: emitter spacing ``s`` and tip distance ``L_tip`` beyond emitter 1 (metres)."""

    emitter_spacing_m: float = 0.12
    tip_length_m: float = 0.06

    def emitters_m(self, tip_m: FloatArray, axis: FloatArray) -> FloatArray:
        """Emitter positions, shape (2, 3), for a tip at ``tip_m`` and unit axis ``u`` (e2 → tip)."""
        u = np.asarray(axis, dtype=float)
        u = u / np.linalg.norm(u)
        tip = np.asarray(tip_m, dtype=float)
        return np.stack(
            [tip - self.tip_length_m * u, tip - (self.tip_length_m + self.emitter_spacing_m) * u]
        )


@dataclass
class SonicEnvironment:
    """Air and acoustics: temperature, timing noise, echoes (mutable: the lab changes)."""

    temperature_c: float = 20.0
    timing_noise_s: float = 0.1e-3 / 343.0  # ~0.1 mm of path at 20 °C
    echo_probability: float = 0.0
    echo_extra_path_m: tuple[float, float] = (0.05, 2.44)
    bar_echo_probability: float = 0.0


@dataclass(frozen=True)
class SonicShot:
    """One simulated shot: raw counter values and the truth behind them.

    Attributes
    ----------
    counts : ndarray of int64, shape (E, M)
        Summed counter values (``A`` firings) per emitter × microphone.
    bar_counts : ndarray of int64, shape (B,)
        Counter value of each calibration bar firing.
    echo : bool
        True when at least one path (probe or bar) arrived late by an echo.
    overflow : ndarray of bool, shape (E,)
        Emitter had at least one path with no arrival (counter saturated).
    bar_overflow : bool
    emitters_m : ndarray, shape (E, 3)
        True emitter positions.
    speed_m_s : float
        True speed of sound.
    """

    counts: NDArray[np.int64]
    bar_counts: NDArray[np.int64]
    echo: bool
    overflow: NDArray[np.bool_]
    bar_overflow: bool
    emitters_m: FloatArray
    speed_m_s: float


@dataclass
class SonicLab:
    """The digitizer corner of the virtual lab: array, probe, air, and where the probe is held."""

    array: SonicArray
    probe: SonicProbe = field(default_factory=SonicProbe)
    environment: SonicEnvironment = field(default_factory=SonicEnvironment)
    tip_m: FloatArray = field(default_factory=lambda: np.array([0.0, 0.0, 1.0]))
    axis: FloatArray = field(default_factory=lambda: np.array([0.0, 0.0, 1.0]))

    def place_probe(self, tip_m: FloatArray, axis: FloatArray) -> None:
        """The virtual operator holds the probe tip at ``tip_m`` with unit axis ``axis`` (e2 → tip)."""
        axis = np.asarray(axis, dtype=float)
        norm = float(np.linalg.norm(axis))
        if not np.isfinite(norm) or norm == 0.0:
            raise ValueError("probe axis has zero length; give a direction vector")
        self.tip_m = np.asarray(tip_m, dtype=float).copy()
        self.axis = axis / norm

    def _counts(
        self, path_m: FloatArray, c: float, averaging: int, rng: np.random.Generator
    ) -> NDArray[np.int64]:
        """Summed counts for paths ``path_m`` (any shape) fired ``averaging`` times."""
        clk = self.array.clock_hz
        tau = self.array.delay_s + path_m / c
        noise = rng.normal(
            0.0, self.environment.timing_noise_s, size=(averaging, *np.shape(path_m))
        )
        per_firing = np.floor((tau + noise) * clk).astype(np.int64)
        return per_firing.sum(axis=0)

    def shot(
        self,
        rng: np.random.Generator,
        *,
        n_emitters: int = 2,
        n_microphones: int | None = None,
        averaging: int = 1,
        n_bar: int = 4,
    ) -> SonicShot:
        """Fire one shot with the probe where it is held; return the counter values."""
        env = self.environment
        mics = self.array.microphones_m[: n_microphones or len(self.array.microphones_m)]
        c = float(speed_of_sound_m_s(env.temperature_c))
        emitters = self.probe.emitters_m(self.tip_m, self.axis)[:n_emitters]
        path = np.linalg.norm(emitters[:, None, :] - mics[None, :, :], axis=-1)
        echo = False
        if rng.random() < env.echo_probability:
            echo = True
            n_paths = int(rng.integers(1, 4))
            flat = rng.choice(path.size, size=min(n_paths, path.size), replace=False)
            path = path.copy()
            path.flat[flat] += rng.uniform(*env.echo_extra_path_m, size=flat.size)
        counts = self._counts(path, c, averaging, rng)
        no_arrival = path > self.array.max_range_m
        counts[no_arrival] = self.array.counter_max
        bar_path = np.full(n_bar, self.array.bar_length_m)
        if n_bar and rng.random() < env.bar_echo_probability:
            echo = True
            bar_path[int(rng.integers(n_bar))] += rng.uniform(*env.echo_extra_path_m)
        bar_counts = self._counts(bar_path, c, 1, rng)
        return SonicShot(
            counts=counts,
            bar_counts=bar_counts,
            echo=echo,
            overflow=no_arrival.any(axis=1),
            bar_overflow=False,
            emitters_m=emitters,
            speed_m_s=c,
        )


def default_array(spacing_m: float = 1.0) -> SonicArray:
    """A planar square array of four microphones, ``spacing_m`` apart, in the DACS plane z = 0."""
    h = spacing_m / 2
    mics = np.array([[-h, -h, 0.0], [h, -h, 0.0], [h, h, 0.0], [-h, h, 0.0]])
    return SonicArray(microphones_m=mics)
