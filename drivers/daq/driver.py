"""Driver of the dimacq USB DAQ over pyusb, with the backend injected.

Two layers, after NI-DAQmx and uldaq:

- :class:`DaqDevice` — the wire: vendor control requests and bulk frames of
  :mod:`dimacq.drivers.daq.protocol` on a ``usb.core.Device``. Public methods own timeouts,
  logging and validation and turn pyusb errors into :mod:`dimacq.errors`; the wire steps are
  :meth:`DaqDevice._control` and :meth:`DaqDevice._bulk_read` (template method,
  :class:`~dimacq.drivers.base.WireDriver`).
- :class:`DaqTask` — task → channels → timing → start / read / stop. Channels carry their
  transducer sensitivity (mV/g, mV/N, V/V) and come back in engineering units (m/s², N, V).
  Reads are aligned on the device's sample counter: a FIFO overflow, a lost transfer, an
  overloaded channel or a USB timeout is recorded as an event on the task and in the block,
  never silently patched. Samples already received are never dropped by an error (they are
  filed in the shared sample-counter buffer, :class:`~dimacq.drivers.stream.CounterStream`).

Opening a device (real or simulated is only the backend)::

    dev = DaqDevice.open(backend=None)            # libusb via pyusb's default backend
    dev = DaqDevice.open(backend=VirtualDaqBackend(source, wiring))   # the simulator
"""

from __future__ import annotations

import errno
import logging
import time
from collections.abc import Callable
from typing import Any, Literal

import numpy as np
import usb.core
import usb.util

from dimacq.devices.daq import ChannelConfig, DaqBlock, DaqEvent
from dimacq.drivers.base import Deadline, WireDriver
from dimacq.drivers.daq import protocol as p
from dimacq.drivers.stream import CounterStream
from dimacq.errors import (
    DeviceError,
    DeviceLostError,
    DeviceNotFoundError,
    DeviceStateError,
    DeviceTimeoutError,
    ProtocolError,
    SetupError,
)

__all__ = [
    "STANDARD_GRAVITY",
    "ChannelConfig",
    "DaqBlock",
    "DaqDevice",
    "DaqEvent",
    "DaqTask",
]

log = logging.getLogger(__name__)

#: m/s² per g, to turn mV/g into V/(m/s²).
STANDARD_GRAVITY = 9.80665


_BULK = "bulk read"
#: Draining stale frames before START: a read this short that times out means the FIFO is empty.
_DRAIN_TIMEOUT_S = 0.02
_DRAIN_MAX_FRAMES = 4096


