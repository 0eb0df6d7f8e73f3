"""What the SYNC-counting load cell drivers share (CAN FD: :mod:`dimacq.drivers.loadcell.driver`,
CANopen: :mod:`dimacq.drivers.canopen_loadcell.driver`).

Both amplifiers count the DAQ's sample-clock pulses and label every sample with that counter, so
a sample's counter *is* its DAQ sample number:

- ``read_until(end)`` waits until the stream's counter passes ``end − 1`` (:meth:`_await_counter`).
  When the stream stalls short of it while the amplifier streams, the driver asks the amplifier's
  own counter: if the amplifier is past ``end``, the frames in between were lost on the bus (a
  bus-off over a run's last pulses, after which the SYNC stops and nothing comes again) — a gap
  the caller sees as NaN samples and a ``gap`` event, not a timeout.
- after both devices stopped, the pulses the amplifier counted must equal the samples the DAQ
  clocked (:meth:`verify_count`), else the streams are misaligned (``drift``).
"""

from __future__ import annotations

from collections.abc import Callable

from dimacq.devices.loadcell import LoadCellEvent
from dimacq.drivers.base import Deadline
from dimacq.errors import DeviceStateError, DeviceTimeoutError

__all__ = ["STALL_PROBE_S", "SyncCounting", "unwrap_u32"]

#: seconds without a new counter while streaming before the driver asks the amplifier's counter
STALL_PROBE_S = 0.5


def unwrap_u32(raw: int, ref: int) -> int:
    """The absolute counter whose low 32 bits are ``raw``, at or after ``ref`` (a counter the
    device has already passed): ``ref + ((raw − ref) mod 2³²)``."""
    ref = max(ref, 0)
    return ref + ((raw - ref) & 0xFFFFFFFF)


class SyncCounting:
    """Mixin of the SYNC-counting load cell drivers.

    The driver provides ``streaming``, ``_final_pulses`` (pulses counted, set by ``stop()``),
    :meth:`_record`, :meth:`_device_counter` and :attr:`_who` (how messages name the device).
    """

    streaming: bool
    _final_pulses: int | None

    @property
    def _who(self) -> str:
        raise NotImplementedError

    def _record(self, ev: LoadCellEvent) -> None:
        raise NotImplementedError

    def _device_counter(self) -> int:
        """The amplifier's own pulse counter, asked over the bus and unwrapped (u32 on the wire)
        against the stream's (raises DeviceTimeoutError)."""
        raise NotImplementedError

    def _await_counter(
        self,
        end_sample: int,
        deadline: Deadline,
        have: Callable[[], int],
        pump: Callable[[float], None],
        timed_out: Callable[[int], DeviceTimeoutError],
    ) -> None:
        """Return once sample ``end_sample − 1`` is in, or is known lost.

        ``have()`` files what arrived and returns one past the highest sample in; ``pump(left)``
        waits up to ``left`` seconds for more frames; ``timed_out(have)`` is the error raised when
        ``deadline`` passes first (the samples received are kept).
        """
        final = None if self.streaming else self._final_pulses
        last, stalled = have(), Deadline(STALL_PROBE_S)
        while True:
            now_have = have()
            if now_have >= end_sample or (final is not None and end_sample <= final):
                return
            if now_have != last:
                last, stalled = now_have, Deadline(STALL_PROBE_S)
            elif self.streaming and stalled.left() <= 0:
                stalled = Deadline(STALL_PROBE_S)
                if self._counter_passed(end_sample):
                    have()  # file the frames that came with the answer
                    return
            left = deadline.left()
            if left <= 0:
                raise timed_out(now_have)
            pump(left)

    def _counter_passed(self, end_sample: int) -> bool:
        """The amplifier's own counter has reached ``end_sample``."""
        try:
            return self._device_counter() >= end_sample
        except DeviceTimeoutError:
            return False  # still off the bus: keep waiting within the caller's deadline

    def verify_count(self, daq_samples_clocked: int) -> LoadCellEvent | None:
        """After both devices stopped: the pulses counted must equal the DAQ's samples.

        Returns (and records) a ``drift`` event when they differ: SYNC pulses were missed or
        added somewhere, so the load cell samples are misaligned with the DAQ's.
        """
        if self._final_pulses is None:
            raise DeviceStateError("verify_count() needs stop() first")
        diff = self._final_pulses - daq_samples_clocked
        if diff == 0:
            return None
        ev = LoadCellEvent(
            "drift",
            0,
            daq_samples_clocked,
            f"{self._who} counted {self._final_pulses} SYNC pulses, the DAQ clocked "
            f"{daq_samples_clocked} samples ({diff:+d}): the streams are misaligned; check the "
            "SYNC cable and start the amplifier before the DAQ",
        )
        self._record(ev)
        return ev
