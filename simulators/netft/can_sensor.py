"""A simulated ATI Net F/T on python-can's ``virtual`` bus, with the rig's request trigger.

The sensor reads the same bridge outputs of the virtual lab's load cell as the amplifier
simulators (:class:`~dimacq.simulators.lab.source.SampleSource` gauge channels) and turns them
into forces and torques with **its own** calibration matrix (the factory's, which the host never
sees: what the sensor holds), then into counts with its counts per force and per torque unit. It
answers the frames of :mod:`dimacq.drivers.netft.protocol` (the only thing it shares with the
driver): REQUEST LONG with its four answers, REQUEST SHORT with two, BIAS.

**It samples on its own clock.** A Net F/T samples its gauges free-running at its internal rate
(7000 S/s, ``adc_rate_hz``) and a REQUEST LONG copies the set it holds — the last one its
own clock sampled — into the answers (the manual: "the current force/torque set"); nothing in
it samples at the request. So sample ``n`` of its clock is taken at world position
``y_n = (n + φ) · fs / f_adc`` (``fs`` the world's rate, ``φ`` its clock's phase at power-on,
drawn from the seed; ``ppm`` its crystal's error) and a request at world position ``x``
answers ``n = ⌊x · f_adc / fs − φ⌋``, a value ``x − y_n`` old: 0 .. 1/f_adc s (0–143 µs at
7 kHz). The world exists as samples at ``fs``; between them it is interpolated band-limited
(the RDT simulator's 16-tap Kaiser-windowed sinc). Its answers carry ``n`` as their sample
number. The factory's low-pass filter is off (the sensor's default setting, not modelled).

The same thread plays the rig's **request trigger**: the bus interface that sends REQUEST LONG
on every pulse of the DAQ's sample clock (:class:`~dimacq.simulators.daq.clock.SampleClock`).
For pulse ``k`` of a DAQ run it sends the request, then the sensor's answers for world sample
``epoch + k``, so on the bus each request is followed by its four answers, as on a real bus
where a request during a transmission ends it. ``frame_loss_rate`` loses answers at random
(seeded; each one logged as a simulated fault).
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Sequence
from typing import Any

import can
import numpy as np
from numpy.typing import NDArray

from dimacq.drivers.netft import protocol as p
from dimacq.simulators.daq.clock import SampleClock
from dimacq.simulators.imperfections import fault_log
from dimacq.simulators.lab.held import held_sample, read_between
from dimacq.simulators.lab.source import SampleSource
from dimacq.simulators.loadcell.pulses import BURST_S
from dimacq.simulators.virtual_can import SimVirtualBus

__all__ = ["NetFtCanSim"]

log = logging.getLogger(__name__)

_CHUNK = 256


class NetFtCanSim:
    """Simulated Net F/T and request trigger; use as a context manager.

    Parameters
    ----------
    channel : str
        python-can virtual channel shared with the driver's bus.
    source : SampleSource
    gauge_channels : sequence of int
        Source channels of the cell's bridges.
    factory_matrix : array_like (6, n_gauges)
        The sensor's own calibration: loads (N, N·m) per gauge unit.
    calibration : CalibrationInfo
        Its counts per unit.
    base : int
        Its base address.
    clock : SampleClock, optional
        The DAQ's sample clock, whose pulses trigger the requests (None: host requests only).
    adc_rate_hz : float
        The sensor's own free-running sample rate (its sample number counts these).
    ppm : float
        Its crystal's error against the world's clock, parts per million.
    frame_loss_rate : float
        Per answer frame: probability it is lost on the bus.
    """

    def __init__(
        self,
        channel: str,
        source: SampleSource,
        gauge_channels: Sequence[int],
        factory_matrix: Any,
        calibration: p.CalibrationInfo,
        *,
        base: int = 0x020,
        clock: SampleClock | None = None,
        adc_rate_hz: float = 7000.0,
        ppm: float = 0.0,
        frame_loss_rate: float = 0.0,
        seed: int = 0,
    ) -> None:
        self.source = source
        self.gauges = np.asarray(gauge_channels, dtype=np.intp)
        self.C = np.asarray(factory_matrix, dtype=float)
        if self.C.shape != (6, len(self.gauges)):
            raise ValueError(f"factory matrix {self.C.shape} for {len(self.gauges)} gauges")
        self.counts_per_unit = 1.0 / calibration.si_per_count()
        self.base = p.check_base(base)
        self.clock = clock
        self.adc_rate_hz = adc_rate_hz
        self.frame_loss_rate = frame_loss_rate
        self.rng = np.random.default_rng([seed, base])
        #: its own samples per world sample, and its clock's phase at power-on (in its samples)
        self.per_world = adc_rate_hz * (1.0 + 1e-6 * ppm) / source.sample_rate_hz
        self.phase = float(self.rng.random())
        self.bias_g = np.zeros(len(self.gauges))
        self.status = 0
        self.injected: dict[str, int] = {}
        self._run = -1  # DAQ run whose pulses are being requested
        self._sent = 0  # pulses of that run requested
        self._epoch = 0
        self._lock = threading.Lock()
        self._stop_evt = threading.Event()
        self.bus = SimVirtualBus(channel=channel)
        self._thread = threading.Thread(target=self._loop, name=f"netft-sim-{channel}")
        self._thread.start()

    # -- lifetime ------------------------------------------------------------------------------
    def close(self) -> None:
        self._stop_evt.set()
        if self.clock is not None:
            self.clock.notify()
        self._thread.join(timeout=5.0)
        self.bus.shutdown()

    def __enter__(self) -> NetFtCanSim:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- physics -------------------------------------------------------------------------------
    def _source_lock(self) -> Any:
        return self.clock.source_lock if self.clock is not None else self._lock

    def _world_now(self) -> int:
        if self.clock is None:
            return 0
        st = self.clock.state()
        return st.epoch + st.count

    def held(self, x: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
        """For requests at world positions ``x``: the world position of the set it holds and
        that set's sample number, ``(y, n)``."""
        return held_sample(x, self.per_world, self.phase)

    def _read(self, y: NDArray[np.float64]) -> NDArray[np.float64]:
        return read_between(self.source, self.gauges, y, self._source_lock())

    def _counts(self, y: NDArray[np.float64]) -> NDArray[np.int64]:
        """Counts (n, 6) in AXES order of the sets held at world positions ``y``."""
        loads = self.C @ (self._read(y) - self.bias_g[:, None])  # (6, n) N, N·m
        return np.rint(loads.T * self.counts_per_unit).astype(np.int64)

    # -- wire ----------------------------------------------------------------------------------
    def _send(self, offset: int, data: bytes) -> None:
        self.bus.send(
            can.Message(arbitration_id=self.base + offset, data=data, is_extended_id=False)
        )

    def _lost(self, offset: int) -> None:
        self.injected["can_frame_loss"] = self.injected.get("can_frame_loss", 0) + 1
        fault_log.warning(
            "simulated fault can_frame_loss: Net F/T answer base+%d lost on the bus", offset
        )

    def _answer_long(self, counts: NDArray[np.int64], sample: int) -> None:
        for off, data in p.long_frames(counts.tolist(), self.status, sample & 0xFFFFFFFF):
            if self.frame_loss_rate and self.rng.random() < self.frame_loss_rate:
                self._lost(off)
                continue
            self._send(off, data)

    def _handle(self, data: bytes) -> None:
        try:
            req = p.Request.decode(data)
        except Exception:  # a real sensor ignores what it does not understand
            log.debug("Net F/T simulator: ignored request %s", data.hex())
            return
        world = self._world_now()
        y, n = self.held(np.array([float(world)]))
        if req.command == p.Command.REQUEST_LONG:
            self._answer_long(self._counts(y)[0], int(n[0]))
        elif req.command == p.Command.REQUEST_SHORT:
            c = self._counts(y)[0]
            sample = int(n[0])
            c16 = np.clip(c, -32768, 32767).tolist()
            self._send(5, p.ShortXY(c16[0], c16[3], c16[1], c16[4]).encode())
            self._send(6, p.ShortZ(c16[2], c16[5], self.status & 0x7FFF, sample & 0x7FFF).encode())
        elif req.command == p.Command.BIAS:
            with self._source_lock():
                self.bias_g = self.source.read(self.gauges, world, 1)[:, 0].copy()

    def _requests(self) -> int:
        """Pulses of the DAQ's clock not yet requested: request and answer them (one chunk)."""
        if self.clock is None:
            return 0
        st = self.clock.state()
        if st.run != self._run:
            if not st.running and st.count == 0:
                return 0
            self._run, self._sent = st.run, 0
        self._epoch = st.epoch
        n = min(st.count - self._sent, _CHUNK)
        if n <= 0:
            return 0
        k0 = self._sent
        world = (self._epoch + k0 + np.arange(n, dtype=np.int64)).astype(float)
        y, samples = self.held(world)
        counts = self._counts(y)
        payloads = p.long_payloads(counts, self.status, samples)
        lost = (
            self.rng.random((n, 4)) < self.frame_loss_rate
            if self.frame_loss_rate
            else np.zeros((n, 4), dtype=bool)
        )
        req = p.Request(p.Command.REQUEST_LONG).encode()
        base, send, Msg = self.base, self.bus.send, can.Message
        for j in range(n):
            send(Msg(arbitration_id=base, data=req, is_extended_id=False))
            for a in range(4):
                if lost[j, a]:
                    self._lost(a + 1)
                    continue
                send(
                    Msg(
                        arbitration_id=base + 1 + a,
                        data=payloads[j, a].tobytes(),
                        is_extended_id=False,
                    )
                )
        self._sent += n
        return n

    def _loop(self) -> None:
        try:
            while not self._stop_evt.is_set():
                msg = self.bus.recv(0.0)
                while msg is not None:
                    if msg.arbitration_id == self.base:
                        self._handle(bytes(msg.data))
                    msg = self.bus.recv(0.0)
                if self.bus.receivers_behind(self.base + 1):
                    # the pulses wait while the host holds too many frames, so its next
                    # answer is not queued behind seconds of them
                    self._stop_evt.wait(BURST_S)
                    continue
                sent = self._requests()
                if sent == 0:
                    if self.clock is not None:
                        self.clock.wait_change(self.clock.state(), BURST_S)
                    else:
                        self._stop_evt.wait(BURST_S)
                elif sent < _CHUNK:
                    self._stop_evt.wait(BURST_S)
        except Exception:  # pragma: no cover - surfaced through the test's timeouts
            log.exception("Net F/T simulator thread failed")
