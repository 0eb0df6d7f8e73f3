"""Driver of Measurement Computing USB-1808(X) DAQs over pyusb, one unit or several in step.

Two layers, as for our own DAQ (:mod:`dimacq.drivers.daq.driver`):

- :class:`Usb1808` — one unit on the wire: the vendor requests and bulk scans of
  :mod:`dimacq.drivers.mcc.protocol` (facts from MCC's uldaq, ``github:mccdaq/uldaq``
  ``src/usb/``, and Warren Jasper's Linux driver, ``github:wjasper/Linux_Drivers``
  ``USB/mcc-libusb/usb-1808.c``) on an injected ``usb.core.Device``: FPGA load (the binary
  image of :mod:`dimacq.drivers.mcc.fpga`), EEPROM calibration table in 64-byte reads, ADC setup,
  scan queue, scan start/stop, status, bulk reads.
- :class:`MccTask` — a :class:`~dimacq.devices.daq.Daq` over one or more units. Physical
  channel ``k`` is input ``k % 8`` of unit ``k // 8`` (units in the rig file's ``[daq] units``
  order). **Several units in step**: the first unit is the clock master (its pacer at
  ``100 MHz / (N + 1)``, output on its ICLKO pin); the others are started first with pacer
  period 0, i.e. paced by their external clock input wired to the master's ICLKO, so every unit
  takes scan ``s`` on master pulse ``s``. The task reads the same number of scans from each
  unit and, at stop, checks that every unit delivered exactly as many scans as the master
  clocked (a :class:`~dimacq.errors.ProtocolError` otherwise: a loose clock cable).

**IEPE conditioning is external**: the USB-1808X has DC-coupled voltage inputs only; IEPE
accelerometers and hammers go through an IEPE signal conditioner (constant current, AC coupling,
gain 1) whose BNC outputs are wired single-ended to the DAQ. The rig file's ``iepe_current_ma``
and ``coupling`` are that conditioner's settings, not sent to the DAQ; its sensitivities
(mV/g, mV/N) give volts per unit as for any DAQ. Inputs: ±10 V or ±5 V ranges, single-ended.

The bulk stream has no sample counter and no overload flags: scan ``s`` is the ``s``-th scan
received; a code at either end of the 18-bit scale is an overload; a FIFO overrun (status bit
AIN_SCAN_OVERRUN) ends the unit's scan, which the task reports as an ``overflow`` event.

**Host buffer**, as uldaq's: the unit's FIFO holds 32 KiB of samples (8192 samples: 0.5 s of
eight inputs at 2 kHz), so the task reads every unit's bulk endpoint continuously in one
background thread, started by ``start()`` and joined by ``stop()``, into a bounded host buffer
per unit (``host_buffer_s`` of scans); ``read`` takes from that buffer. A unit whose host buffer
is full is not read until the program reads; if its FIFO overruns meanwhile, the error names
the host falling behind (the program did not read for ``host_buffer_s``), not the device. An
error in the thread is raised by the next read that needs what the thread did not deliver.
"""

from __future__ import annotations

import errno
import logging
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
import usb.core
import usb.util

from dimacq.devices.daq import ChannelConfig, DaqEvent
from dimacq.drivers.base import Deadline, WireDriver
from dimacq.drivers.daq.driver import STANDARD_GRAVITY, StreamedReads
from dimacq.drivers.mcc import protocol as p
from dimacq.drivers.stream import CounterStream
from dimacq.errors import (
    DeviceError,
    DeviceLostError,
    DeviceStateError,
    DeviceTimeoutError,
    ProtocolError,
    SetupError,
)

__all__ = ["MccIdentity", "MccTask", "Usb1808"]

log = logging.getLogger(__name__)

_BULK = "bulk read"
#: the pacer's quantisation (100 MHz / (N + 1)) accepted against the asked rate: below the
#: 100 MHz oscillator's own tolerance
RATE_TOLERANCE = 1e-5
_DRAIN_TIMEOUT_S = 0.05
#: the host buffer per unit, seconds of scans (uldaq's applications hold seconds of scans)
HOST_BUFFER_S = 10.0
#: the reader thread's bulk-read timeout (at least two transfers' time): how long ``stop()``
#: may wait for the thread's read in progress
_READER_TIMEOUT_S = 0.25