class DaqDevice(WireDriver):
    """One dimacq USB DAQ (wire level).

    Parameters
    ----------
    device : usb.core.Device
        Found with the backend of choice (see :meth:`open`).
    timeout_s : float
        Default timeout of control and bulk transfers.
    retries : int
        Further attempts of a query (IDENTIFY, GET_STATUS) that timed out.
    """

    reopen_hint = "open it again with DaqDevice.open()"

    def __init__(self, device: Any, *, timeout_s: float = 1.0, retries: int = 0) -> None:
        self._dev = device
        super().__init__(f"DAQ {self._describe()}", timeout_s=timeout_s, retries=retries, log=log)
        try:
            device.set_configuration()
        except usb.core.USBError as err:
            raise DeviceError(
                f"DAQ {self._describe()}: cannot set its USB configuration ({err}); "
                "check permissions (udev rule for 1209:DA64) and that no other program holds it"
            ) from err

    @classmethod
    def open(
        cls, backend: Any = None, *, serial_number: str | None = None, timeout_s: float = 1.0
    ) -> DaqDevice:
        """Find the DAQ (VID 0x1209, PID 0xDA64) on ``backend`` and open it."""
        found = usb.core.find(
            find_all=True, idVendor=p.VENDOR_ID, idProduct=p.PRODUCT_ID, backend=backend
        )
        devices = list(found or [])
        for dev in devices:
            if serial_number is None:
                return cls(dev, timeout_s=timeout_s)
            ident = cls(dev, timeout_s=timeout_s).identify()
            if ident.serial_number == serial_number:
                return cls(dev, timeout_s=timeout_s)
            usb.util.dispose_resources(dev)
        wanted = f" with serial number {serial_number}" if serial_number else ""
        raise DeviceNotFoundError(
            f"no dimacq DAQ (USB 1209:DA64){wanted} found; check the cable and the backend, "
            "or use the simulator backend"
        )

    def _describe(self) -> str:
        return f"USB {getattr(self._dev, 'bus', '?')}:{getattr(self._dev, 'address', '?')}"

    # -- wire steps ------------------------------------------------------------------------
    def _control(
        self, bm: int, request: int, value: int, index: int, data: Any, timeout_ms: int
    ) -> Any:
        return self._dev.ctrl_transfer(bm, request, value, index, data, timeout_ms)

    def _bulk_read(self, n_bytes: int, timeout_ms: int) -> Any:
        return self._dev.read(p.DATA_ENDPOINT, n_bytes, timeout_ms)

    def _wire_error(self, err: Exception, what: str, deadline: Deadline) -> DeviceError | None:
        if not isinstance(err, usb.core.USBError):
            return None
        if err.errno == errno.ENODEV:
            return DeviceLostError(
                f"DAQ {self._describe()} dropped off the USB bus during {what.partition(' ')[0]} "
                f"({err}); it is found again by its serial number (DaqTask.reconnect)"
            )
        if what == _BULK:
            if isinstance(err, usb.core.USBTimeoutError):
                return DeviceTimeoutError(
                    f"DAQ sent no frame within {deadline.timeout_s} s; check that the task is "
                    "started and the sample clock runs"
                )
            return DeviceError(f"DAQ bulk read failed: {err}")
        name = what.partition(" ")[0]
        if isinstance(err, usb.core.USBTimeoutError):
            return DeviceTimeoutError(
                f"DAQ did not answer {name} within {deadline.timeout_s} s; check the USB connection"
            )
        if err.errno == errno.EPIPE:
            return DeviceStateError(
                f"DAQ refused {what}: the value is not supported or the device is streaming; "
                "read get_status() and stop the task before changing its configuration"
            )
        return DeviceError(f"DAQ {name} failed: {err}")

    # -- public, owning timeout, logging, validation ----------------------------------------
    def _request(
        self,
        request: p.Request,
        value: int = 0,
        index: int = 0,
        data: bytes | None = None,
        read_len: int | None = None,
    ) -> bytes:
        bm = p.BM_REQUEST_IN if read_len is not None else p.BM_REQUEST_OUT
        payload = read_len if read_len is not None else (data or b"")

        def attempt(deadline: Deadline) -> bytes:
            timeout_ms = max(1, int(deadline.timeout_s * 1000))
            ret = self._control(bm, int(request), value, index, payload, timeout_ms)
            return b"" if read_len is None else bytes(ret)

        return self._exchange(
            f"{request.name} (value={value}, index={index})",
            attempt,
            idempotent=read_len is not None,
        )

    def identify(self) -> p.DeviceIdentity:
        """IDENTIFY: model data, serial number, firmware."""
        return p.DeviceIdentity.decode(
            self._request(p.Request.IDENTIFY, read_len=p.IDENTIFY_STRUCT.size)
        )

    def get_status(self) -> p.DeviceStatus:
        """GET_STATUS: running, overflow, actual rate, samples clocked, frames lost."""
        return p.DeviceStatus.decode(
            self._request(p.Request.GET_STATUS, read_len=p.STATUS_STRUCT.size)
        )

    def set_sample_rate(self, rate_hz: int) -> None:
        if not 0 < rate_hz < 2**32:
            raise SetupError(f"sample rate {rate_hz} Hz is out of range; give 1 .. 2^32-1 Hz")
        self._request(p.Request.SET_SAMPLE_RATE, data=p.RATE_STRUCT.pack(int(rate_hz)))

    def set_channel_enable(self, channel: int, enabled: bool) -> None:
        self._request(p.Request.SET_CHANNEL_ENABLE, int(enabled), channel)

    def set_iepe(self, channel: int, current_ua: int) -> None:
        if current_ua not in p.IEPE_CURRENTS_UA:
            raise SetupError(
                f"channel {channel}: IEPE current {current_ua} µA is not supported; "
                f"choose one of {p.IEPE_CURRENTS_UA}"
            )
        self._request(p.Request.SET_IEPE, current_ua, channel)

    def set_range(self, channel: int, range_v: float) -> None:
        self._request(p.Request.SET_RANGE, range_code(range_v), channel)

    def set_coupling(self, channel: int, coupling: Literal["AC", "DC"]) -> None:
        self._request(p.Request.SET_COUPLING, 1 if coupling == "AC" else 0, channel)

    def start(self, samples_per_frame: int) -> None:
        if not 0 < samples_per_frame < 2**16:
            raise SetupError(f"samples_per_frame={samples_per_frame}; give 1 .. 65535")
        self._request(p.Request.START, samples_per_frame)

    def stop(self) -> None:
        self._request(p.Request.STOP)

    def read_frame(self, n_bytes: int, timeout_s: float | None = None) -> bytes:
        """Read one bulk frame of at most ``n_bytes``.

        Raises
        ------
        DeviceTimeoutError
            No frame within ``timeout_s`` (default :attr:`timeout_s`).
        """

        def attempt(deadline: Deadline) -> bytes:
            return bytes(self._bulk_read(n_bytes, max(1, int(deadline.timeout_s * 1000))))

        return self._exchange(_BULK, attempt, timeout_s=timeout_s)

    def _close_transport(self) -> None:
        usb.util.dispose_resources(self._dev)


