"""The USB DAQ simulator: a pyusb backend object that is the device side of the protocol.

``usb.core.find(backend=VirtualDaqBackend(...))`` finds one dimacq DAQ (VID 0x1209, PID 0xDA64)
whose control requests and bulk frames follow :mod:`dimacq.drivers.daq.protocol` byte for
byte (the codec module is the only thing shared with the driver). The analogue world behind its
inputs is a :class:`~dimacq.simulators.lab.source.SampleSource`: each wired input reads one
source channel (physical unit), multiplies it by the transducer's true sensitivity (V/unit) and
digitises it on the selected range (24 bits, clipping and overload flags at full scale). An IEPE
transducer gives 0 V when its input's IEPE current is off. AC coupling is ideal (the source
carries no sensor bias voltage).

The sample clock has two modes. By default it runs as fast as the host reads: each bulk read
clocks one frame of ``samples_per_frame`` samples. With ``free_running=True`` it runs in wall
time, as a real DAQ's does, independent of the host: samples are clocked at ``sample_rate_hz``
from START to STOP, a bulk read waits for the next complete frame (or times out), frames the
host has not read yet wait in the device FIFO, and GET_STATUS reports every sample clocked, so at
STOP the DAQ has clocked more samples than the host has received. Either way the clocked samples
drive :attr:`clock` (the SYNC output the load cell amplifier counts). Pulse ``k`` of a run is
sample ``clock.epoch + k`` of the source; a new run continues the world where the previous one
stopped.

Frames still in the FIFO at STOP stay readable after it (a short last frame for a partial one);
a real device may keep them across the next START (``DaqFaults.stale_frames_survive_start``),
so a driver must drain them before starting. ``DaqFaults.frames_clocked_before_stop`` clocks
that many frames between the host's last read and STOP in the default mode too.

Faults for tests (:class:`DaqFaults`): bulk reads that time out, frames lost in the device FIFO
(the next frame carries the overflow flag and the sample counter jumps), transfers lost on the
way (sequence and sample counter jump, no flag), frames with a corrupted payload.

Imperfections of a real device (free-running mode, :class:`DaqFaults` rates, drawn from the
backend's seeded generator; each injected one is logged on :data:`~dimacq.simulators.
imperfections.fault_log`): a **bounded FIFO** (``fifo_bytes``): while the host is late and the
FIFO is full, the samples clocked find no room and are lost — the next frame the host reads
after them carries the overflow flag and its first sample jumps past them, GET_STATUS counts the
lost frames; **stalls** (``stall_rate`` per bulk read): the device NAKs for ``stall_s`` (the
clock runs on, the FIFO fills; a stall as long as the host's timeout is a USB timeout);
**re-enumeration** (``reenumerate_rate`` per bulk read): the device drops off the bus for
``reenumerate_s`` (a reset: it stops, forgets its configuration and FIFO) and comes back at a new
address; every transfer on the old handle fails with ``ENODEV`` (libusb's NO_DEVICE), as on a
real bus. ``time_scale`` makes the free-running clock a time-lapse (1: real time);
``adaptive`` lets that time-lapse slow down rather than overflow the FIFO when the host falls
behind (:class:`~dimacq.simulators.daq.clock.SampleClock`: the clock never counts past the FIFO's
room), which a simulation may do and a real DAQ cannot.
"""

from __future__ import annotations

import array
import errno
import logging
import time
from collections import deque
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import usb.core

from dimacq.drivers.daq import protocol as p
from dimacq.simulators.daq.clock import SampleClock
from dimacq.simulators.imperfections import fault_log
from dimacq.simulators.lab.source import SampleSource
from dimacq.simulators.usb_device import Desc, OneBulkInBackend

__all__ = ["DaqFaults", "DaqInput", "VirtualDaqBackend"]

log = logging.getLogger(__name__)

_SUPPORTED_RATES_HZ_NOTE = "the simulator clocks at its source's sample rate only"


@dataclass(frozen=True)
class DaqInput:
    """What is plugged into one DAQ input.

    Attributes
    ----------
    source_channel : int
        Index into the source's channels.
    sensitivity_v_per_unit : float
        True sensitivity of the transducer, V per source unit (V/(m/s²), V/N, or 1 for V).
    iepe : bool
        The transducer needs IEPE current (reads 0 V without it).
    """

    source_channel: int
    sensitivity_v_per_unit: float
    iepe: bool = True


