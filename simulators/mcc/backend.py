"""USB-1808X simulator: a pyusb backend with one or more MCC units on it, byte for byte.

``usb.core.find(idVendor=0x09DB, idProduct=0x013E, backend=Mcc1808Backend(...))`` finds the
units; their vendor requests, EEPROM, FPGA load and bulk scans follow
:mod:`dimacq.drivers.mcc.protocol` (facts from MCC's Linux driver ``usb-1808.c``). The analogue
world behind the inputs is a :class:`~dimacq.simulators.lab.source.SampleSource`; global input
``k`` is input ``k % 8`` of unit ``k // 8``. The external IEPE conditioner is ideal (gain 1,
always powered). Each unit's ADC has its own gain and offset error, which its EEPROM calibration
table (written at "the factory": the table corrects exactly the code errors) undoes; the driver
learns them only by reading the EEPROM.

Clock: the unit started with a pacer period > 0 is the master; it drives :attr:`clock` (the
shared :class:`~dimacq.simulators.daq.clock.SampleClock` the load cell simulators count, as
they count the master's ICLKO) in time-lapse wall time (``time_scale``), or, with
``free_running=False`` (fast tests), as fast as the host reads. Units started with
pacer period 0 (external clock) take one scan per master pulse from the moment they are armed:
armed before the master starts, they scan in step. ``missed_pulses`` (fault) makes a slave lose
its first pulses (a loose clock cable). ``fifo_bytes``: a unit whose host is late by more than
its FIFO overruns: its scan stops there and STATUS sets AIN_SCAN_OVERRUN.

The FPGA of a unit made with ``fpga_configured=False`` is not configured: DAQ requests stall
until the host streams ``fpga_image`` (the unit's ``.rbf``) after FPGA_CONFIG.
"""

from __future__ import annotations

import array
import errno
import logging
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import usb.core

from dimacq.drivers.mcc import protocol as p
from dimacq.simulators.daq.backend import DaqInput
from dimacq.simulators.daq.clock import SampleClock
from dimacq.simulators.lab.source import SampleSource
from dimacq.simulators.usb_device import Desc, OneBulkInBackend

__all__ = ["Mcc1808Backend", "default_fpga_image"]

log = logging.getLogger(__name__)


def default_fpga_image() -> bytes:
    """A stand-in bitstream (the simulator's ``.rbf``): 4 KiB of a fixed pattern."""
    return bytes(np.random.default_rng(1808).integers(0, 256, 4096, dtype=np.uint8))


@dataclass
class _Unit:
    serial: str
    desc: Any
    slope: np.ndarray  # true ADC errors: raw = (ideal − offset) / slope
    offset: np.ndarray
    eeprom: dict[int, int]
    fpga_configured: bool
    fpga_image: bytes
    config_mode: bool = False
    fpga_rx: bytearray = field(default_factory=bytearray)
    mem_address: int = 0
    ranges: list[int] = field(default_factory=lambda: [0] * p.N_AI)
    queue: list[int] = field(default_factory=lambda: [0])
    running: bool = False
    master: bool = False
    run: int = -1  # clock run it scans in (-1: armed, waiting for the master to start)
    offset_pulses: int = 0  # master pulses before its first scan
    frozen: int | None = None  # scans clocked once its clock stopped
    sent: int = 0
    overrun: bool = False
    missed: int = 0


