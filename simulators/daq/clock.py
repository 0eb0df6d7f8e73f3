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

An **adaptive** time-lapse (``start(..., adaptive=True)``) is what a simulation may do and a real
DAQ cannot: slow down when the host falls behind. The simulated devices that buffer the pulses
(the DAQ's FIFO, an amplifier's frame queue) say how far the count may go before they would lose
data (:meth:`hold_at`); the clock never counts past the lowest of those limits (the lab waits,
its time stretched: no sample is lost), and each time it has to wait it halves its factor, at
most once per :data:`SLOW_EVERY_S` of wall time, down to :data:`MIN_SCALE`. After
:data:`RECOVER_AFTER_S` without a wait it speeds up by :data:`RECOVER_FACTOR`, at most to the
factor it started at. The count is piecewise linear in wall time,

    n(t) = n_j + (t − t_j) · rate · s_j        for t_j ≤ t < t_(j+1),

with a new segment ``(t_j, n_j, s_j)`` at each change; :meth:`run_report` gives the factors used
and the simulated and wall seconds of the run.
"""

from __future__ import annotations

import logging
import threading
import time
from dataclasses import dataclass

__all__ = [
    "MIN_SCALE",
    "RECOVER_AFTER_S",
    "RECOVER_FACTOR",
    "SLOW_EVERY_S",
    "ClockState",
    "RunReport",
    "SampleClock",
    "run_log",
]

#: where each free-running run's :class:`RunReport` is logged (DEBUG, ``extra={"run_report": r}``)
run_log = logging.getLogger("dimacq.simulators.time_lapse")

#: the lowest factor an adaptive time-lapse slows to (simulated seconds per wall second)
MIN_SCALE = 0.25
#: wall seconds between two slow-downs (one preemption does not halve the factor twice)
SLOW_EVERY_S = 1.0
#: wall seconds without a wait before an adaptive time-lapse speeds up again
RECOVER_AFTER_S = 4.0
#: the speed-up after :data:`RECOVER_AFTER_S` without a wait
RECOVER_FACTOR = 1.5


@dataclass(frozen=True)
class ClockState:
    """A snapshot: ``run`` counts runs (START) since creation; ``count`` pulses in this run."""

    run: int
    running: bool
    epoch: int
    count: int
    sample_rate_hz: float


@dataclass(frozen=True)
class RunReport:
    """A free-running run: its pulses, wall seconds, the factors it used (in order) and how
    often and how long an adaptive clock waited for the host."""

    run: int
    pulses: int
    sample_rate_hz: float
    wall_s: float
    factors: tuple[float, ...]
    waits: int
    adaptive: bool

    @property
    def simulated_s(self) -> float:
        return self.pulses / self.sample_rate_hz if self.sample_rate_hz else 0.0

    @property
    def effective_scale(self) -> float:
        """Simulated seconds per wall second over the whole run."""
        return self.simulated_s / self.wall_s if self.wall_s > 0 else 0.0


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
        self._adaptive = False
        self._start_scale = 0.0
        self._seg_t = 0.0  # the present segment: wall time, count (float) and factor at its start
        self._seg_n = 0.0
        self._segments: list[tuple[float, float, float]] = []
        self._limits: dict[str, int] = {}
        self._factors: list[float] = []
        self._waits = 0
        self._last_slow = -1e9
        self._last_wait = 0.0
        self._last_report: RunReport | None = None
        self.source_lock = threading.RLock()

    def start(
        self,
        epoch: int,
        sample_rate_hz: float,
        *,
        wall_scale: float | None = None,
        adaptive: bool = False,
    ) -> None:
        """Start a run at world sample ``epoch``; free-running at ``wall_scale`` (None: the
        host's reads clock it, :meth:`advance`), slowing down for the host when ``adaptive``."""
        with self._cond:
            self._run += 1
            self._running = True
            self._epoch = epoch
            self._count = 0
            self._rate = sample_rate_hz
            self._wall_scale = wall_scale
            self._t0 = time.monotonic()
            self._adaptive = bool(adaptive) and wall_scale is not None
            self._start_scale = wall_scale or 0.0
            self._seg_t, self._seg_n = self._t0, 0.0
            self._segments = [(self._t0, 0.0, wall_scale or 0.0)]
            self._limits = {}
            self._factors = [wall_scale] if wall_scale is not None else []
            self._waits = 0
            self._last_slow = -1e9
            self._last_wait = self._t0
            self._cond.notify_all()

    def _new_segment(self, now: float, n: float, scale: float) -> None:
        self._seg_t, self._seg_n, self._wall_scale = now, n, scale
        self._segments.append((now, n, scale))
        if scale != self._factors[-1]:
            self._factors.append(scale)

    def _tick(self) -> None:
        """Free-running: the count of now (call with the lock held)."""
        if not (self._running and self._wall_scale is not None):
            return
        now = time.monotonic()
        x = self._seg_n + (now - self._seg_t) * self._rate * self._wall_scale
        if self._adaptive:
            limit = min(self._limits.values(), default=None)
            if limit is not None and x > limit:
                # a device would lose data: the lab waits for the host, slower from now on
                scale = self._wall_scale
                if now - self._last_slow >= SLOW_EVERY_S:
                    scale = max(MIN_SCALE, scale / 2)
                    self._last_slow = now
                self._waits += 1
                self._last_wait = now
                x = float(max(limit, self._count))
                self._new_segment(now, x, scale)
            elif self._wall_scale < self._start_scale and now - self._last_wait >= RECOVER_AFTER_S:
                self._last_wait = now  # the next speed-up after as long again
                self._new_segment(now, x, min(self._start_scale, self._wall_scale * RECOVER_FACTOR))
        n = int(x)
        if n > self._count:
            self._count = n

    def hold_at(self, who: str, limit: int | None) -> None:
        """Adaptive clock: device ``who`` loses data past count ``limit`` of this run (None: it
        no longer limits the clock)."""
        with self._cond:
            if limit is None:
                self._limits.pop(who, None)
            else:
                self._limits[who] = int(limit)

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
            if self._running and self._factors:
                self._last_report = RunReport(
                    self._run,
                    self._count,
                    self._rate,
                    time.monotonic() - self._t0,
                    tuple(self._factors),
                    self._waits,
                    self._adaptive,
                )
                r = self._last_report
                run_log.debug(
                    "simulated DAQ run %d: %.2f s simulated in %.2f s wall, factors %s, %d waits",
                    r.run,
                    r.simulated_s,
                    r.wall_s,
                    "/".join(f"{f:g}" for f in r.factors),
                    r.waits,
                    extra={"run_report": r},
                )
            self._running = False
            self._limits = {}
            self._cond.notify_all()
            return self._count

    def run_report(self) -> RunReport | None:
        """The last free-running run that stopped (None before one has)."""
        with self._cond:
            return self._last_report

    def position_at(self, t_monotonic: float) -> float | None:
        """The world's sample position (fractional) at wall time ``t_monotonic`` while a
        free-running run clocks (None otherwise): ``epoch + (t − t0) × rate × scale``. What a
        sensor on its own clock reads the world at (the lab's physical time, not a device's)."""
        with self._cond:
            if not self._running or self._wall_scale is None:
                return None
            t_j, n_j, s_j = self._segments[-1]
            for seg in reversed(self._segments):
                t_j, n_j, s_j = seg
                if seg[0] <= t_monotonic:
                    break
            return self._epoch + n_j + (t_monotonic - t_j) * self._rate * s_j

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