class Usb1808(WireDriver):
    """One USB-1808 / USB-1808X (wire level), on an injected ``usb.core.Device``.

    Raises
    ------
    DeviceError
        The USB configuration cannot be set (permissions, another program).
    """

    def __init__(self, device: Any, *, timeout_s: float = 1.0) -> None:
        self._dev = device
        self.model = p.PRODUCT_IDS.get(int(getattr(device, "idProduct", 0)), "USB-1808?")
        super().__init__(f"{self.model} {self._describe()}", timeout_s=timeout_s, log=log)
        try:
            device.set_configuration()
        except usb.core.USBError as err:
            raise DeviceError(
                f"{self.name}: cannot set its USB configuration ({err}); check permissions "
                "(udev rule for 09db:013e, config/udev) and that no other program holds it"
            ) from err

    def _describe(self) -> str:
        return f"USB {getattr(self._dev, 'bus', '?')}:{getattr(self._dev, 'address', '?')}"

    # -- wire steps ------------------------------------------------------------------------
    def _control(self, bm: int, req: int, value: int, index: int, data: Any, ms: int) -> Any:
        return self._dev.ctrl_transfer(bm, req, value, index, data, ms)

    def _bulk_read(self, n_bytes: int, timeout_ms: int) -> Any:
        return self._dev.read(p.DATA_ENDPOINT, n_bytes, timeout_ms)

    def _wire_error(self, err: Exception, what: str, deadline: Deadline) -> DeviceError | None:
        if not isinstance(err, usb.core.USBError):
            return None
        if err.errno == errno.ENODEV:
            return DeviceLostError(f"{self.name} dropped off the USB bus during {what} ({err})")
        if isinstance(err, usb.core.USBTimeoutError):
            return DeviceTimeoutError(
                f"{self.name}: no answer to {what} within {deadline.timeout_s} s; check the USB "
                "cable and, on a slave unit, the clock cable from the master's ICLKO"
            )
        if err.errno == errno.EPIPE:
            return DeviceStateError(
                f"{self.name} refused {what} (stall): a scan is running or the value is not "
                "supported; stop the scan and check the configuration"
            )
        return DeviceError(f"{self.name}: {what} failed: {err}")

    def _out(self, req: p.Request, data: bytes = b"", value: int = 0, index: int = 0) -> None:
        def attempt(deadline: Deadline) -> None:
            ms = max(1, int(deadline.timeout_s * 1000))
            self._control(p.BM_REQUEST_OUT, int(req), value, index, data, ms)

        self._exchange(f"{req.name}", attempt)

    def _in(self, req: p.Request, length: int, value: int = 0, index: int = 0) -> bytes:
        def attempt(deadline: Deadline) -> bytes:
            ms = max(1, int(deadline.timeout_s * 1000))
            return bytes(self._control(p.BM_REQUEST_IN, int(req), value, index, length, ms))

        got: bytes = self._exchange(f"{req.name}", attempt, idempotent=True)
        if len(got) != length:
            raise ProtocolError(f"{self.name}: {req.name} gave {len(got)} bytes, not {length}")
        return got

    # -- commands --------------------------------------------------------------------------
    def status(self) -> p.Status:
        """STATUS (u16 bits)."""
        return p.Status(p.STATUS_STRUCT.unpack(self._in(p.Request.STATUS, 2))[0])

    def serial_number(self) -> str:
        """SERIAL: 8 ASCII characters."""
        return self._in(p.Request.SERIAL, 8).decode("ascii", "replace").rstrip("\x00 ")

    def fpga_version(self) -> int:
        return int(p.STATUS_STRUCT.unpack(self._in(p.Request.FPGA_VERSION, 2))[0])

    def configure_fpga(self, image: bytes, source: str = "the FPGA image") -> None:
        """Load the FPGA as uldaq's ``UsbFpgaDevice::loadFpga`` and Jasper's ``usbInit_1808`` do:
        FPGA_CONFIG with the unlock code, STATUS must say FPGA_CONFIG_MODE, the image in 64-byte
        FPGA_DATA transfers and two zero bytes after it, then STATUS must say FPGA_CONFIGURED.

        Raises
        ------
        SetupError
            ``image`` is not the binary image (text, no sync word, another length): nothing sent.
        DeviceStateError
            The unit does not enter config mode, or is not configured after the image.
        """
        try:
            p.check_fpga_image(image, source)
        except ValueError as err:
            raise SetupError(str(err)) from err
        self._out(p.Request.FPGA_CONFIG, bytes([p.FPGA_UNLOCK]))
        if not self.status() & p.Status.FPGA_CONFIG_MODE:
            raise DeviceStateError(f"{self.name} does not enter FPGA config mode; power-cycle it")
        for piece in p.fpga_transfers(image):
            self._out(p.Request.FPGA_DATA, piece)
        if not self.status() & p.Status.FPGA_CONFIGURED:
            raise DeviceStateError(
                f"{self.name}: FPGA not configured after {len(image)} bytes of {source}; "
                "power-cycle it and give uldaq's USB_1808.bin as daq_fpga_file "
                "(DIMACQ_DAQ_FPGA_FILE)"
            )

    def read_memory(self, address: int, length: int) -> bytes:
        """MEM_ADDRESS once, then MEMORY reads of at most 64 bytes (the address
        auto-increments), as uldaq's ``memRead_SingleCmd``: ``length`` EEPROM bytes."""
        self._out(p.Request.MEM_ADDRESS, p.ADDRESS_STRUCT.pack(address))
        return b"".join(self._in(p.Request.MEMORY, n) for n in p.eeprom_reads(length))

    def read_calibration(self) -> tuple[np.ndarray, np.ndarray]:
        """The factory calibration table (slope, offset), each shape (8 inputs, 4 ranges)."""
        return p.calibration_table(self.read_memory(p.CAL_BASE_ADDRESS, p.CAL_TABLE_BYTES))

    def adc_setup(self, ranges: list[p.Range], modes: list[p.InputMode]) -> None:
        self._out(p.Request.AIN_ADC_SETUP, p.adc_setup(ranges, modes))

    def scan_config(self, inputs: list[int]) -> None:
        index, data = p.scan_queue(inputs)
        self._out(p.Request.AIN_SCAN_CONFIG, data, index=index)

    def clear_fifo(self) -> None:
        self._out(p.Request.AIN_CLR_FIFO)

    def scan_start(self, start: p.AInScanStart) -> None:
        self._out(p.Request.AIN_SCAN_START, start.encode())

    def scan_stop(self) -> None:
        self._out(p.Request.AIN_SCAN_STOP)

    def read_scans(self, n_bytes: int, timeout_s: float | None = None) -> bytes:
        """One bulk transfer of at most ``n_bytes`` (short after a stop)."""

        def attempt(deadline: Deadline) -> bytes:
            return bytes(self._bulk_read(n_bytes, max(1, int(deadline.timeout_s * 1000))))

        data: bytes = self._exchange(_BULK, attempt, timeout_s=timeout_s)
        return data

    def _close_transport(self) -> None:
        usb.util.dispose_resources(self._dev)


