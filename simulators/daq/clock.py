"""The DAQ's sample clock as seen on its SYNC output: what the load cell amplifier counts.

In the lab a cable carries the DAQ's sample clock to the load cell amplifier, which counts its
pulses; nothing else is shared. :class:`SampleClock` is that cable for the simulators: the DAQ
simulator drives it (start at a position of the lab's world, advance per sample clocked, stop),
the load cell simulator observes it. ``epoch`` is the :class:`~dimacq.simulators.lab.source.
SampleSource` counter of pulse 0 of the present run, so ``epoch + k`` is the world's sample at
pulse ``k``. ``source_lock`` serialises the two simulators' reads of the shared source.

A free-running clock (``start(..., wall_scale=s)``) pulses in wall time whoever looks: its count
is ``(now − t0) × rate × s`` while it runs, whether the DAQ's host reads or not, and
:meth:`stop` freezes it at the count of that instant (returned, so the DAQ reports exactly what
the amplifiers counted).
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass

__all__ = ["ClockState", "SampleClock"]


@dataclass(frozen=True)
class ClockState:
    """A snapshot: ``run`` counts runs (START) since creation; ``count`` pulses in this run."""

    run: int
    running: bool
    epoch: int
    count: int
    sample_rate_hz: float


class SampleClock:
    """Pulses of the DAQ sample clock, observable from another thread."""

    def __init__(self) -> None:
        self._cond = threading.Condition()
        self._run = 0
        self._running = False
        self._epoch = 0
        self._count = 0
        self._rate = 0.0
        self._wall_scale: float | None = None
        self._t0 = 0.0
        self.source_lock = threading.RLock()

    def start(self, epoch: int, sample_rate_hz: float, *, wall_scale: float | None = None) -> None:
        with self._cond:
            self._run += 1
            self._running = True
            self._epoch = epoch
            self._count = 0
            self._rate = sample_rate_hz
            self._wall_scale = wall_scale
            self._t0 = time.monotonic()
            self._cond.notify_all()

    def _tick(self) -> None:
        """Free-running: the count of now (call with the lock held)."""
        if self._running and self._wall_scale is not None:
            n = int((time.monotonic() - self._t0) * self._rate * self._wall_scale)
            if n > self._count:
                self._count = n

    def count(self) -> int:
        """Pulses of this run so far."""
        with self._cond:
            self._tick()
            return self._count

    def advance(self, count: int) -> None:
        """The clock has produced ``count`` pulses in this run."""
        with self._cond:
            self._count = count
            self._cond.notify_all()

    def stop(self) -> int:
        """Stop; return the pulses of the run (frozen)."""
        with self._cond:
            self._tick()
            self._running = False
            self._cond.notify_all()
            return self._count

    def position_at(self, t_monotonic: float) -> float | None:
        """The world's sample position (fractional) at wall time ``t_monotonic`` while a
        free-running run clocks (None otherwise): ``epoch + (t − t0) × rate × scale``. What a
        sensor on its own clock reads the world at (the lab's physical time, not a device's)."""
        with self._cond:
            if not self._running or self._wall_scale is None:
                return None
            return self._epoch + (t_monotonic - self._t0) * self._rate * self._wall_scale

    def pulses_per_wall_s(self) -> float | None:
        """Free-running: pulses per wall second (``rate × scale``); None while it does not
        run on its own (stopped, or clocked by the host's reads)."""
        with self._cond:
            if not self._running or self._wall_scale is None:
                return None
            return self._rate * self._wall_scale

    def state(self) -> ClockState:
        with self._cond:
            self._tick()
            return ClockState(self._run, self._running, self._epoch, self._count, self._rate)

    def wait_change(self, seen: ClockState, timeout_s: float) -> ClockState:
        """Block until the clock differs from ``seen`` (or the timeout), return the new state."""
        with self._cond:

            def changed() -> bool:
                self._tick()
                return (self._run, self._running, self._count) != (
                    seen.run,
                    seen.running,
                    seen.count,
                )

            if self._wall_scale is not None and self._running:
                # nobody notifies wall-time pulses: look again every 2 ms
                end = time.monotonic() + timeout_s
                while not changed() and time.monotonic() < end:
                    self._cond.wait(min(0.002, end - time.monotonic()))
            else:
                self._cond.wait_for(changed, timeout_s)
            return ClockState(self._run, self._running, self._epoch, self._count, self._rate)

    def notify(self) -> None:
        """Wake every waiter (used by observers shutting down)."""
        with self._cond:
            self._cond.notify_all()
