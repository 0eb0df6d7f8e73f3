"""USB-1808X twin: a pyusb backend with one or more MCC units on it, written from MCC's code.

``usb.core.find(idVendor=0x09DB, idProduct=0x013E, backend=Mcc1808Backend(...))`` finds the
units. What a unit does is transcribed here from the vendor's published code, not taken from our
driver: MCC's uldaq (``github:mccdaq/uldaq`` at 1d84041, ``src/usb/``) and Warren Jasper's Linux
driver (``github:wjasper/Linux_Drivers``, ``USB/mcc-libusb/usb-1808.c`` / ``.h``); the twin has
its own request table (:class:`_Req`), status bits, struct layouts and limits below, each with its
source. The analogue world behind the inputs is a
:class:`~dimacq.simulators.lab.source.SampleSource`; global input ``k`` is input ``k % 8`` of
unit ``k // 8``. The external IEPE conditioner is ideal (gain 1, always powered). Each unit's ADC
has its own gain and offset error, which its EEPROM calibration table (written at "the factory":
the table corrects exactly the code errors) undoes; the driver learns them only by reading the
EEPROM.

As the device:

- **FPGA**: not configured at power-up (``fpga_configured=False``); DAQ requests stall until it
  is. FPGA_CONFIG with the unlock code 0xAD enters config mode (STATUS bit 9); FPGA_DATA outside
  config mode stalls (Jasper ``usbFPGAConfig_USB1808``), as does one over 64 bytes
  (``usbFPGAData_USB1808``: "max length is 64 bytes"). The bytes go to the Spartan-6
  (:class:`~dimacq.simulators.mcc.spartan6.Spartan6`): a text file never syncs, a truncated or
  other-size image never completes, so the unit stays unconfigured and keeps refusing scans.
- **EEPROM**: MEMORY reads of at most 64 bytes (uldaq ``setMemMaxReadSize(MT_EEPROM, 64)``) from
  the MEM_ADDRESS address, which auto-increments (Jasper ``usbMemoryR_USB1808``); longer reads
  stall. Calibration table at 0x7000: slope, offset f32 LE per input and range.
- **FIFO**: 32 KiB of samples (uldaq ``DaqIUsb1808.h`` ``FIFO_SIZE = 8 * 4 * 1024``): a host late
  by more overruns; the scan stops there and STATUS sets AIN_SCAN_OVERRUN (bit 2).

Clock: the unit started with a pacer period > 0 is the master; it drives :attr:`clock` (the
shared :class:`~dimacq.simulators.daq.clock.SampleClock` the load cell simulators count, as
they count the master's ICLKO) in time-lapse wall time (``time_scale``), or, with
``free_running=False`` (fast tests), as fast as the host reads. Units started with
pacer period 0 (external clock) take one scan per master pulse from the moment they are armed:
armed before the master starts, they scan in step. ``missed_pulses`` (fault) makes a slave lose
its first pulses (a loose clock cable).
"""

from __future__ import annotations

import array
import errno
import logging
import struct
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from enum import IntEnum
from typing import Any

import numpy as np
import usb.core

from dimacq.simulators.daq.backend import DaqInput
from dimacq.simulators.daq.clock import SampleClock
from dimacq.simulators.lab.source import SampleSource
from dimacq.simulators.mcc.spartan6 import Spartan6, synthetic_image
from dimacq.simulators.usb_device import Desc, OneBulkInBackend

__all__ = ["FIFO_BYTES", "Mcc1808Backend", "lab_fpga_image"]

log = logging.getLogger(__name__)