@dataclass(frozen=True)
class MccIdentity:
    """Who the DAQ is: model, the master's serial number, every unit's, FPGA version."""

    model: str
    serial_number: str
    units: tuple[str, ...]
    firmware: str
    n_channels: int


@dataclass
class _UnitRun:
    """A unit's part of a run: its inputs, calibration row per queued input, its host buffer
    (``scans``, ``held`` scans in it) and the scans read off the wire (``received``)."""

    unit: Usb1808
    inputs: list[int]
    columns: list[int]  # task channel index of each queued input
    ranges: np.ndarray
    slope: np.ndarray
    offset: np.ndarray
    scans: list[np.ndarray]
    received: int = 0
    held: int = 0
    overrun: bool = False
    drained: bool = False  # after stop: read until a timeout


def range_of(config: ChannelConfig) -> p.Range:
    """±10 V or ±5 V (the bipolar ranges a conditioned AC signal needs).

    Raises
    ------
    SetupError
        Any other range, naming the channel and the fix.
    """
    for code in (p.Range.BP_10V, p.Range.BP_5V):
        if abs(config.range_v - p.RANGES_V[code]) < 1e-9:
            return code
    raise SetupError(
        f"channel {config.name}: range_v = {config.range_v:g} V; the USB-1808X has ±10 V and "
        "±5 V: set range_v to 10 or 5 in the rig file (a bridge needs an amplifier before it)"
    )