@dataclass
class DaqFaults:
    """Faults to inject, by 0-based bulk read index or frame sequence number."""

    timeout_reads: set[int] = field(default_factory=set)
    fifo_overflow_frames: set[int] = field(default_factory=set)
    lost_transfers: set[int] = field(default_factory=set)
    corrupt_frames: set[int] = field(default_factory=set)
    #: Frames the clock produces after the host's last read and before STOP (left in the FIFO).
    frames_clocked_before_stop: int = 0
    #: START does not clear the FIFO: frames left from the previous run are read first.
    stale_frames_survive_start: bool = False
    #: Per bulk read: probability that the device NAKs for ``stall_s`` seconds (wall time).
    stall_rate: float = 0.0
    stall_s: float = 0.25
    #: Per bulk read: probability that the device drops off the bus for ``reenumerate_s``
    #: seconds and re-enumerates at a new address.
    reenumerate_rate: float = 0.0
    reenumerate_s: float = 0.5


@dataclass(frozen=True)
class _Handle:
    """An open device handle; dead once the device has re-enumerated."""

    generation: int


class VirtualDaqBackend(OneBulkInBackend):
    """A pyusb backend with one simulated dimacq DAQ on it.

    Parameters
    ----------
    source : SampleSource
        The virtual lab behind the inputs.
    wiring : mapping of physical channel → DaqInput
        Inputs not listed read 0 V.
    n_channels : int
    serial_number : str
    clock : SampleClock, optional
        The SYNC output; pass the same object to the load cell simulator.
    faults : DaqFaults, optional
    free_running : bool
        Clock samples in wall time (a real DAQ) instead of one frame per bulk read.
    time_scale : float
        Free-running: samples clocked per wall second = ``time_scale × sample_rate_hz``.
    fifo_bytes : int
        Free-running: the device FIFO's size in bytes (0: unbounded); a frame takes
        ``p.frame_size`` bytes.
    adaptive : bool
        Free-running: the time-lapse slows down when the host falls behind instead of losing
        samples in a full FIFO.
    seed : int
        Seed of the random faults (:class:`DaqFaults` rates).
    """

    data_endpoint = p.DATA_ENDPOINT
    device_name = "simulated DAQ"

    def __init__(
        self,
        source: SampleSource,
        wiring: Mapping[int, DaqInput],
        *,
        n_channels: int = 64,
        serial_number: str = "SIMDAQ-0001",
        clock: SampleClock | None = None,
        faults: DaqFaults | None = None,
        free_running: bool = False,
        time_scale: float = 1.0,
        fifo_bytes: int = 0,
        adaptive: bool = False,
        seed: int = 0,
    ) -> None:
        super().__init__()
        self.source = source
        self.wiring = dict(wiring)
        for k, w in self.wiring.items():
            if not 0 <= k < n_channels:
                raise ValueError(f"wiring: physical channel {k} outside 0..{n_channels - 1}")
            if not 0 <= w.source_channel < len(source.channel_names):
                raise ValueError(f"wiring: source channel {w.source_channel} does not exist")
        self.n_channels = n_channels
        self.identity = p.DeviceIdentity(
            p.PROTOCOL_VERSION, n_channels, 204800, 24, len(p.RANGES_V), serial_number, "sim-1.0"
        )
        self.clock = clock if clock is not None else SampleClock()
        self.faults = faults if faults is not None else DaqFaults()
        self._device: Any = Desc(
            bLength=18,
            bDescriptorType=1,
            bcdUSB=0x0200,
            bDeviceClass=0xFF,
            bDeviceSubClass=0,
            bDeviceProtocol=0,
            bMaxPacketSize0=64,
            idVendor=p.VENDOR_ID,
            idProduct=p.PRODUCT_ID,
            bcdDevice=0x0100,
            iManufacturer=0,
            iProduct=0,
            iSerialNumber=0,
            bNumConfigurations=1,
            address=1,
            bus=1,
            port_number=1,
            port_numbers=(1,),
            speed=3,
        )
        self.enabled = np.zeros(n_channels, dtype=bool)
        self.iepe_ua = np.zeros(n_channels, dtype=int)
        self.range_code = np.zeros(n_channels, dtype=int)
        self.ac = np.zeros(n_channels, dtype=bool)
        self.sample_rate_hz = float(source.sample_rate_hz)
        self.running = False
        self.open_handles = 0
        self._spf = 0
        self._count = 0
        self._epoch = 0
        self._world = 0
        self._seq = 0
        self._reads = 0
        self._overflowed = False
        self._pending_overflow = False
        self._frames_lost = 0
        self.free_running = free_running
        self.time_scale = float(time_scale)
        self.fifo_bytes = int(fifo_bytes)
        self.adaptive = bool(adaptive)
        self.rng = np.random.default_rng(seed)
        self._lost: deque[tuple[int, int]] = deque()  # sample ranges lost in a full FIFO
        self._lost_upto = 0
        self._generation = 0  # bumped at each re-enumeration: older handles are dead
        self._gone_until = 0.0
        #: faults injected so far, by kind (what the soak compares with what was reported)
        self.injected: dict[str, int] = {}
        self._t0 = 0.0
        self._sent = 0  # samples framed (sent or lost) in this run
        self._fifo: deque[bytes] = deque()  # frames left in the FIFO after STOP

    # -- enumeration (descriptors: OneBulkInBackend) ------------------------------------------
    def enumerate_devices(self) -> Any:
        if time.monotonic() >= self._gone_until:
            yield self._device

    # -- handles -----------------------------------------------------------------------------
    def open_device(self, dev: Any) -> Any:
        self._alive(None)
        self.open_handles += 1
        return _Handle(self._generation)

    def close_device(self, dev_handle: Any) -> None:
        self.open_handles -= 1
        if self.running and dev_handle.generation == self._generation:
            self._stop()

    def _alive(self, dev_handle: Any) -> None:
        """A transfer on a handle of before a re-enumeration, or while off the bus: ENODEV."""
        gone = time.monotonic() < self._gone_until
        if gone or (dev_handle is not None and dev_handle.generation != self._generation):
            raise usb.core.USBError("No such device", error_code=-4, errno=errno.ENODEV)

    def _count_fault(self, kind: str, message: str, *args: Any) -> None:
        self.injected[kind] = self.injected.get(kind, 0) + 1
        fault_log.warning("simulated fault %s: " + message, kind, *args)

    def _reenumerate(self) -> None:
        """Off the bus for ``reenumerate_s``, then back at the next address, reset."""
        self._stop()
        unseen = sum(1 for f in self._fifo if p.decode_frame(f).flags & p.FrameFlags.OVERFLOW)
        unseen += len(self._lost) + int(self._pending_overflow)
        if unseen:
            self.injected["fifo_overflow"] = self.injected.get("fifo_overflow", 0) - unseen
            fault_log.warning(
                "simulated fault note: %d fifo_overflow(s) discarded unread by the reset", unseen
            )
        self._fifo.clear()
        self._generation += 1
        self._gone_until = time.monotonic() + self.faults.reenumerate_s
        self._device.address = self._device.address % 127 + 1
        self.enabled[:] = False
        self.iepe_ua[:] = 0
        self.range_code[:] = 0
        self.ac[:] = False
        self._count_fault(
            "usb_reenumeration",
            "the DAQ drops off the USB bus for %g s and comes back at address %d",
            self.faults.reenumerate_s,
            self._device.address,
        )

    # -- control requests --------------------------------------------------------------------
    def ctrl_transfer(
        self,
        dev_handle: Any,
        bmRequestType: int,
        bRequest: int,
        wValue: int,
        wIndex: int,
        data: array.array[int],
        timeout: int,
    ) -> int:
        self._alive(dev_handle)
        if bmRequestType == p.BM_REQUEST_IN:
            if bRequest == p.Request.IDENTIFY:
                return self._answer(data, self.identity.encode())
            if bRequest == p.Request.GET_STATUS:
                st = p.DeviceStatus(
                    self.running,
                    self._overflowed,
                    self.sample_rate_hz,
                    self._clocked(),
                    self._frames_lost,
                )
                return self._answer(data, st.encode())
            raise self._stall(f"unknown IN request {bRequest:#x}")
        if bmRequestType != p.BM_REQUEST_OUT:
            raise self._stall(f"request type {bmRequestType:#x} not supported")
        req = bRequest
        if req == p.Request.STOP:
            self._stop()
            return 0
        if self.running:
            raise self._stall(f"request {req:#x} while streaming")
        if req == p.Request.SET_SAMPLE_RATE:
            rate = p.RATE_STRUCT.unpack(bytes(data))[0] if len(data) == p.RATE_STRUCT.size else -1
            if rate != round(self.source.sample_rate_hz):
                raise self._stall(f"rate {rate} Hz: {_SUPPORTED_RATES_HZ_NOTE}")
            self.sample_rate_hz = float(self.source.sample_rate_hz)
            return 4
        if req == p.Request.START:
            if wValue == 0 or not self.enabled.any():
                raise self._stall("START with no samples per frame or no channel enabled")
            self._start(wValue)
            return 0
        ch = wIndex
        if not 0 <= ch < self.n_channels:
            raise self._stall(f"channel {ch} does not exist")
        if req == p.Request.SET_CHANNEL_ENABLE:
            self.enabled[ch] = bool(wValue)
        elif req == p.Request.SET_IEPE:
            if wValue not in p.IEPE_CURRENTS_UA:
                raise self._stall(f"IEPE current {wValue} µA")
            self.iepe_ua[ch] = wValue
        elif req == p.Request.SET_RANGE:
            if not 0 <= wValue < len(p.RANGES_V):
                raise self._stall(f"range code {wValue}")
            self.range_code[ch] = wValue
        elif req == p.Request.SET_COUPLING:
            self.ac[ch] = bool(wValue)
        else:
            raise self._stall(f"unknown OUT request {req:#x}")
        return 0

    def _start(self, spf: int) -> None:
        if not self.faults.stale_frames_survive_start:
            self._fifo.clear()
        self._spf = spf
        self._count = 0
        self._sent = 0
        self._t0 = time.monotonic()
        self._seq = 0
        self._reads = 0
        self._overflowed = False
        self._pending_overflow = False
        self._frames_lost = 0
        self._lost.clear()
        self._lost_upto = 0
        self._epoch = self._world
        self.running = True
        self.clock.start(
            self._epoch,
            self.sample_rate_hz,
            wall_scale=self.time_scale if self.free_running else None,
            adaptive=self.adaptive,
        )
        self._hold_clock()

    def _hold_clock(self) -> None:
        """Adaptive time-lapse: the clock may count up to the FIFO's room, no further."""
        cap = self._fifo_samples()
        if self.adaptive and self.free_running and cap:
            self.clock.hold_at("daq", self._sent + cap + sum(b - a for a, b in self._lost))

    def _stop(self) -> None:
        if self.running:
            if self.free_running:
                # the clock stops at one instant: the count the amplifiers saw
                self._count = max(self._count, self.clock.stop())
                self._overflow()
            else:
                self._count += self.faults.frames_clocked_before_stop * self._spf
                self.clock.advance(self._count)
            # what was clocked and not sent stays in the FIFO, readable after STOP
            while True:
                self._skip_lost()
                if self._sent >= self._count:
                    break
                frame = self._next_frame(min(self._spf, self._count - self._sent))
                if frame:
                    self._fifo.append(frame)
            self.running = False
            self._world = self._epoch + self._count
            self.clock.stop()

    def _clocked(self) -> int:
        """Samples clocked in this run (free-running: advanced to the wall time while running)."""
        if self.free_running and self.running:
            n = self.clock.count()
            if n > self._count:
                self._count = n
            self._overflow()
        return self._count

    def _fifo_samples(self) -> int:
        """Samples the FIFO holds (whole frames of the enabled channels); 0: unbounded."""
        if not self.fifo_bytes or not self._spf:
            return 0
        frame = p.frame_size(self._spf, max(1, int(self.enabled.sum())))
        return max(1, self.fifo_bytes // frame) * self._spf

    def _overflow(self) -> None:
        """Samples clocked while the FIFO is full find no room: they are lost (whole frames)."""
        cap = self._fifo_samples()
        if not cap:
            return
        room_end = self._sent + cap + sum(b - a for a, b in self._lost)
        start = max(room_end, self._lost_upto)
        start += -start % self._spf
        end = self._count - self._count % self._spf
        if end > start:
            if self._lost and self._lost[-1][1] == start:  # the same overflow goes on
                self._lost[-1] = (self._lost[-1][0], end)
            else:
                self._lost.append((start, end))
                self._count_fault(
                    "fifo_overflow",
                    "the host is late; the DAQ FIFO (%d bytes) is full from sample %d on",
                    self.fifo_bytes,
                    start,
                )
            self._lost_upto = end

    def world_sample(self, daq_sample: int) -> int:
        """The source counter of DAQ sample ``daq_sample`` of the present run."""
        return self._epoch + daq_sample

    # -- bulk data ---------------------------------------------------------------------------
    def _make_frame(self, n: int) -> tuple[int, int, np.ndarray, int]:
        """Samples ``_sent .. _sent + n - 1`` as counts; clocks them first in the default mode."""
        chans = np.flatnonzero(self.enabled)
        first = self._sent
        volts = np.zeros((chans.size, n))
        wired = [(i, self.wiring[int(k)]) for i, k in enumerate(chans) if int(k) in self.wiring]
        if wired:
            src = np.array([w.source_channel for _, w in wired], dtype=np.intp)
            with self.clock.source_lock:
                x = self.source.read(src, self._epoch + first, n)
            for row, (i, w) in enumerate(wired):
                powered = (not w.iepe) or self.iepe_ua[chans[i]] > 0
                volts[i] = x[row] * w.sensitivity_v_per_unit if powered else 0.0
        rng_v = np.array([p.RANGES_V[c] for c in self.range_code[chans]])
        counts = np.rint(volts.T / rng_v * 2**23)
        over = np.abs(counts) > p.FULL_SCALE_COUNTS
        np.clip(counts, -p.FULL_SCALE_COUNTS, p.FULL_SCALE_COUNTS, out=counts)
        mask = 0
        for col in np.flatnonzero(over.any(axis=0)).tolist():
            mask |= 1 << col
        self._sent += n
        if self._sent > self._count:
            self._count = self._sent
            self.clock.advance(self._count)
        if self.running:
            self._hold_clock()
        return first, mask, counts.astype(np.int32), n

    def _await_frame(self, deadline: float) -> bool:
        """Free-running: wait until a whole frame is clocked; False at the deadline."""
        while self._clocked() - self._sent < self._spf:
            self._skip_lost()
            if self._clocked() - self._sent >= self._spf:
                break
            left = deadline - time.monotonic()
            if left <= 0:
                return False
            # the rest of the frame takes its samples' duration at the clock's pace (real
            # time over the time-lapse): a bulk read returns once its frame is complete
            pace = self.clock.pulses_per_wall_s() or self.sample_rate_hz * self.time_scale
            need = (self._sent + self._spf - self._count) / pace
            time.sleep(min(left, max(need, 0.0005)))
        return True

    def bulk_read(
        self, dev_handle: Any, ep: int, intf: int, buff: array.array[int], timeout: int
    ) -> int:
        if ep != p.DATA_ENDPOINT:
            raise usb.core.USBError("Pipe error", error_code=-9, errno=errno.EPIPE)
        self._alive(dev_handle)
        read_index = self._reads
        self._reads += 1
        timed_out = usb.core.USBTimeoutError("Operation timed out", error_code=-7, errno=110)
        if read_index in self.faults.timeout_reads:
            raise timed_out
        f = self.faults
        if self.running and f.reenumerate_rate and self.rng.random() < f.reenumerate_rate:
            self._reenumerate()
            raise usb.core.USBError("No such device", error_code=-4, errno=errno.ENODEV)
        if self.running and f.stall_rate and self.rng.random() < f.stall_rate:
            wait = min(f.stall_s, timeout / 1000)
            self._count_fault(
                "usb_timeout" if f.stall_s >= timeout / 1000 else "usb_stall",
                "the DAQ NAKs bulk reads for %g s (host timeout %g s)",
                f.stall_s,
                timeout / 1000,
            )
            time.sleep(wait)
            if f.stall_s >= timeout / 1000:
                raise timed_out
        if self._fifo:
            return self._deliver(self._fifo.popleft(), buff)
        if not self.running:
            raise timed_out
        deadline = time.monotonic() + timeout / 1000
        while True:
            if self.free_running and not self._await_frame(deadline):
                raise timed_out
            frame = self._next_frame(self._spf)
            if frame:
                return self._deliver(frame, buff)

    def _skip_lost(self) -> None:
        """Step over samples lost in a full FIFO; the next frame carries the overflow flag."""
        while self._lost and self._lost[0][0] <= self._sent:
            a, b = self._lost.popleft()
            self._frames_lost += (b - a) // max(1, self._spf)
            self._sent = max(self._sent, b)
            self._overflowed = True
            self._pending_overflow = True

    def _next_frame(self, n: int) -> bytes:
        """Frame the next ``n`` samples; b"" when the frame is lost (fault) on the device side."""
        self._skip_lost()
        if self._lost:
            n = min(n, self._lost[0][0] - self._sent)
        first, mask, counts, _ = self._make_frame(n)
        seq = self._seq
        if seq in self.faults.fifo_overflow_frames:
            # The FIFO overflowed: these samples never leave the device.
            self.faults.fifo_overflow_frames.discard(seq)
            self._overflowed = True
            self._pending_overflow = True
            self._frames_lost += 1
            return b""
        self._seq += 1
        if seq in self.faults.lost_transfers:
            self.faults.lost_transfers.discard(seq)
            return b""
        flags = p.FrameFlags.OVERFLOW if self._pending_overflow else p.FrameFlags.NONE
        self._pending_overflow = False
        frame = p.encode_frame(seq, first, counts, overload_mask=mask, flags=flags)
        if seq in self.faults.corrupt_frames:
            frame = frame[:-1] + bytes([frame[-1] ^ 0xFF])
        return frame

    @staticmethod
    def _deliver(frame: bytes, buff: array.array[int]) -> int:
        if len(frame) > len(buff):
            raise usb.core.USBError("Overflow", error_code=-8, errno=errno.EOVERFLOW)
        buff[: len(frame)] = array.array("B", frame)
        return len(frame)
