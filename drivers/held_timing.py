"""What a CAN load cell's own free-running sampling does to its FRFs, and what is left.

A Net F/T or a CiA 404 amplifier does not sample at the request or the SYNC: it samples on its
own clock, period ``T``, and answers with the value it last produced (after its filter, group
delay ``d``). Its clock and the DAQ's are unrelated, so the age ``τ`` of the value held at a
request is uniform over ``[0, T)`` and independent of the signal. Sample ``k`` is then
``y_k = x(t_k − d − τ_k)``, and its expected spectrum is

    E[e^{−jωτ}] = (1 − e^{−jωT}) / (jωT) = e^{−jωT/2} · sinc(fT),   sinc(u) = sin(πu)/(πu)

so the cell's FRF carries a **known** factor ``R(f) = F(f) · e^{−jωT/2} · sinc(fT)`` (``F`` the
filter's response; a moving average of ``N`` own samples:
``F = e^{−jω(N−1)T/2} · sin(πfNT) / (N sin(πfT))``): a mean delay ``d + T/2`` and a magnitude
that are removed by dividing by ``R`` (:meth:`HeldSampleTiming.response`).

What is not removable is each sample's own age about its mean, ``τ − T/2``: uniform over
``[−T/2, T/2)``, standard deviation ``T/√12``, a phase error of ``ω(τ − T/2)`` on that sample.
Its cost at the band's top ``f`` is taken as that per-sample spread,

    σ_φ = 360 · f · T / √12   degrees

(a bound: it is noise, uncorrelated between samples, and averages down across records) and
compared with the phase budget (:meth:`HeldSampleTiming.check`): above it the run is refused.
At the Net F/T's 7000 S/s (T = 142.9 µs) σ_φ is 2° at 135 Hz and 9.7° at 655 Hz.

Where the two rates are commensurate (a DAQ at exactly 1000 S/s and the device at exactly 7000)
the age is one constant of ``[0, T)`` instead of a spread: an unknown delay of the same
``T/√12`` standard deviation about the removed mean, which does not average down. The same
bound covers both.

The age could be recovered per sample from the device's sample numbers (its clock's phase and
rate fitted against the requests); that is not done here.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from dimacq.errors import SetupError

__all__ = ["HeldSampleTiming"]


@dataclass(frozen=True)
class HeldSampleTiming:
    """A device sampling on its own clock at ``rate_hz``, answering with its last value after a
    moving average of ``average_n`` of its samples (1: no filter).

    Attributes
    ----------
    rate_hz : float
        Its own sample rate, Hz (``T = 1 / rate_hz``).
    average_n : int
        Samples its filter averages (1: none).
    label : str
        The device, for messages.
    """

    rate_hz: float
    average_n: int = 1
    label: str = "load cell"

    @property
    def period_s(self) -> float:
        return 1.0 / self.rate_hz

    @property
    def filter_delay_s(self) -> float:
        """The moving average's group delay ``(N − 1) T / 2``, s."""
        return (self.average_n - 1) * self.period_s / 2.0

    @property
    def mean_delay_s(self) -> float:
        """``d + T/2``, s: removed with :meth:`response`."""
        return self.filter_delay_s + self.period_s / 2.0

    @property
    def spread_s(self) -> float:
        """``T / √12``, s: the held value's age about its mean (not removable)."""
        return self.period_s / np.sqrt(12.0)

    def phase_std_deg(self, f_hz: float | NDArray[np.float64]) -> NDArray[np.float64]:
        """``360 f T / √12``, degrees."""
        return np.asarray(360.0 * np.asarray(f_hz, dtype=float) * self.spread_s)

    def response(self, f_hz: NDArray[np.float64]) -> NDArray[np.complex128]:
        """``R(f) = F(f) e^{−jωT/2} sinc(fT)``: the expected factor on the cell's FRFs."""
        f = np.asarray(f_hz, dtype=float)
        T, N = self.period_s, self.average_n
        hold = np.exp(-1j * np.pi * f * T) * np.sinc(f * T)
        den = N * np.sin(np.pi * f * T)
        ratio = np.where(
            np.abs(den) > 1e-12, np.sin(np.pi * f * N * T) / np.where(den == 0, 1, den), 1.0
        )
        filt = np.exp(-1j * np.pi * f * (N - 1) * T) * ratio
        return np.asarray(filt * hold, dtype=np.complex128)

    def highest_band_hz(self, max_phase_deg: float) -> float:
        """The band's top at which ``σ_φ`` equals ``max_phase_deg``, Hz."""
        return float(max_phase_deg / (360.0 * self.spread_s))

    def check(self, band_hz: float, max_phase_deg: float, *, where: str) -> float:
        """``σ_φ`` at ``band_hz``, degrees, or :class:`SetupError` when above the budget."""
        phase = float(self.phase_std_deg(band_hz))
        if not phase <= max_phase_deg:
            raise SetupError(
                f"{where}: {self.label} samples on its own clock at {self.rate_hz:g} S/s and "
                f"answers with its last value: that value's age (0..{1e6 * self.period_s:.1f} "
                f"us, std {1e6 * self.spread_s:.1f} us about its removed mean) costs "
                f"{phase:.1f} deg of FRF phase at {band_hz:g} Hz, above the budget of "
                f"{max_phase_deg:g} deg; analyse up to {self.highest_band_hz(max_phase_deg):.0f} "
                "Hz, raise the device's own sample rate where it can be set, or read the cell's "
                "outputs as DAQ inputs (loadcell = 'daq-channels')"
            )
        return phase