def range_code(range_v: float) -> int:
    """Range code of ``±range_v`` volts (:data:`protocol.RANGES_V`)."""
    for code, r in enumerate(p.RANGES_V):
        if abs(r - range_v) < 1e-9 * r:
            return code
    raise SetupError(f"input range ±{range_v} V is not supported; choose one of {p.RANGES_V}")


class StreamedReads:
    """The reads of a task whose decoded samples sit in a :class:`CounterStream` (``_stream``):
    ``read`` / ``read_buffered`` / ``read_available`` over the task's ``_fill(n, timeout_s)``
    (receive until ``n`` samples are buffered), shared by our DAQ's and the USB-1808's tasks."""

    _stream: CounterStream
    sample_rate_hz: float | None

    @property
    def channels(self) -> tuple[ChannelConfig, ...]:
        raise NotImplementedError

    @property
    def channel_names(self) -> tuple[str, ...]:
        raise NotImplementedError

    def _fill(self, n_samples: int, timeout_s: float | None) -> None:
        raise NotImplementedError

    def read(self, n_samples: int, timeout_s: float | None = None) -> DaqBlock:
        """Read the next ``n_samples`` samples (blocking), in engineering units.

        Raises
        ------
        DeviceTimeoutError
            A frame did not arrive in time; what was received stays buffered for the next read.
        """
        if n_samples <= 0:
            raise SetupError(f"n_samples={n_samples}; read at least one sample")
        self._fill(n_samples, timeout_s)
        return self._take(n_samples)

    def read_buffered(self) -> DaqBlock | None:
        """Everything received and not yet read (e.g. after stop()), or None."""
        if self._stream.buffered == 0:
            return None
        return self._take(self._stream.buffered)

    def read_available(self, timeout_s: float | None = None) -> DaqBlock:
        """Read at least one more frame and return all buffered samples."""
        self._fill(self._stream.buffered + 1, timeout_s)
        return self._take(self._stream.buffered)

    def samples_clocked_now(self) -> int | None:
        """None: the task's device cannot say how far its clock is (see :class:`DaqTask`)."""
        return None

    def _take(self, n: int) -> DaqBlock:
        st = self._stream
        got = st.take(st.next_sample + n)
        events = st.pop_events(got.first, got.first + n)
        assert self.sample_rate_hz is not None
        return DaqBlock(
            got.first,
            self.sample_rate_hz,
            self.channel_names,
            tuple(c.units for c in self.channels),
            got.data.T,
            got.flags.astype(bool, copy=False).T,
            got.valid,
            events,
        )