# -- the device's facts, each from the vendor's code -------------------------------------------
#: Jasper usb-1808.h: MCC's vendor id (pmd.h MCC_VID), USB1808X_PID
VID, PID_1808X = 0x09DB, 0x013E
#: libusb: IN | VENDOR | DEVICE = 0xC0, OUT | VENDOR | DEVICE = 0x40 (uldaq UsbDaqDevice.cpp
#: send/query)
BM_IN, BM_OUT = 0xC0, 0x40
#: uldaq DaqIUsb1808.cpp ``setScanEndpointAddr(0x86)``; Jasper ``LIBUSB_ENDPOINT_IN|6``
SCAN_ENDPOINT = 0x86
N_AI, N_RANGES = 8, 4
#: uldaq DaqIUsb1808.cpp ``unsigned char scanQueue[13]``
QUEUE_BYTES = 13
#: uldaq DaqIUsb1808.h ``FIFO_SIZE = 8 * 4 * 1024`` (bytes: 4 per sample)
FIFO_BYTES = 8 * 4 * 1024
SAMPLE_BYTES = 4
#: uldaq Usb1808.cpp ``mDaqDeviceInfo.setClockFreq(100000000)``
CLOCK_HZ = 100e6
#: uldaq AiUsb1808.cpp ``setCalCoefsStartAddr(0x7000)``, 32 coefficients of 2 f32
CAL_ADDRESS = 0x7000
#: uldaq UsbDaqDevice.cpp ``setMemMaxReadSize(MT_EEPROM, 64)``
MEM_READ_MAX = 64
#: Jasper usbFPGAData_USB1808 "max length is 64 bytes"; usbFPGAConfig_USB1808 ``0xad``
FPGA_DATA_MAX, UNLOCK = 64, 0xAD
#: 18-bit ADC (uldaq AiUsb1808.cpp ``setResolution(18)``); Jasper volts_USB1808
CODE_MAX, MID = 0x3FFFF, 131072
#: Jasper volts_USB1808: full scale of range codes 0..3 (BP_10V, BP_5V, UP_10V, UP_5V)
FULL_SCALE_V = (10.0, 5.0, 10.0, 5.0)
#: Jasper usbAInScanStart_USB1808 ``struct AInScan_t`` sent as 14 bytes (uldaq TAINSCAN_CFG)
SCAN_START = struct.Struct("<IIIBB")


class _Req(IntEnum):
    """Jasper usb-1808.c lines 40-82 (uldaq the same: DaqIUsb1808.h, AiUsb1808.h,
    UsbFpgaDevice.h, Usb1808.cpp)."""

    ADC_SETUP = 0x11
    AIN_SCAN_START = 0x12
    AIN_SCAN_STOP = 0x13
    AIN_CONFIG = 0x14
    AIN_CLR_FIFO = 0x15
    MEMORY = 0x30
    MEM_ADDRESS = 0x31
    STATUS = 0x40
    TRIGGER_CONFIG = 0x43
    SERIAL = 0x48
    FPGA_CONFIG = 0x50
    FPGA_DATA = 0x51
    FPGA_VERSION = 0x52


#: Jasper usb-1808.h status bits
ST_RUNNING, ST_OVERRUN, ST_CONFIGURED, ST_CONFIG_MODE = 1 << 1, 1 << 2, 1 << 8, 1 << 9


def lab_fpga_image() -> bytes:
    """The simulated lab's FPGA image: of the USB-1808 image's form and length
    (:func:`~dimacq.simulators.mcc.spartan6.synthetic_image`), as a lab's ``USB_1808.bin``."""
    return synthetic_image()