class Mcc1808Backend(OneBulkInBackend):
    """A pyusb backend with ``n_units`` simulated USB-1808X on it.

    Parameters
    ----------
    source : SampleSource
    wiring : mapping of global input → DaqInput
        Input ``k`` of unit ``k // 8``; inputs not listed read 0 V.
    n_units : int
    serials : sequence of str, optional
        8-character serial numbers (default ``"01F2A00u"``).
    clock : SampleClock, optional
    free_running : bool
        The master's clock runs in (time-lapse) wall time, as a real one does; False: it runs
        as fast as the host reads (a bulk read clocks what it asks for), for fast tests.
    time_scale : float
        Free-running: master pulses per wall second = ``time_scale × sample_rate_hz``.
    fifo_bytes : int
        Each unit's FIFO (0: unbounded).
    fpga_configured : bool
        Whether the units' FPGAs are loaded at power-up (a real one is not).
    missed_pulses : mapping of serial → int
        Pulses a slave misses at the start of its scan (fault).
    seed : int
        The units' ADC errors.
    """

    data_endpoint = p.DATA_ENDPOINT
    device_name = "simulated USB-1808X"

    def __init__(
        self,
        source: SampleSource,
        wiring: Mapping[int, DaqInput],
        *,
        n_units: int = 1,
        serials: Sequence[str] | None = None,
        clock: SampleClock | None = None,
        free_running: bool = True,
        time_scale: float = 1.0,
        fifo_bytes: int = 0,
        fpga_configured: bool = False,
        fpga_image: bytes | None = None,
        missed_pulses: Mapping[str, int] | None = None,
        seed: int = 0,
    ) -> None:
        super().__init__()
        self.source = source
        self.wiring = dict(wiring)
        if any(not 0 <= k < p.N_AI * n_units for k in self.wiring):
            raise ValueError(f"wiring beyond the {n_units} unit(s) × {p.N_AI} inputs")
        serials = list(serials) if serials else [f"01F2A{u:03X}" for u in range(n_units)]
        self.clock = clock if clock is not None else SampleClock()
        self.free_running = free_running
        self.time_scale = float(time_scale)
        self.fifo_bytes = int(fifo_bytes)
        self.sample_rate_hz = float(source.sample_rate_hz)
        self._epoch = 0
        self._world = 0
        self._run = -1
        rng = np.random.default_rng([seed, 1808])
        image = fpga_image if fpga_image is not None else default_fpga_image()
        self.units: list[_Unit] = []
        for u, serial in enumerate(serials):
            slope = 1 + rng.normal(0, 2e-3, (p.N_AI, p.N_RANGES))
            offset = rng.normal(0, 30.0, (p.N_AI, p.N_RANGES))
            table = p.encode_calibration(slope, offset)
            # what the factory stored: the float32 values, which the ADC errors then follow
            slope32, offset32 = p.calibration_table(table)
            eeprom = {p.CAL_BASE_ADDRESS + i: b for i, b in enumerate(table)}
            desc = Desc(
                bLength=18,
                bDescriptorType=1,
                bcdUSB=0x0200,
                bDeviceClass=0xFF,
                bDeviceSubClass=0,
                bDeviceProtocol=0,
                bMaxPacketSize0=64,
                idVendor=p.VENDOR_ID,
                idProduct=0x013E,
                bcdDevice=0x0100,
                iManufacturer=0,
                iProduct=0,
                iSerialNumber=0,
                bNumConfigurations=1,
                address=u + 2,
                bus=1,
                port_number=u + 1,
                port_numbers=(u + 1,),
                speed=3,
            )
            self.units.append(
                _Unit(
                    serial,
                    desc,
                    slope32,
                    offset32,
                    eeprom,
                    fpga_configured,
                    image,
                    missed=int((missed_pulses or {}).get(serial, 0)),
                )
            )

    # -- enumeration (descriptors: OneBulkInBackend) ------------------------------------------
    def enumerate_devices(self) -> Any:
        for u in self.units:
            yield u.desc

    def open_device(self, dev: Any) -> Any:
        return next(u for u in self.units if u.desc is dev)

    def close_device(self, dev_handle: Any) -> None:
        if dev_handle.running:
            self._scan_stop(dev_handle)

    # -- control requests --------------------------------------------------------------------
    def _status(self, u: _Unit) -> int:
        s = p.Status.NONE
        if u.running and not self._frozen(u):
            s |= p.Status.AIN_SCAN_RUNNING
        if u.overrun:
            s |= p.Status.AIN_SCAN_OVERRUN
        if u.fpga_configured:
            s |= p.Status.FPGA_CONFIGURED
        if u.config_mode:
            s |= p.Status.FPGA_CONFIG_MODE
        return int(s)

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
        u: _Unit = dev_handle
        R = p.Request
        if bmRequestType == p.BM_REQUEST_IN:
            if bRequest == R.STATUS:
                return self._answer(data, p.STATUS_STRUCT.pack(self._status(u)))
            if bRequest == R.SERIAL:
                return self._answer(data, u.serial.encode("ascii")[:8].ljust(8, b"0"))
            if bRequest == R.FPGA_VERSION:
                return self._answer(data, p.STATUS_STRUCT.pack(0x0103))
            if bRequest == R.MEMORY:
                out = bytes(u.eeprom.get(u.mem_address + i, 0xFF) for i in range(len(data)))
                u.mem_address += len(data)
                return self._answer(data, out)
            raise self._stall(f"unknown IN request {bRequest:#x}")
        if bmRequestType != p.BM_REQUEST_OUT:
            raise self._stall(f"request type {bmRequestType:#x}")
        payload = bytes(data)
        if bRequest == R.MEM_ADDRESS:
            u.mem_address = p.ADDRESS_STRUCT.unpack(payload[:2])[0]
        elif bRequest == R.FPGA_CONFIG:
            if payload != bytes([p.FPGA_UNLOCK]):
                raise self._stall("FPGA_CONFIG without the unlock code")
            u.config_mode, u.fpga_configured, u.fpga_rx = True, False, bytearray()
        elif bRequest == R.FPGA_DATA:
            if not u.config_mode or len(payload) > p.FPGA_CHUNK:
                raise self._stall("FPGA_DATA outside config mode or over 64 bytes")
            u.fpga_rx += payload
            if len(u.fpga_rx) >= len(u.fpga_image):
                u.config_mode = False
                u.fpga_configured = bytes(u.fpga_rx) == u.fpga_image
        elif not u.fpga_configured:
            raise self._stall(f"request {bRequest:#x} before the FPGA is configured")
        elif bRequest == R.AIN_SCAN_STOP:
            self._scan_stop(u)
        elif u.running:
            raise self._stall(f"request {bRequest:#x} while scanning")
        elif bRequest == R.AIN_ADC_SETUP:
            ranges, _modes = p.decode_adc_setup(payload)
            if len(ranges) != p.N_AI:
                raise self._stall("AIN_ADC_SETUP needs 8 bytes")
            u.ranges = [int(r) for r in ranges]
        elif bRequest == R.AIN_SCAN_CONFIG:
            queue = p.decode_scan_queue(wIndex, payload)
            if len(payload) != p.SCAN_QUEUE_LEN or any(q >= p.N_AI for q in queue):
                raise self._stall("scan queue: 13 bytes of analogue inputs 0..7 expected")
            u.queue = queue
        elif bRequest == R.AIN_CLR_FIFO:
            u.sent, u.frozen, u.overrun = 0, 0, False
        elif bRequest == R.TRIGGER_CONFIG:
            pass
        elif bRequest == R.AIN_SCAN_START:
            if len(payload) != p.AIN_SCAN_START_STRUCT.size:
                raise self._stall("AIN_SCAN_START needs 14 bytes")
            self._scan_start(u, p.AInScanStart.decode(payload))
        else:
            raise self._stall(f"unknown OUT request {bRequest:#x}")
        return len(payload)

    def _scan_start(self, u: _Unit, cmd: p.AInScanStart) -> None:
        u.sent, u.frozen, u.overrun, u.running = 0, None, False, True
        u.master = cmd.pacer_period > 0
        if u.master:
            rate = p.pacer_rate_hz(cmd.pacer_period)
            if abs(rate / self.sample_rate_hz - 1) > 1e-5:
                u.running = False
                raise self._stall(
                    f"pacer {rate:g} Hz: the simulated lab samples at {self.sample_rate_hz:g} Hz"
                )
            self._epoch = self._world
            scale = self.time_scale if self.free_running else None
            self.clock.start(self._epoch, self.sample_rate_hz, wall_scale=scale)
            self._run = self.clock.state().run
            u.run, u.offset_pulses = self._run, 0
            for s in self.units:  # armed slaves take the master's pulses from the first
                if s.running and not s.master and s.run == -1:
                    s.run, s.offset_pulses = self._run, s.missed
        else:
            st = self.clock.state()
            live = st.running and st.run == self._run
            u.run = self._run if live else -1
            u.offset_pulses = (st.count + u.missed) if live else 0

    def _scan_stop(self, u: _Unit) -> None:
        if not u.running:
            return
        if u.master:
            count = self.clock.stop()
            self._world = self._epoch + count
        u.frozen = self._clocked(u)
        u.running = False

    def _frozen(self, u: _Unit) -> bool:
        """The unit gets no more pulses: stopped, or its master's clock stopped."""
        st = self.clock.state()
        return not u.running or u.run == -1 or not (st.running and st.run == u.run)

    def _clocked(self, u: _Unit) -> int:
        """Scans the unit has taken so far (stops at a FIFO overrun)."""
        if u.frozen is not None:
            return u.frozen
        if u.run == -1:
            return 0
        st = self.clock.state()
        n = max(0, st.count - u.offset_pulses) if st.run == u.run else 0
        if self.fifo_bytes:
            cap = self.fifo_bytes // (4 * len(u.queue))
            if n - u.sent > cap:
                n, u.overrun, u.frozen = u.sent + cap, True, u.sent + cap
                log.warning("simulated USB-1808X %s: FIFO overrun at scan %d", u.serial, n)
        return n

    def world_sample(self, daq_sample: int) -> int:
        """The source counter of the master's scan ``daq_sample`` of the present run."""
        return self._epoch + daq_sample

    # -- bulk data ---------------------------------------------------------------------------
    def _codes(self, u: _Unit, first: int, n: int) -> np.ndarray:
        """Raw ADC codes of scans ``first .. first + n − 1``, shape (n, len(queue))."""
        unit = self.units.index(u)
        volts = np.zeros((n, len(u.queue)))
        wired = [
            (j, self.wiring[unit * p.N_AI + q])
            for j, q in enumerate(u.queue)
            if unit * p.N_AI + q in self.wiring
        ]
        if wired:
            src = np.array([w.source_channel for _, w in wired], dtype=np.intp)
            start = self._epoch + u.offset_pulses + first
            with self.clock.source_lock:
                x = self.source.read(src, start, n)
            for row, (j, w) in enumerate(wired):
                volts[:, j] = x[row] * w.sensitivity_v_per_unit
        q = np.array(u.queue)
        rng = np.array(u.ranges)[q]
        full = np.array([p.RANGES_V[p.Range(int(r))] for r in rng])
        bipolar = rng <= p.Range.BP_5V
        ideal = np.where(
            bipolar, volts / full * p.MID_SCALE + p.MID_SCALE, volts / full * p.CODE_MASK
        )
        raw = (ideal - u.offset[q, rng]) / u.slope[q, rng]
        return np.clip(np.rint(raw), 0, p.CODE_MASK).astype(np.int64)

    def bulk_read(
        self, dev_handle: Any, ep: int, intf: int, buff: array.array[int], timeout: int
    ) -> int:
        u: _Unit = dev_handle
        if ep != p.DATA_ENDPOINT:
            raise usb.core.USBError("Pipe error", error_code=-9, errno=errno.EPIPE)
        want = len(buff) // (4 * len(u.queue))
        if not self.free_running and not self._frozen(u) and u.frozen is None:
            st = self.clock.state()  # host-paced: this read clocks what it asks for
            if st.count < u.offset_pulses + u.sent + want:
                self.clock.advance(u.offset_pulses + u.sent + want)
        deadline = time.monotonic() + timeout / 1000
        while True:
            avail = self._clocked(u) - u.sent
            if avail >= want or (avail > 0 and self._frozen(u)):
                break
            left = deadline - time.monotonic()
            if left <= 0 or (avail <= 0 and self._frozen(u) and not u.running):
                if left > 0:
                    time.sleep(min(left, 0.005))
                raise usb.core.USBTimeoutError("Operation timed out", error_code=-7, errno=110)
            need = (want - avail) / (self.sample_rate_hz * self.time_scale)
            time.sleep(min(left, max(need, 0.0005)))
        n = min(avail, want)
        data = p.encode_scans(self._codes(u, u.sent, n))
        u.sent += n
        buff[: len(data)] = array.array("B", data)
        return len(data)
