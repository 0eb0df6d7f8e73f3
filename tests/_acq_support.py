"""Test support for the acquisition tests: a deterministic SampleSource and a leak check.

``ImpulseSource`` is a small virtual lab with a closed-form answer: the force channel of each
input carries a Kronecker impulse of amplitude ``A`` at every excitation sample, and each
response channel is the sum of those impulses through a known two-pole digital resonator
``1 / (1 − 2 r cos θ z⁻¹ + r² z⁻²)``, whose impulse response is
``h[k] = r^k sin((k + 1) θ) / sin θ`` (k ≥ 0), times ``response_gain``, and whose FRF is ``scipy.signal.freqz``. A
background of sines (distinct frequency per channel) plus optional extra channels (``"V"``
gauges, each a fixed mix of the responses) make every channel distinguishable.
"""

from __future__ import annotations

import threading
from collections.abc import Iterator
from pathlib import Path

import can.interfaces.virtual
import numpy as np
import pytest


class ImpulseSource:
    def __init__(
        self,
        sample_rate_hz: float = 2048.0,
        n_inputs: int = 1,
        n_responses: int = 3,
        n_gauges: int = 0,
        amplitude_n: float = 100.0,
        background: float = 0.0,
        response_gain: float = 0.01,
    ) -> None:
        self.sample_rate_hz = sample_rate_hz
        self.n_inputs = n_inputs
        self.n_responses = n_responses
        self.n_gauges = n_gauges
        self.amplitude = amplitude_n
        self.background = background
        self.gain = response_gain
        names = [f"{10 + j}+X force" for j in range(n_inputs)]
        names += [f"{100 + k}+Z" for k in range(n_responses)]
        names += [f"LC1 g{g + 1:02d}" for g in range(n_gauges)]
        units = ["N"] * n_inputs + ["m/s^2"] * n_responses + ["V"] * n_gauges
        self.channel_names = tuple(names)
        self.channel_units = tuple(units)
        # resonator per (response, input)
        self.r = 0.995 - 0.002 * np.arange(n_responses)[:, None] - 0.001 * np.arange(n_inputs)
        self.theta = (
            2
            * np.pi
            * (60.0 + 25 * np.arange(n_responses)[:, None] + 7 * np.arange(n_inputs))
            / sample_rate_hz
        )
        rng = np.random.default_rng(42)
        self.gauge_mix = rng.standard_normal((n_gauges, n_responses)) * 0.01
        self.hits: list[tuple[int, int]] = []
        self.lock = threading.Lock()

    def excite(self, input_index: int, at_sample: int) -> None:
        with self.lock:
            self.hits.append((input_index, at_sample))

    def frf(self, freqs_hz: np.ndarray) -> np.ndarray:
        """Closed-form FRFs, shape (n_lines, n_responses, n_inputs)."""
        z1 = np.exp(-2j * np.pi * freqs_hz / self.sample_rate_hz)[:, None, None]
        return self.gain / (1 - 2 * self.r * np.cos(self.theta) * z1 + self.r**2 * z1**2)

    def _responses(self, start: int, n: int) -> np.ndarray:
        k = start + np.arange(n)
        out = np.zeros((self.n_responses, n))
        with self.lock:
            hits = list(self.hits)
        for j, at in hits:
            lag = k - at
            pos = lag >= 0
            r = self.r[:, j : j + 1]
            th = self.theta[:, j : j + 1]
            lg = lag[pos][None, :]
            out[:, pos] += self.gain * self.amplitude * r**lg * np.sin((lg + 1) * th) / np.sin(th)
        return out

    def read(self, channels: np.ndarray, start: int, n: int) -> np.ndarray:
        k = start + np.arange(n)
        ni, _nr = self.n_inputs, self.n_responses
        force = np.zeros((ni, n))
        with self.lock:
            hits = list(self.hits)
        for j, at in hits:
            if start <= at < start + n:
                force[j, at - start] += self.amplitude
        resp = self._responses(start, n)
        gauges = self.gauge_mix @ resp
        allc = np.concatenate([force, resp, gauges])
        ch = np.asarray(channels)
        bg = self.background * np.sin(
            2 * np.pi * (3.0 + 1.37 * ch[:, None]) * k[None, :] / self.sample_rate_hz
        )
        return allc[ch] + bg


@pytest.fixture
def no_leaks(no_thread_leaks: None) -> Iterator[None]:
    """Fail the test if it leaves python-can virtual channels open (and, through the suite's
    ``no_thread_leaks``, threads)."""
    yield
    with can.interfaces.virtual.channels_lock:
        open_channels = list(can.interfaces.virtual.channels)
    assert not open_channels, f"test left python-can virtual channels open: {open_channels}"


def calibration_scale(rig_path: Path, *, chain: bool = True) -> float:
    """``(true/used of the hammer) × mean(certificate/true of the accelerometers)`` of the rig
    file ``rig_path`` over the simulated transducers: the factor the rig file's calibration
    errors put on a mass measured from accelerances (first order; the CG, a ratio, does not
    carry it). The hammer's used sensitivity is the certificate's times its recorded chain
    factor (``chain=False``: the certificate's alone)."""
    from dimacq.io.rig_file import load_rig_file
    from dimacq.simulators.lab import transducers as tr

    rf = load_rig_file(rig_path)
    (h,) = rf.hammers
    hammer = tr.true_sensitivity(
        tr.NOMINAL_HAMMER_MV_PER_N, tr.HAMMER_TOLERANCE, tr.hammer_serial(h.physical_channel)
    )
    accel = [
        r.sensitivity_mv_per_g
        / tr.true_sensitivity(
            tr.NOMINAL_ACCEL_MV_PER_G,
            tr.ACCEL_TOLERANCE,
            tr.accelerometer_serial(r.physical_channel),
        )
        for r in rf.responses
    ]
    used = h.effective_sensitivity_mv_per_n if chain else h.sensitivity_mv_per_n
    return float(hammer / used * np.mean(accel))