@dataclass
class _Unit:
    serial: str
    desc: Any
    slope: np.ndarray  # true ADC errors: raw = (ideal − offset) / slope
    offset: np.ndarray
    eeprom: dict[int, int]
    fpga: Spartan6
    fpga_configured: bool
    config_mode: bool = False
    mem_address: int = 0
    ranges: list[int] = field(default_factory=lambda: [0] * N_AI)
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
        Each unit's FIFO, bytes (the device's 32 KiB; 0: unbounded, for tests of other things).
    fpga_configured : bool
        Whether the units' FPGAs are loaded at power-up (a real one is not).
    missed_pulses : mapping of serial → int
        Pulses a slave misses at the start of its scan (fault).
    seed : int
        The units' ADC errors.
    """

    data_endpoint = SCAN_ENDPOINT
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
        fifo_bytes: int = FIFO_BYTES,
        adaptive: bool = False,
        fpga_configured: bool = False,
        missed_pulses: Mapping[str, int] | None = None,
        seed: int = 0,
    ) -> None:
        super().__init__()
        self.source = source
        self.wiring = dict(wiring)
        if any(not 0 <= k < N_AI * n_units for k in self.wiring):
            raise ValueError(f"wiring beyond the {n_units} unit(s) × {N_AI} inputs")
        serials = list(serials) if serials else [f"01F2A{u:03X}" for u in range(n_units)]
        self.clock = clock if clock is not None else SampleClock()
        self.free_running = free_running
        self.time_scale = float(time_scale)
        self.fifo_bytes = int(fifo_bytes)
        self.adaptive = bool(adaptive)
        self.sample_rate_hz = float(source.sample_rate_hz)
        self._epoch = 0
        self._world = 0
        self._run = -1
        rng = np.random.default_rng([seed, 1808])
        self.units: list[_Unit] = []
        for u, serial in enumerate(serials):
            slope = 1 + rng.normal(0, 2e-3, (N_AI, N_RANGES))
            offset = rng.normal(0, 30.0, (N_AI, N_RANGES))
            # what the factory stored (Jasper usbBuildGainTableAI_USB1808: for each input, for
            # each range, slope then offset as IEEE-754 f32 LE); the ADC errors then follow it
            pairs = np.stack([slope, offset], axis=-1).astype("<f4")
            slope32, offset32 = pairs[..., 0].astype(float), pairs[..., 1].astype(float)
            eeprom = {CAL_ADDRESS + i: b for i, b in enumerate(pairs.tobytes())}
            desc = Desc(
                bLength=18,
                bDescriptorType=1,
                bcdUSB=0x0200,
                bDeviceClass=0xFF,
                bDeviceSubClass=0,
                bDeviceProtocol=0,
                bMaxPacketSize0=64,
                idVendor=VID,
                idProduct=PID_1808X,
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
                    Spartan6(),
                    fpga_configured,
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
        s = 0
        if u.running and not self._frozen(u):
            s |= ST_RUNNING
        if u.overrun:
            s |= ST_OVERRUN
        if u.fpga_configured:
            s |= ST_CONFIGURED
        if u.config_mode:
            s |= ST_CONFIG_MODE
        return s

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
        R = _Req
        if bmRequestType == BM_IN:
            if bRequest == R.STATUS:  # Jasper usbStatus_USB1808: u16
                return self._answer(data, struct.pack("<H", self._status(u)))
            if bRequest == R.SERIAL:  # Jasper usbGetSerialNumber_USB1808: 8 ASCII bytes
                return self._answer(data, u.serial.encode("ascii")[:8].ljust(8, b"0"))
            if bRequest == R.FPGA_VERSION:  # Jasper usbFPGAVersion_USB1808: u16
                return self._answer(data, struct.pack("<H", 0x0103))
            if bRequest == R.MEMORY:
                if len(data) > MEM_READ_MAX:
                    raise self._stall(f"MEMORY read of {len(data)} bytes (at most 64)")
                out = bytes(u.eeprom.get(u.mem_address + i, 0xFF) for i in range(len(data)))
                u.mem_address += len(data)
                return self._answer(data, out)
            raise self._stall(f"unknown IN request {bRequest:#x}")
        if bmRequestType != BM_OUT:
            raise self._stall(f"request type {bmRequestType:#x}")
        payload = bytes(data)
        if bRequest == R.FPGA_DATA:
            if not u.config_mode or len(payload) > FPGA_DATA_MAX:
                raise self._stall("FPGA_DATA outside config mode or over 64 bytes")
            u.fpga.feed(payload)
            u.fpga_configured = u.fpga.done
            if u.fpga.error:
                log.info("simulated USB-1808X %s: FPGA %s", u.serial, u.fpga.error)
            return len(payload)
        if u.fpga_configured:
            # config mode ends with the next other request, not with the image: uldaq sends
            # two more FPGA_DATA bytes after it and fails on a stall (UsbFpgaDevice.cpp)
            u.config_mode = False
        if bRequest == R.MEM_ADDRESS:  # Jasper usbMemAddressW_USB1808: u16 LE
            if len(payload) != 2:
                raise self._stall("MEM_ADDRESS needs 2 bytes")
            u.mem_address = struct.unpack("<H", payload)[0]
        elif bRequest == R.FPGA_CONFIG:
            if payload != bytes([UNLOCK]):
                raise self._stall("FPGA_CONFIG without the unlock code 0xAD")
            u.config_mode, u.fpga_configured = True, False
            u.fpga.reset()
        elif not u.fpga_configured:
            raise self._stall(f"request {bRequest:#x} before the FPGA is configured")
        elif bRequest == R.AIN_SCAN_STOP:
            self._scan_stop(u)
        elif u.running:  # Jasper usbAInScanStart_USB1808: "a bus stall if an AInScan is running"
            raise self._stall(f"request {bRequest:#x} while scanning")
        elif bRequest == R.ADC_SETUP:  # Jasper usbADCSetupW_USB1808: range bits 1-0, mode 3-2
            if len(payload) != N_AI:
                raise self._stall("ADC_SETUP: 8 bytes of range | mode << 2 expected")
            u.ranges = [b & 3 for b in payload]
        elif bRequest == R.AIN_CONFIG:  # Jasper usbAInScanConfigW_USB1808: wIndex lastChan - 1
            queue = list(payload[: wIndex + 1])
            if (
                len(payload) != QUEUE_BYTES
                or wIndex >= QUEUE_BYTES
                or any(q >= N_AI for q in queue)
            ):
                raise self._stall("scan queue: 13 bytes, analogue inputs 0..7 expected")
            u.queue = queue
        elif bRequest == R.AIN_CLR_FIFO:
            u.sent, u.frozen, u.overrun = 0, 0, False
        elif bRequest == R.TRIGGER_CONFIG:
            if len(payload) != 1:
                raise self._stall("TRIGGER_CONFIG needs 1 byte")
        elif bRequest == R.AIN_SCAN_START:
            if len(payload) != SCAN_START.size:
                raise self._stall("AIN_SCAN_START needs 14 bytes")
            self._scan_start(u, *SCAN_START.unpack(payload))
        else:
            raise self._stall(f"unknown OUT request {bRequest:#x}")
        return len(payload)

    def _scan_start(
        self, u: _Unit, count: int, retrig: int, period: int, packet: int, options: int
    ) -> None:
        """Jasper usbAInScanStart_USB1808: pacer_period 0 = the ICLKO pin paces the scan, else
        ``100 MHz / (pacer_period + 1)``; the trigger options are not simulated."""
        u.sent, u.frozen, u.overrun, u.running = 0, None, False, True
        u.master = period > 0
        if u.master:
            rate = CLOCK_HZ / (period + 1)
            if abs(rate / self.sample_rate_hz - 1) > 1e-5:
                u.running = False
                raise self._stall(
                    f"pacer {rate:g} Hz: the simulated lab samples at {self.sample_rate_hz:g} Hz"
                )
            self._epoch = self._world
            scale = self.time_scale if self.free_running else None
            self.clock.start(
                self._epoch, self.sample_rate_hz, wall_scale=scale, adaptive=self.adaptive
            )
            self._run = self.clock.state().run
            u.run, u.offset_pulses = self._run, 0
            for s in self.units:  # armed slaves take the master's pulses from the first
                if s.running and not s.master and s.run == -1:
                    s.run, s.offset_pulses = self._run, s.missed
            self._hold_clock()
        else:
            st = self.clock.state()
            live = st.running and st.run == self._run
            u.run = self._run if live else -1
            u.offset_pulses = (st.count + u.missed) if live else 0
            self._hold_clock()

    def _hold_clock(self) -> None:
        """Adaptive time-lapse of the simulated lab: its clock may count up to each running
        unit's FIFO room, no further (the lab waits for a late host, as a simulation may; a
        real unit cannot, and overruns)."""
        if not (self.adaptive and self.free_running and self.fifo_bytes):
            return
        for u in self.units:
            key = f"mcc-{u.serial}"
            if u.running and u.run == self._run and u.frozen is None:
                cap = self.fifo_bytes // (SAMPLE_BYTES * len(u.queue))
                self.clock.hold_at(key, u.offset_pulses + u.sent + cap - 1)
            else:
                self.clock.hold_at(key, None)

    def _scan_stop(self, u: _Unit) -> None:
        if not u.running:
            return
        if u.master:
            count = self.clock.stop()
            self._world = self._epoch + count
        u.frozen = self._clocked(u)
        u.running = False
        self._hold_clock()

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
            cap = self.fifo_bytes // (SAMPLE_BYTES * len(u.queue))
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
            (j, self.wiring[unit * N_AI + q])
            for j, q in enumerate(u.queue)
            if unit * N_AI + q in self.wiring
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
        full = np.array([FULL_SCALE_V[int(r)] for r in rng])
        bipolar = rng <= 1  # Jasper volts_USB1808: BP_10V, BP_5V
        ideal = np.where(bipolar, volts / full * MID + MID, volts / full * CODE_MAX)
        raw = (ideal - u.offset[q, rng]) / u.slope[q, rng]
        return np.clip(np.rint(raw), 0, CODE_MAX).astype(np.int64)

    def bulk_read(
        self, dev_handle: Any, ep: int, intf: int, buff: array.array[int], timeout: int
    ) -> int:
        u: _Unit = dev_handle
        if ep != SCAN_ENDPOINT:
            raise usb.core.USBError("Pipe error", error_code=-9, errno=errno.EPIPE)
        want = len(buff) // (SAMPLE_BYTES * len(u.queue))
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
        # Jasper usbAInScanStart_USB1808: scan-major, each sample 32 bits (18-bit code, zeros)
        data = self._codes(u, u.sent, n).astype("<u4").tobytes()
        u.sent += n
        self._hold_clock()
        buff[: len(data)] = array.array("B", data)
        return len(data)