class MccTask(StreamedReads):
    """A :class:`~dimacq.devices.daq.Daq` task on USB-1808(X) units (first = clock master).

    Parameters
    ----------
    units : sequence of Usb1808
        In channel order: inputs ``8u .. 8u + 7`` are unit ``u``'s.
    name : str
    calibrations : sequence of (slope, offset), optional
        Each unit's EEPROM table (read from the units when not given).
    host_buffer_s : float
        Each unit's host buffer, seconds of scans: ``ceil(host_buffer_s · rate)`` scans (at
        least two transfers).

    ``samples_clocked_now()`` is None: the unit's STATUS is flags only (no scan count in the
    command set read), so an impact session looks for a hit from what it has read.
    """

    def __init__(
        self,
        units: Sequence[Usb1808],
        name: str = "task",
        *,
        calibrations: Sequence[tuple[np.ndarray, np.ndarray]] | None = None,
        host_buffer_s: float = HOST_BUFFER_S,
    ) -> None:
        if not units:
            raise SetupError("no USB-1808 unit; connect one and give its serial in [daq] units")
        if not host_buffer_s > 0:
            raise SetupError(
                f"host_buffer_s = {host_buffer_s}: give the host buffer's length in seconds (> 0)"
            )
        self.host_buffer_s = float(host_buffer_s)
        self.units = list(units)
        self.name = name
        self.calibrations = (
            list(calibrations)
            if calibrations is not None
            else [u.read_calibration() for u in units]
        )
        self.serials = tuple(u.serial_number() for u in self.units)
        self._channels: dict[int, ChannelConfig] = {}
        self.sample_rate_hz: float | None = None
        self.samples_per_frame = 256
        self.events: list[DaqEvent] = []
        self.samples_clocked: int | None = None
        self._running = False
        self._runs: list[_UnitRun] = []
        self._stream: CounterStream[DaqEvent] = CounterStream(0)
        self._scale = np.zeros(0)
        # shared with the reader thread, under _cond: each run's host buffer and counts,
        # the thread's failure and the host overflow
        self._cond = threading.Condition()
        self._reader: threading.Thread | None = None
        self._halt = threading.Event()
        self._host_scans = 0
        self._failure: Exception | None = None
        self._failure_is_overflow = False
        self._failure_reported = False
        self._waited = False
        self._full_at = 0
        self._host_behind: str | None = None

    # -- identity and channels ---------------------------------------------------------------
    def identify(self) -> MccIdentity:
        master = self.units[0]
        n = len(self.units)
        return MccIdentity(
            master.model if n == 1 else f"{master.model} ×{n}",
            self.serials[0],
            self.serials,
            f"FPGA {master.fpga_version():#06x}",
            p.N_AI * n,
        )

    def add_channel(self, config: ChannelConfig) -> None:
        if self._running:
            raise DeviceStateError(f"task {self.name} is running; stop it before adding channels")
        k = config.physical_channel
        if not 0 <= k < p.N_AI * len(self.units):
            raise SetupError(
                f"channel {config.name}: physical_channel {k} is beyond the {len(self.units)} "
                f"unit(s) ({p.N_AI} inputs each); add the unit's serial to [daq] units"
            )
        if k in self._channels:
            raise SetupError(
                f"physical channel {k} is already in task {self.name} as "
                f"{self._channels[k].name!r}; use another input"
            )
        if not config.sensitivity_v_per_unit > 0:
            raise SetupError(
                f"channel {config.name}: sensitivity {config.sensitivity_v_per_unit} V/unit; "
                "give the transducer's positive sensitivity from its calibration sheet"
            )
        range_of(config)
        self._channels[k] = config

    def _add(self, k: int, name: str, units: str, v_per_unit: float, range_v: float) -> None:
        # IEPE current and coupling belong to the external conditioner (module docstring)
        self.add_channel(ChannelConfig(k, name, units, v_per_unit, range_v, 0, "DC"))

    def add_accel_channel(
        self,
        physical_channel: int,
        name: str,
        sensitivity_mv_per_g: float,
        *,
        range_v: float = 5.0,
        iepe_current_ma: float = 4.0,
        coupling: Literal["AC", "DC"] = "AC",
    ) -> None:
        """An accelerometer behind the external IEPE conditioner; data in m/s²."""
        v = sensitivity_mv_per_g * 1e-3 / STANDARD_GRAVITY
        self._add(physical_channel, name, "m/s^2", v, range_v)

    def add_force_channel(
        self,
        physical_channel: int,
        name: str,
        sensitivity_mv_per_n: float,
        *,
        range_v: float = 5.0,
        iepe_current_ma: float = 4.0,
        coupling: Literal["AC", "DC"] = "AC",
    ) -> None:
        """A force transducer (hammer) behind the external IEPE conditioner; data in N."""
        self._add(physical_channel, name, "N", sensitivity_mv_per_n * 1e-3, range_v)

    def add_voltage_channel(
        self,
        physical_channel: int,
        name: str,
        *,
        range_v: float = 10.0,
        coupling: Literal["AC", "DC"] = "DC",
    ) -> None:
        self._add(physical_channel, name, "V", 1.0, range_v)

    @property
    def channels(self) -> tuple[ChannelConfig, ...]:
        return tuple(self._channels[k] for k in sorted(self._channels))

    @property
    def channel_names(self) -> tuple[str, ...]:
        return tuple(c.name for c in self.channels)

    def configure_timing(self, sample_rate_hz: float, samples_per_frame: int = 256) -> None:
        """The scan rate (the master's pacer ``100 MHz / (N + 1)`` must hit it within
        :data:`RATE_TOLERANCE`) and the scans per bulk transfer.

        Raises
        ------
        SetupError
            A rate the pacer cannot give, naming ``[daq] sample_rate_hz``.
        """
        if self._running:
            raise DeviceStateError(f"task {self.name} is running; stop it before changing timing")
        if not (0 < sample_rate_hz <= 200_000) or samples_per_frame <= 0:
            raise SetupError(
                f"[daq] sample_rate_hz = {sample_rate_hz:g}, samples_per_frame = "
                f"{samples_per_frame}: the USB-1808X scans at up to 200 kHz; give a rate in "
                "(0, 200000] Hz and a positive frame size"
            )
        actual = p.pacer_rate_hz(p.pacer_period(sample_rate_hz))
        if abs(actual / sample_rate_hz - 1) > RATE_TOLERANCE:
            raise SetupError(
                f"[daq] sample_rate_hz = {sample_rate_hz:g}: the USB-1808X pacer gives "
                f"100 MHz/(N+1) = {actual:.6g} Hz at best; choose a rate 100 MHz/(N+1)"
            )
        self.sample_rate_hz = float(sample_rate_hz)
        self.samples_per_frame = int(samples_per_frame)

    @property
    def running(self) -> bool:
        return self._running

    # -- run ------------------------------------------------------------------------------------
    def start(self) -> None:
        """Configure every unit (ADC ranges, scan queue, clear FIFO), arm the slaves on their
        external clock, then start the master's pacer."""
        if self._running:
            raise DeviceStateError(f"task {self.name} is already running")
        if not self._channels:
            raise SetupError(f"task {self.name} has no channels; add channels before start()")
        if self.sample_rate_hz is None:
            raise SetupError(f"task {self.name}: call configure_timing() before start()")
        chans = self.channels
        self._runs = []
        for u, unit in enumerate(self.units):
            cols = [j for j, c in enumerate(chans) if c.physical_channel // p.N_AI == u]
            if not cols and u > 0:
                continue  # a slave with nothing to read is not started
            inputs = [chans[j].physical_channel % p.N_AI for j in cols] or [0]
            rng = [p.Range.BP_10V] * p.N_AI
            for j in cols:
                rng[chans[j].physical_channel % p.N_AI] = range_of(chans[j])
            unit.scan_stop()
            unit.adc_setup(rng, [p.InputMode.SINGLE_ENDED] * p.N_AI)
            unit.scan_config(inputs)
            unit.clear_fifo()
            slope, offset = self.calibrations[u]
            ranges = np.array([rng[i] for i in inputs])
            self._runs.append(
                _UnitRun(
                    unit, inputs, cols, ranges, slope[inputs, ranges], offset[inputs, ranges], []
                )
            )
        self._scale = np.array([1.0 / c.sensitivity_v_per_unit for c in chans])
        self._stream = CounterStream(len(chans), flag_shape=(len(chans),), flag_dtype=np.bool_)
        self.events = []
        self.samples_clocked = None
        transfer = max(self._transfer(r) for r in self._runs)
        self._host_scans = max(int(np.ceil(self.host_buffer_s * self.sample_rate_hz)), 2 * transfer)
        self._failure, self._failure_is_overflow, self._failure_reported = None, False, False
        self._waited, self._full_at, self._host_behind = False, 0, None
        master, slaves = self._runs[0], self._runs[1:]
        for r in slaves:  # armed first: they take a scan on each master pulse from the first
            r.unit.scan_start(p.AInScanStart(0, 0, 0))
        master.unit.scan_start(p.AInScanStart(0, 0, p.pacer_period(self.sample_rate_hz)))
        self._running = True
        self._halt.clear()
        self._reader = threading.Thread(
            target=self._read_continuously, name=f"MCC reader {self.name}", daemon=True
        )
        self._reader.start()
        log.info(
            "MCC task %s started: %d channels on %d unit(s) at %g Hz",
            self.name,
            len(chans),
            len(self._runs),
            self.sample_rate_hz,
        )

    def _read_unit(self, r: _UnitRun, timeout_s: float | None) -> int:
        """One bulk transfer of about ``samples_per_frame`` scans of unit ``r`` (whole 512-byte
        packets, :func:`~dimacq.drivers.mcc.protocol.scans_per_transfer`) into its host buffer;
        the scans read."""
        n_q = len(r.inputs)
        data = r.unit.read_scans(self._transfer(r) * n_q * 4, timeout_s)
        try:
            codes = p.decode_scans(data, n_q)
        except ValueError as err:
            raise ProtocolError(f"{r.unit.name}: {err}; stop and restart the task") from err
        got = int(codes.shape[0])
        if got:
            with self._cond:
                r.scans.append(codes)
                r.received += got
                r.held += got
                self._cond.notify_all()
        return got

    def _transfer(self, r: _UnitRun) -> int:
        return p.scans_per_transfer(self.samples_per_frame, len(r.inputs))

    def _fail(self, err: Exception, *, overflow: bool = False) -> None:
        """Keep the reader's first failure for the reads."""
        with self._cond:
            if self._failure is None:
                self._failure, self._failure_is_overflow = err, overflow
            self._cond.notify_all()

    def _read_continuously(self) -> None:
        """The reader thread: a transfer of the unit with the fewest scans received, in turn;
        once ``stop()`` has stopped the scans (``_halt``), each unit until a read times out
        (its FIFO is empty), then the thread ends.

        A unit whose host buffer has no room for a transfer is not read until the program
        reads (the unit's FIFO fills meanwhile); if a FIFO overran during such a wait, the
        overrun is the host's falling behind. A timeout with a unit's AIN_SCAN_OVERRUN set ends
        the thread (that scan has stopped), as does any other error, kept for the reads.
        """
        assert self.sample_rate_hz is not None
        transfer_s = max(self._transfer(r) for r in self._runs) / self.sample_rate_hz
        timeout_s = max(_READER_TIMEOUT_S, 2 * transfer_s)
        try:
            while True:
                halted = self._halt.is_set()
                todo = [r for r in self._runs if not (halted and r.drained)]
                if not todo:
                    return
                lag = min(todo, key=lambda r: r.received)
                if not halted and self._wait_for_room(lag):
                    continue
                try:
                    self._read_unit(lag, _DRAIN_TIMEOUT_S if halted else timeout_s)
                except DeviceTimeoutError:
                    if not self._running:  # stop() has begun: no status asked
                        lag.drained = self._halt.is_set()
                        continue
                    over = [r for r in self._runs if r.unit.status() & p.Status.AIN_SCAN_OVERRUN]
                    if not over:
                        continue  # no scan yet: a read waiting longer says so
                    for r in over:
                        r.overrun = True
                    msg = self._host_behind or (
                        f"{over[0].unit.name} FIFO overrun after scan {over[0].received}: its "
                        "scan stopped (read faster or lower the rate); stop and restart the task"
                    )
                    self._fail(DeviceStateError(msg), overflow=True)
                    return
        except Exception as err:  # re-raised by the next read
            log.error("MCC task %s: reader thread failed: %s", self.name, err)
            self._fail(err)

    def _wait_for_room(self, r: _UnitRun) -> bool:
        """Whether unit ``r``'s host buffer had no room for a transfer (then wait up to
        :data:`_READER_TIMEOUT_S` for a read); on resuming after such a wait, a unit whose FIFO
        overran meanwhile is put down to the host (:attr:`_host_behind`)."""
        with self._cond:
            if r.held + self._transfer(r) <= self._host_scans:
                if not self._waited:
                    return False
                self._waited = False
            else:
                if not self._waited:
                    self._waited = True
                    self._full_at = r.received
                    log.debug(
                        "MCC task %s: the host buffer of %s is full (%d scans unread); not "
                        "reading it until the program reads",
                        self.name,
                        r.unit.name,
                        r.held,
                    )
                self._cond.wait(_READER_TIMEOUT_S)
                return True
        if self._host_behind is None and any(
            u.unit.status() & p.Status.AIN_SCAN_OVERRUN for u in self._runs
        ):
            assert self.sample_rate_hz is not None
            self._host_behind = (
                f"task {self.name}: the host fell behind: its buffer of {r.unit.name} held "
                f"{self._host_scans} scans ({self._host_scans / self.sample_rate_hz:.3g} s) "
                f"unread after scan {self._full_at}, so it was not read and the unit's FIFO "
                "overran; read more often or give a larger host_buffer_s, then restart"
            )
        return False

    def _halt_reader(self) -> None:
        self._halt.set()
        if self._reader is not None:
            self._reader.join()
            self._reader = None

    def _merge(self) -> None:
        """Scans every unit has delivered to its host buffer → engineering units in the counter
        stream."""
        first = self._stream.end
        with self._cond:
            n = min(r.received for r in self._runs) - first
            if n <= 0:
                return
            taken = []
            for r in self._runs:
                codes = np.concatenate(r.scans) if len(r.scans) > 1 else r.scans[0]
                rest = codes[n:]
                r.scans = [rest] if rest.shape[0] else []
                r.held -= n
                taken.append(codes[:n])
            self._cond.notify_all()  # room in the host buffers
        n_ch = len(self._channels)
        volts = np.zeros((n, n_ch))
        over = np.zeros((n, n_ch), dtype=bool)
        for r, codes in zip(self._runs, taken, strict=True):
            v, clip = p.codes_to_volts(codes, r.ranges, r.slope, r.offset)
            if r.columns:
                volts[:, r.columns] = v[:, : len(r.columns)]
                over[:, r.columns] = clip[:, : len(r.columns)]
        if over.any():
            names = self.channel_names
            hit = tuple(names[int(k)] for k in np.flatnonzero(over.any(axis=0)))
            self._record(
                DaqEvent(
                    "overload",
                    first,
                    n,
                    hit,
                    f"overload on {', '.join(hit)} in samples {first}..{first + n - 1}; raise "
                    "the input range or lower the conditioner's gain",
                )
            )
        self._stream.put(first, volts * self._scale, over)

    def _record(self, ev: DaqEvent) -> None:
        self._stream.record(ev)
        self.events.append(ev)
        log.warning("MCC task %s: %s", self.name, ev.message)

    def _fill(self, n_samples: int, timeout_s: float | None) -> None:
        """Wait (at most ``timeout_s``, else the master's USB timeout) until the host buffers
        hold ``n_samples`` scans of every unit beyond those read.

        Raises
        ------
        DeviceTimeoutError
            Not in time; what arrived stays buffered for the next read.
        DeviceStateError
            A unit's FIFO overran or the host buffer did (after the samples before it).
        DeviceError
            The reader thread's error (USB, protocol), after the samples before it.
        """
        wait_s = self.units[0].timeout_s if timeout_s is None else timeout_s
        deadline = time.monotonic() + wait_s
        while True:
            self._merge()
            st = self._stream
            if st.buffered >= n_samples:
                return
            if not self._running:
                raise DeviceStateError(
                    f"task {self.name} is not running and holds {st.buffered} of the "
                    f"{n_samples} samples asked for; start() it or read_buffered()"
                )
            with self._cond:
                more = min(r.received for r in self._runs) > st.end
                failure = self._failure
                if not more and failure is None:
                    left = deadline - time.monotonic()
                    if left > 0:
                        self._cond.wait(left)
                        continue
            if more:
                continue
            if failure is not None:
                if self._failure_is_overflow and not self._failure_reported:
                    self._failure_reported = True
                    self._record(DaqEvent("overflow", st.end, 0, self.channel_names, str(failure)))
                raise failure
            lag = min(self._runs, key=lambda r: r.received)
            self._record(
                DaqEvent("timeout", st.end, 0, (), f"USB timeout after sample {st.end - 1}")
            )
            raise DeviceTimeoutError(
                f"task {self.name}: no scan from {lag.unit.name} within {wait_s} s; check the "
                "USB cable and, on a slave unit, the clock cable from the master's ICLKO "
                f"({st.buffered} samples kept; read again)"
            )

    def stop(self) -> None:
        """Stop the master's pacer (every unit stops with it), stop the slaves, read what each
        FIFO still holds, and check that every unit delivered the scans the master clocked.

        Raises
        ------
        ProtocolError
            A unit delivered another number of scans than the master (clock cable), or
            overran (the samples after its overrun are reported as an ``overflow`` event first).
        DeviceStateError
            A unit's FIFO overran while its host buffer was full (the program fell behind).
        """
        if not self._running:
            return
        self._running = False
        try:
            for r in self._runs:
                r.unit.scan_stop()
        finally:
            self._halt_reader()  # the thread reads what the FIFOs still hold
        for r in self._runs:  # unless it ended first (an error)
            while not r.drained and self._read_unit_quiet(r):
                pass
        counts = [r.received for r in self._runs]
        self.samples_clocked = counts[0]
        self._merge()
        log.info("MCC task %s stopped: scans per unit %s", self.name, counts)
        bad = [
            f"{r.unit.name} ({self.serials[self.units.index(r.unit)]}): {r.received}"
            for r in self._runs[1:]
            if r.received != counts[0]
        ]
        overrun = [r.unit.name for r in self._runs if r.unit.status() & p.Status.AIN_SCAN_OVERRUN]
        if bad or overrun:
            end = self._stream.end
            if counts[0] > end:
                self._record(
                    DaqEvent(
                        "overflow",
                        end,
                        counts[0] - end,
                        self.channel_names,
                        f"samples {end}..{counts[0] - 1} missing on a slave unit",
                    )
                )
            if overrun and self._host_behind:  # the host buffer was full: the host's fault
                raise DeviceStateError(self._host_behind)
            if overrun:  # an overrun stops that unit's scan: counts differ for that reason
                raise ProtocolError(
                    f"task {self.name}: FIFO overrun on {', '.join(overrun)} (the host read "
                    f"later than its 32 KiB FIFO holds; scans per unit {counts}): read faster, "
                    "lower the rate or the load on this PC, then restart"
                )
            raise ProtocolError(
                f"task {self.name}: the master clocked {counts[0]} scans but {'; '.join(bad)}; "
                "check the clock cable from the master's ICLKO to each slave's clock input, "
                "then restart"
            )

    def _read_unit_quiet(self, r: _UnitRun) -> int:
        try:
            return self._read_unit(r, _DRAIN_TIMEOUT_S)
        except DeviceTimeoutError:
            return 0

    def close(self) -> None:
        """Close the units (a running task is stopped first; its errors are logged)."""
        try:
            self.stop()
        except DeviceError as err:
            log.warning("MCC task %s: stopping before close: %s", self.name, err)
        finally:
            self._halt_reader()
            for u in self.units:
                u.close()
