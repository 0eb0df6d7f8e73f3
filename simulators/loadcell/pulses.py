"""The sample pulses of a SYNC-counting load cell amplifier simulator (the CAN FD one,
:mod:`dimacq.simulators.loadcell.amplifier`, and the CANopen one,
:mod:`dimacq.simulators.canopen_loadcell.amplifier`).

An amplifier armed on the DAQ's SYNC output takes one sample per clock pulse of the DAQ's run
that follows the arming (``external``); on its internal clock it takes ``rate_hz × time_scale``
samples per wall second from arming. The simulator thread sends frames for the pulses seen and
not yet sent, ``chunk`` at a time. A thread that fell behind its own internal clock lets the
oscillator slip (at most ``max_lag`` pulses of backlog) rather than queueing frames no real
amplifier would have.
"""

from __future__ import annotations

import time

from dimacq.simulators.daq.clock import SampleClock

__all__ = ["BURST_PULSES", "BURST_S", "SyncPulses"]

#: wall time between two bursts of frames once a simulator has caught up with its clock, s. A
#: real amplifier sends each sample as it is taken; the simulator sends the pulses of the last
#: few ms at once, so that its cost (numpy and Python per burst) does not grow with how often it
#: looks: on a free-running DAQ clock a busy loop found a pulse or two each pass and spent a CPU
#: core on them, under the GIL the service's event loop needs to answer.
BURST_S = 0.004
#: fewest pulses a burst carries once caught up: on a slow clock (real time, a low time-lapse)
#: the bursts are that far apart rather than :data:`BURST_S` (at 2048 S/s and 1× 62 ms, at 16× and
#: above ``BURST_S``), so their fixed cost (a source read, an encode, a queue hand-over) is not
#: paid 250 times per wall second for a few frames each: about 0.1 core at 1–4× before
BURST_PULSES = 128


class SyncPulses:
    """Mixin: pulse bookkeeping of an amplifier simulator.

    The simulator provides ``clock`` (the DAQ's :class:`SampleClock` or None), ``rate_hz``,
    ``time_scale``, ``_world_internal`` (world sample reached on the internal clock) and
    :meth:`_emit` (frames of ``n`` pulses from ``pulse0``); it calls :meth:`_init_pulses` in its
    constructor, :meth:`_arm_pulses` on START and :meth:`_send_pulses` from its thread.
    """

    clock: SampleClock | None
    rate_hz: float
    time_scale: float
    _world_internal: int
    _pulse_chunk: int = 128

    def _init_pulses(self, chunk: int) -> None:
        self._pulse_chunk = chunk
        self._external = True
        self._pulses = 0  # pulses sent since arming
        self._base_run = 0  # the DAQ run counted, and its count at arming
        self._base_count = 0
        self._epoch = 0  # world sample of count 0 of that run
        self._t0 = 0.0  # wall time of arming (internal clock)
        self._internal_epoch = 0  # world sample of counter 0 of an internal-clock run

    def _emit(self, pulse0: int, n: int) -> None:
        raise NotImplementedError

    def _arm_pulses(self, external: bool) -> None:
        """Counter 0 at the next pulse: the DAQ run after this one (or this one if running)."""
        self._external = external
        self._pulses = 0
        self._internal_epoch = self._world_internal
        self._t0 = time.monotonic()
        if external and self.clock is not None:
            st = self.clock.state()
            if st.running:
                self._base_run, self._base_count = st.run, st.count
            else:
                self._base_run, self._base_count = st.run + 1, 0

    def _world0(self) -> int:
        """World sample of pulse 0 of this arming."""
        return self._epoch + self._base_count if self._external else self._internal_epoch

    def _available_pulses(self) -> int:
        """Pulses seen since arming (SYNC pulses, or internal clock ticks)."""
        if not self._external:
            scale = self.rate_hz * self.time_scale
            ticks = int((time.monotonic() - self._t0) * scale)
            lag = 8 * self._pulse_chunk
            if ticks > self._pulses + lag:
                self._t0 += (ticks - self._pulses - lag) / scale
                ticks = self._pulses + lag
            return ticks
        if self.clock is None:
            return self._pulses
        st = self.clock.state()
        if st.run != self._base_run:
            return self._pulses  # the DAQ has not started this run yet, or has moved on
        self._epoch = st.epoch
        return st.count - self._base_count

    def _burst_s(self) -> float:
        """Wall time to the next burst once caught up: :data:`BURST_S`, or the time
        :data:`BURST_PULSES` pulses take at the clock's pace when that is longer."""
        if self._external:
            pace = self.clock.pulses_per_wall_s() if self.clock is not None else None
        else:
            pace = self.rate_hz * self.time_scale
        if not pace:
            return BURST_S
        return max(BURST_S, BURST_PULSES / pace)

    def _receivers_behind(self) -> bool:
        """Hook: a receiver on the bus holds too many frames not taken yet
        (:meth:`~dimacq.simulators.virtual_can.SimVirtualBus.receivers_behind`; default: no)."""
        return False

    def _drop_backlog(self, avail: int) -> None:
        """Hook: what to do with pulses far behind (default: nothing, send them all)."""

    #: pulses of backlog past which the amplifier drops frames (None: it never does); on an
    #: adaptive DAQ clock (:meth:`SampleClock.hold_at`) the clock waits for it there instead
    max_backlog: int | None = None
    #: the last :meth:`_send_pulses` sent nothing because a receiver is that far behind
    held_back: bool = False

    def _hold_clock(self, ahead: int | None = None) -> None:
        """Tell an adaptive DAQ clock how far it may count before this amplifier drops frames
        (``ahead`` pulses past those sent; default :attr:`max_backlog`)."""
        if self.max_backlog is None or self.clock is None or not self._external:
            return
        key = f"amplifier-{id(self)}"
        st = self.clock.state()
        if st.run == self._base_run and st.running:
            more = self.max_backlog if ahead is None else ahead
            self.clock.hold_at(key, self._base_count + self._pulses + more)

    def _freeze(self) -> None:
        """Stop the simulated clock where the frames sent stop, while the receivers catch up:
        the internal oscillator slips (no ticks pile up for the stop's final burst) and an
        adaptive DAQ clock is held at the last pulse sent (on a fixed DAQ clock the pulses
        keep coming, as they would on a real bus, up to :attr:`max_backlog`)."""
        if not self._external:
            self._t0 = time.monotonic() - self._pulses / (self.rate_hz * self.time_scale)
            return
        self._hold_clock(ahead=0)

    def _send_pulses(self, final: bool = False) -> int:
        """Send frames for pulses seen (one chunk, or all of them when ``final``); how many
        pulses were sent (0: nothing to send; fewer than a chunk: caught up, wait
        :data:`BURST_S` before looking again). Nothing is sent, except at the ``final`` call,
        while a receiver is behind (:data:`~dimacq.simulators.virtual_can.RX_BACKLOG_FRAMES`
        frames waiting; :attr:`held_back`
        says so: wait :data:`BURST_S`, the clock may not stop changing)."""
        self.held_back = not final and self._receivers_behind()
        if self.held_back:
            self._freeze()
            return 0
        avail = self._available_pulses()
        self._drop_backlog(avail)
        sent = 0
        while self._pulses < avail:
            n = min(self._pulse_chunk, avail - self._pulses)
            self._emit(self._pulses, n)
            self._pulses += n
            sent += n
            if not final:
                break
        self._hold_clock()
        return sent