def accel_config(
    physical_channel: int,
    name: str,
    sensitivity_mv_per_g: float,
    range_v: float,
    iepe_current_ma: float,
    coupling: Literal["AC", "DC"],
) -> ChannelConfig:
    """An IEPE accelerometer's channel in m/s²: ``v = S · 10⁻³ / g₀`` V per m/s² from ``S``
    mV/g, the IEPE current in whole µA."""
    v = sensitivity_mv_per_g * 1e-3 / STANDARD_GRAVITY
    ua = round(iepe_current_ma * 1000)
    return ChannelConfig(physical_channel, name, "m/s^2", v, range_v, ua, coupling)


def force_config(
    physical_channel: int,
    name: str,
    sensitivity_mv_per_n: float,
    range_v: float,
    iepe_current_ma: float,
    coupling: Literal["AC", "DC"],
) -> ChannelConfig:
    """An IEPE force sensor's channel in N: ``v = S · 10⁻³`` V per N from ``S`` mV/N, the
    IEPE current in whole µA."""
    ua = round(iepe_current_ma * 1000)
    return ChannelConfig(
        physical_channel, name, "N", sensitivity_mv_per_n * 1e-3, range_v, ua, coupling
    )


class ScanTask(StreamedReads):
    """The channel table and timing of a task scanning its device's inputs: one
    :class:`ChannelConfig` per physical input, returned in ascending input order (the order on
    the wire), the checks every such device makes before its own (not while running, one config
    per input, a positive sensitivity), the rate and frame size."""

    name: str
    samples_per_frame: int
    _running: bool
    _channels: dict[int, ChannelConfig]

    def _check_new_channel(self, config: ChannelConfig) -> None:
        """Raises DeviceStateError (running) or SetupError (input taken, sensitivity ≤ 0)."""
        if self._running:
            raise DeviceStateError(f"task {self.name} is running; stop it before adding channels")
        if config.physical_channel in self._channels:
            raise SetupError(
                f"physical channel {config.physical_channel} is already in task {self.name} "
                f"as {self._channels[config.physical_channel].name!r}; use another input"
            )
        if not config.sensitivity_v_per_unit > 0:
            raise SetupError(
                f"channel {config.name}: sensitivity {config.sensitivity_v_per_unit} V/unit; "
                "give the transducer's positive sensitivity from its calibration sheet"
            )

    def add_channel(self, config: ChannelConfig) -> None:
        raise NotImplementedError

    def add_voltage_channel(
        self,
        physical_channel: int,
        name: str,
        *,
        range_v: float = 10.0,
        coupling: Literal["AC", "DC"] = "DC",
    ) -> None:
        self.add_channel(ChannelConfig(physical_channel, name, "V", 1.0, range_v, 0, coupling))

    @property
    def channels(self) -> tuple[ChannelConfig, ...]:
        return tuple(self._channels[k] for k in sorted(self._channels))

    @property
    def channel_names(self) -> tuple[str, ...]:
        return tuple(c.name for c in self.channels)

    @property
    def running(self) -> bool:
        return self._running

    def configure_timing(self, sample_rate_hz: float, samples_per_frame: int = 256) -> None:
        if self._running:
            raise DeviceStateError(f"task {self.name} is running; stop it before changing timing")
        if not sample_rate_hz > 0 or samples_per_frame <= 0:
            raise SetupError(
                f"[daq] sample_rate_hz = {sample_rate_hz:g}, samples_per_frame = "
                f"{samples_per_frame}: give a positive rate and frame size"
            )
        self.sample_rate_hz = float(sample_rate_hz)
        self.samples_per_frame = int(samples_per_frame)


