"""A cheap in-memory DAQ for the trigger-wait test and benchmark: the session's own cost shows.

``BlockDaq`` implements :class:`dimacq.devices.daq.Daq` over no device: every block is the same
preallocated zero array (so the DAQ side costs nothing), except the blocks that hold a hammer hit
scheduled by :meth:`BlockDaq.strike`: a 1 kN impulse on channel 0 and a decaying response on
the others. It clocks exactly what is read.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from dimacq.devices.daq import DaqBlock, DaqEvent


class BlockDaq:
    def __init__(self, n_channels: int, sample_rate_hz: float, block_samples: int) -> None:
        self.sample_rate_hz: float | None = sample_rate_hz
        self.events: list[DaqEvent] = []
        self.samples_clocked: int | None = None
        self._names = ("0+X force", *(f"{k}+Z" for k in range(1, n_channels)))
        self._zeros = np.zeros((n_channels, block_samples))
        self._valid = np.ones(block_samples, dtype=bool)
        self._over = np.zeros((n_channels, block_samples), dtype=bool)
        self._next = 0
        self._running = False
        self.hits: list[int] = []
        self.on_read: Callable[[], None] | None = None

    @property
    def channel_names(self) -> tuple[str, ...]:
        return self._names

    @property
    def running(self) -> bool:
        return self._running

    def strike(self, at_sample: int) -> None:
        self.hits.append(at_sample)

    def add_accel_channel(self, *a: object, **k: object) -> None:  # fixed channels
        raise NotImplementedError

    add_force_channel = add_accel_channel

    def configure_timing(self, sample_rate_hz: float, samples_per_frame: int = 256) -> None:
        self.sample_rate_hz = sample_rate_hz

    def identify(self) -> object:
        return "BlockDaq"

    def start(self) -> None:
        self._running, self._next, self.samples_clocked = True, 0, None

    def stop(self) -> None:
        self._running = False
        self.samples_clocked = self._next

    def read(self, n_samples: int, timeout_s: float | None = None) -> DaqBlock:
        if self.on_read is not None:
            self.on_read()
        first = self._next
        self._next += n_samples
        data = self._zeros[:, :n_samples] if n_samples <= self._zeros.shape[1] else None
        hits = [h for h in self.hits if first - 4096 < h < first + n_samples]
        if data is None or hits:
            k = first + np.arange(n_samples)
            data = np.zeros((len(self._names), n_samples))
            for h in hits:
                data[0] += 1000.0 * (k == h)
                lag = np.maximum(k - h, 0)
                data[1:] += (k >= h) * np.exp(-lag / 200.0) * np.sin(0.3 * lag)
        assert self.sample_rate_hz is not None
        return DaqBlock(
            first,
            self.sample_rate_hz,
            self._names,
            ("N", *("m/s^2",) * (len(self._names) - 1)),
            data,
            self._over[:, :n_samples],
            self._valid[:n_samples],
        )

    def read_available(self, timeout_s: float | None = None) -> DaqBlock:
        return self.read(self._zeros.shape[1], timeout_s)

    def read_buffered(self) -> DaqBlock | None:
        return None

    def samples_clocked_now(self) -> int | None:
        return self._next  # it clocks exactly what is read