class DaqTask(ScanTask):
    """An acquisition task: channels → timing → start → read → stop (NI-DAQmx style).

    Channels come back in ascending physical-channel order (the order on the wire); their
    names are in :attr:`channel_names`.
    """

    def __init__(
        self,
        device: DaqDevice,
        name: str = "task",
        *,
        reopen: Callable[[], DaqDevice] | None = None,
    ) -> None:
        self.device = device
        self.name = name
        #: finds the same DAQ again after it dropped off the bus (:meth:`reconnect`)
        self.reopen = reopen
        #: times the device was found again after dropping off
        self.reconnects = 0
        self.clock_start_window: tuple[float, float] | None = None
        self._channels: dict[int, ChannelConfig] = {}
        self.sample_rate_hz: float | None = None
        self.samples_per_frame = 256
        self._running = False
        self._stream: CounterStream[DaqEvent] = CounterStream(0)
        self._next_sequence = 0
        self.events: list[DaqEvent] = []
        self._scale = np.zeros(0)
        #: Samples the DAQ clocked in the last run (GET_STATUS after STOP); None before a stop.
        #: It is at least the samples received: frames still in the device FIFO count too.
        self.samples_clocked: int | None = None

    # -- channels -----------------------------------------------------------------------------
    def identify(self) -> p.DeviceIdentity:
        """The DAQ's identity (the task's device)."""
        return self.device.identify()

    def add_channel(self, config: ChannelConfig) -> None:
        self._check_new_channel(config)
        range_code(config.range_v)
        if config.iepe_current_ua not in p.IEPE_CURRENTS_UA:
            raise SetupError(
                f"channel {config.name}: IEPE current {config.iepe_current_ua} µA; choose one "
                f"of {p.IEPE_CURRENTS_UA}"
            )
        self._channels[config.physical_channel] = config

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
        """IEPE accelerometer; data in m/s²."""
        self.add_channel(
            accel_config(
                physical_channel, name, sensitivity_mv_per_g, range_v, iepe_current_ma, coupling
            )
        )

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
        """IEPE force transducer (impact hammer, shaker stinger load cell); data in N."""
        self.add_channel(
            force_config(
                physical_channel, name, sensitivity_mv_per_n, range_v, iepe_current_ma, coupling
            )
        )

    # -- run -----------------------------------------------------------------------------------
    @property
    def frame_bytes(self) -> int:
        return p.frame_size(self.samples_per_frame, len(self._channels))

    def start(self) -> None:
        """Configure the device for this task and start the sample clock (counter 0)."""
        if self._running:
            raise DeviceStateError(f"task {self.name} is already running")
        if not self._channels:
            raise SetupError(f"task {self.name} has no channels; add channels before start()")
        if self.sample_rate_hz is None:
            raise SetupError(f"task {self.name}: call configure_timing() before start()")
        ident = self.device.identify()
        for ch in self.channels:
            if ch.physical_channel >= ident.n_channels:
                raise SetupError(
                    f"channel {ch.name}: physical channel {ch.physical_channel} does not exist "
                    f"on a {ident.n_channels}-channel DAQ"
                )
        self.device.set_sample_rate(round(self.sample_rate_hz))
        for k in range(ident.n_channels):
            self.device.set_channel_enable(k, k in self._channels)
        for ch in self.channels:
            self.device.set_range(ch.physical_channel, ch.range_v)
            self.device.set_iepe(ch.physical_channel, ch.iepe_current_ua)
            self.device.set_coupling(ch.physical_channel, ch.coupling)
        status = self.device.get_status()
        if abs(status.sample_rate_hz - self.sample_rate_hz) > 1e-9 * self.sample_rate_hz:
            raise SetupError(
                f"the DAQ runs at {status.sample_rate_hz} Hz, not the {self.sample_rate_hz} Hz "
                "asked for; choose a rate the device supports"
            )
        self._scale = np.array(
            [c.range_v / 2**23 / c.sensitivity_v_per_unit for c in self.channels]
        )
        self._stream = CounterStream(
            len(self._channels), flag_shape=(len(self._channels),), flag_dtype=np.bool_
        )
        self._next_sequence = 0
        self.events = []
        self.samples_clocked = None
        self._drain()
        t_before = time.monotonic()
        self.device.start(self.samples_per_frame)
        #: the host's monotonic clock before and after the START request: sample 0 lies between
        self.clock_start_window = (t_before, time.monotonic())
        self._running = True
        log.info(
            "DAQ task %s started: %d channels at %g Hz",
            self.name,
            len(self._channels),
            self.sample_rate_hz,
        )

    def _drain(self) -> None:
        """Read and discard frames left in the device FIFO by a previous run (before START).

        The FIFO is bounded, so this ends at the first read that times out; a stale frame
        larger than this task's frame is discarded by the USB stack (an overflow error).
        """
        stale = 0
        for _ in range(_DRAIN_MAX_FRAMES):
            try:
                self.device.read_frame(self.frame_bytes, _DRAIN_TIMEOUT_S)
            except DeviceTimeoutError:
                break
            except DeviceError:
                pass
            stale += 1
        else:
            raise DeviceStateError(
                f"task {self.name}: the DAQ still sends frames after {_DRAIN_MAX_FRAMES} stale "
                "ones were drained; another program may be running it, stop it and retry"
            )
        if stale:
            log.info("DAQ task %s: drained %d stale frame(s) before start", self.name, stale)

    def samples_clocked_now(self) -> int | None:
        """GET_STATUS's samples clocked since START while the task runs (None when stopped)."""
        if not self._running:
            return None
        return int(self.device.get_status().samples_clocked)

    def stop(self) -> None:
        """Stop the clock and read how many samples it clocked (:attr:`samples_clocked`).

        Samples already received stay readable (:meth:`read_buffered`).
        """
        if self._running:
            self._running = False
            self.device.stop()
            self.samples_clocked = self.device.get_status().samples_clocked
            log.info(
                "DAQ task %s stopped after %d samples clocked", self.name, self.samples_clocked
            )
            self._read_rest()

    def _read_rest(self) -> None:
        """Read what the device FIFO still holds after STOP (bounded by the samples clocked),
        so that its gaps (overflow, lost transfers) are reported and nothing is left stale."""
        assert self.samples_clocked is not None
        for _ in range(_DRAIN_MAX_FRAMES):
            if self._stream.end >= self.samples_clocked:
                return
            try:
                raw = self.device.read_frame(self.frame_bytes, _DRAIN_TIMEOUT_S)
            except DeviceTimeoutError:
                return
            self._ingest(p.decode_frame(raw))

    def reconnect(self, timeout_s: float = 10.0, poll_s: float = 0.1) -> None:
        """Find the DAQ again after it dropped off the bus (USB re-enumeration: a new address,
        a reset device) and make it this task's device; the task is stopped, its channels and
        timing are kept (the next :meth:`start` configures the device again). Samples already
        received stay readable (:meth:`read_buffered`).

        Raises
        ------
        DeviceNotFoundError
            No reopen function, or the DAQ did not come back within ``timeout_s``.
        """
        if self.reopen is None:
            raise DeviceNotFoundError(
                f"task {self.name}: the DAQ dropped off the bus and this task cannot find it "
                "again (no reopen function); open the device again"
            )
        self._running = False
        self.samples_clocked = None
        try:
            self.device.close()
        except Exception:  # the old handle is dead anyway
            log.debug("closing the lost DAQ handle failed", exc_info=True)
        deadline = time.monotonic() + timeout_s
        while True:
            try:
                self.device = self.reopen()
                break
            except DeviceNotFoundError as err:
                if time.monotonic() >= deadline:
                    raise DeviceNotFoundError(
                        f"task {self.name}: the DAQ dropped off the bus and did not come back "
                        f"within {timeout_s:g} s ({err})"
                    ) from err
                time.sleep(poll_s)
        self.reconnects += 1
        log.warning("DAQ task %s: the DAQ is back (%s)", self.name, self.device.name)

    def _record(self, ev: DaqEvent) -> None:
        self._stream.record(ev)
        self.events.append(ev)
        log.warning("DAQ task %s: %s", self.name, ev.message)

    def _ingest(self, frame: p.Frame) -> None:
        st = self._stream
        names = self.channel_names
        expected = st.end  # the sample after the last one received
        if frame.n_channels != len(names):
            raise ProtocolError(
                f"frame {frame.sequence} carries {frame.n_channels} channels, the task "
                f"enabled {len(names)}; stop and restart the task"
            )
        if frame.first_sample < expected:
            raise ProtocolError(
                f"frame {frame.sequence} starts at sample {frame.first_sample}, before the "
                f"expected {expected}; the sample counter went backwards"
            )
        lost_seq = (frame.sequence - self._next_sequence) & 0xFFFFFFFF
        gap = frame.first_sample - expected
        if gap:
            if frame.flags & p.FrameFlags.OVERFLOW:
                kind = "overflow"
                msg = (
                    f"device FIFO overflow: samples {expected}..{frame.first_sample - 1} "
                    "lost (read faster or lower the rate/channel count)"
                )
            else:
                kind = "lost_transfer"
                msg = (
                    f"{lost_seq} bulk transfer(s) lost (sequence {self._next_sequence} → "
                    f"{frame.sequence}): samples {expected}..{frame.first_sample - 1} lost"
                )
            # the buffer reads the missing samples as NaN, not valid
            self._record(DaqEvent(kind, expected, gap, names, msg))
        elif lost_seq:
            raise ProtocolError(
                f"frame sequence jumped {self._next_sequence} → {frame.sequence} without a "
                "sample gap; the stream is inconsistent, stop and restart the task"
            )
        data = frame.to_float(self._scale)
        overload = np.zeros(data.shape, dtype=bool)
        if frame.overload_mask:
            bits = [(frame.overload_mask >> k) & 1 for k in range(len(names))]
            over = np.array(bits, dtype=bool)
            overload[:, over] = True
            self._record(
                DaqEvent(
                    "overload",
                    frame.first_sample,
                    frame.n_samples,
                    tuple(n for n, o in zip(names, over, strict=True) if o),
                    f"overload on {', '.join(n for n, o in zip(names, over, strict=True) if o)} "
                    f"in samples {frame.first_sample}..{frame.first_sample + frame.n_samples - 1}"
                    "; raise the input range",
                )
            )
        st.put(frame.first_sample, data, overload)
        self._next_sequence = (frame.sequence + 1) & 0xFFFFFFFF

    def _fill(self, n_samples: int, timeout_s: float | None) -> None:
        while self._stream.buffered < n_samples:
            if not self._running:
                raise DeviceStateError(
                    f"task {self.name} is not running and holds {self._stream.buffered} of "
                    f"the {n_samples} samples asked for; start() it or read_buffered()"
                )
            try:
                raw = self.device.read_frame(self.frame_bytes, timeout_s)
            except DeviceTimeoutError as err:
                st = self._stream
                self._record(
                    DaqEvent(
                        "timeout",
                        st.end,
                        0,
                        (),
                        f"USB timeout after sample {st.end - 1}; {st.buffered} samples "
                        "kept in the buffer",
                    )
                )
                raise DeviceTimeoutError(
                    f"task {self.name}: {err} ({self._stream.buffered} samples received and "
                    "kept; read again to continue)"
                ) from err
            self._ingest(p.decode_frame(raw))
