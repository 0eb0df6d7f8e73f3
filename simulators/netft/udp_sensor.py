"""A simulated ATI Net F/T's RDT interface on a loopback UDP socket.

It answers the RDT requests of :mod:`dimacq.drivers.netft.protocol` (the codec is all it shares
with the driver): START (real-time: one record per datagram; buffered: ``per_datagram`` records
per datagram), STOP, SET_BIAS; and Read Calibration Info on its TCP port.

It samples on **its own clock**: a crystal ``ppm`` off, ``time_scale`` × wall time (the lab's
time-lapse), its internal counter ``ft_sequence`` at ``ft_rate_hz`` since it was powered, and
records at ``rdt_rate_hz``; record ``j`` of a stream is its state at its own instant, and is sent
once that instant has passed (buffered: with the records before it). What it measures is the
lab's bridge outputs at the lab's physical time of that instant — the DAQ's free-running clock
gives the world's sample position at a wall time (fractional) — through the sensor's own
calibration, in its counts per unit. The world exists as samples at the DAQ's rate; between them
it is interpolated band-limited, as a real sensor samples the continuous signal: a 16-tap
Kaiser-windowed sinc (β = 8, :func:`sinc_weights`), within 0.05 % and 0.01° up to 0.33 × the
DAQ's rate. (The 4-point cubic it replaced lost up to 27 % of the amplitude and ±5° of phase at
0.32 × the rate, the automatic band's top, varying with the instant's fraction: the data's delay
fit read it as a delay that changes across the band.) Nothing of the DAQ's clock reaches the driver: only the records, their sequence numbers
and when they arrive. ``drop`` lists ``rdt_sequence`` numbers whose datagram is lost (once
each); ``loss_rate`` loses datagrams at random.
"""

from __future__ import annotations

import logging
import math
import socket
import threading
import time
from collections.abc import Sequence
from typing import Any

import numpy as np

from dimacq.drivers.netft import protocol as p
from dimacq.simulators.daq.clock import SampleClock
from dimacq.simulators.imperfections import fault_log
from dimacq.simulators.lab.held import INTERP_TAPS, sinc_weights
from dimacq.simulators.lab.source import SampleSource

__all__ = ["NetFtUdpSim"]

#: how far ahead of its last record's instant a datagram is measured, wall s
_AHEAD_S = 0.0004
log = logging.getLogger(__name__)


class NetFtUdpSim:
    """Use as a context manager; :attr:`address` is where it listens (``host``, ``port``; port
    0 picks a free one)."""

    def __init__(
        self,
        source: SampleSource,
        gauge_channels: Sequence[int],
        factory_matrix: Any,
        calibration: p.CalibrationInfo,
        *,
        clock: SampleClock | None = None,
        rdt_rate_hz: float = 1000.0,
        ft_rate_hz: float = 7000.0,
        time_scale: float = 1.0,
        ppm: float = 0.0,
        host: str = "127.0.0.1",
        port: int = 0,
        per_datagram: int = 10,
        drop: Sequence[int] = (),
        loss_rate: float = 0.0,
        seed: int = 0,
    ) -> None:
        self.source = source
        self.gauges = np.asarray(gauge_channels, dtype=np.intp)
        self.C = np.asarray(factory_matrix, dtype=float)
        self.counts_per_unit = 1.0 / calibration.si_per_count()
        self.clock = clock
        self.rdt_rate = float(rdt_rate_hz)
        self.ft_rate = float(ft_rate_hz)
        self.ft_step = round(ft_rate_hz / rdt_rate_hz)
        #: its seconds per wall second
        self.speed = time_scale * (1.0 + 1e-6 * ppm)
        self.per_datagram = per_datagram
        self.drop = set(drop)
        self.loss_rate = loss_rate
        self._rng = np.random.default_rng([seed, 0x4D7])
        self.bias_g = np.zeros(len(self.gauges))
        self.status = 0
        self._t_power = time.monotonic()
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind((host, port))
        self.sock.settimeout(0.002)
        self.address: tuple[str, int] = self.sock.getsockname()[:2]
        # its TCP command interface (Read Calibration Info), on its own loopback port
        self.calibration = calibration
        self.tcp = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        self.tcp.bind((host, 0 if port == 0 else port - 1))
        self.tcp.listen(4)
        self.tcp.settimeout(0.0)
        self.tcp_address: tuple[str, int] = self.tcp.getsockname()[:2]
        self._peer: Any = None
        self._left = 0  # records still to send (-1: until STOP)
        self._buffered = False
        self._tick0 = 0  # its internal tick of record 0 of this stream
        self._sent = 0  # records of this stream measured (sent, pending or lost)
        self._pending: list[tuple[float, bytes]] = []  # (wall time due, datagram)
        self._lock = threading.Lock()
        self._stop_evt = threading.Event()
        self._thread = threading.Thread(target=self._loop, name=f"netft-rdt-sim-{self.address}")
        self._thread.start()

    def close(self) -> None:
        self._stop_evt.set()
        self._thread.join(timeout=5.0)
        self.sock.close()
        self.tcp.close()

    def __enter__(self) -> NetFtUdpSim:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- its clock ---------------------------------------------------------------------------------
    def _own_s(self, wall: float) -> float:
        return (wall - self._t_power) * self.speed

    def _wall(self, own_s: float) -> float:
        return self._t_power + own_s / self.speed

    def _read(self, walls: np.ndarray) -> np.ndarray:
        """The bridge outputs at wall times ``walls``: shape (n_gauges, n)."""
        lock = self.clock.source_lock if self.clock is not None else self._lock
        with lock:
            pos = None if self.clock is None else self.clock.position_at(float(walls[0]))
            if pos is None:  # no run clocks: the world stands at the last sample reached
                at = 0
                if self.clock is not None:
                    st = self.clock.state()
                    at = st.epoch + st.count
                return np.repeat(self.source.read(self.gauges, at, 1), len(walls), axis=1)
            clock = self.clock
            assert clock is not None
            st = clock.state()
            # pulses per wall second: the clock's rate × its time-lapse
            per_s = (clock.position_at(float(walls[0]) + 1.0) or pos) - pos
            x = pos + (walls - walls[0]) * per_s
            # before the run's first pulse the world stands where the last run left it
            x = np.maximum(x, st.epoch)
            idx = np.floor(x).astype(np.int64)[:, None] + INTERP_TAPS[None, :]  # (n, 16)
            lo = max(0, int(idx.min()))
            y = self.source.read(self.gauges, lo, int(idx.max()) + 1 - lo)
        w = sinc_weights(x[:, None] - idx)
        return np.einsum("gnk,nk->gn", y[:, np.clip(idx - lo, 0, y.shape[1] - 1)], w)

    def _counts(self, walls: np.ndarray) -> np.ndarray:
        loads = self.C @ (self._read(walls) - self.bias_g[:, None])
        return np.rint(loads.T * self.counts_per_unit).astype(np.int64)

    # -- requests ----------------------------------------------------------------------------------
    def _handle(self, data: bytes, peer: Any) -> None:
        try:
            req = p.RdtRequest.decode(data)
        except Exception:  # a real sensor ignores what it does not understand
            log.debug("RDT simulator: ignored %s", data.hex())
            return
        if req.command == p.RdtCommand.SET_BIAS:
            self.bias_g = self._read(np.array([time.monotonic()]))[:, 0].copy()
        elif req.command == p.RdtCommand.STOP:
            self._left = 0
            self._pending.clear()
        else:
            self._peer = peer
            self._buffered = req.command == p.RdtCommand.START_BUFFERED
            self._left = req.sample_count if req.sample_count else -1
            self._sent = 0
            self._pending.clear()
            # the first record: its next output instant
            self._tick0 = math.ceil(self._own_s(time.monotonic()) * self.rdt_rate) * self.ft_step

    def _due(self, j: int) -> float:
        """Wall time of record ``j`` of the stream."""
        return self._wall((self._tick0 + j * self.ft_step) / self.ft_rate)

    def _prepare(self) -> None:
        """The next datagram, measured ahead (its records' instants are at most
        :data:`_AHEAD_S` away: the world is settled that far) so that it leaves on time."""
        group = self.per_datagram if self._buffered else 1
        n = group if self._left < 0 else min(group, self._left)
        js = self._sent + np.arange(n)
        walls = self._t_power + (self._tick0 + js * self.ft_step) / self.ft_rate / self.speed
        if walls[-1] - time.monotonic() > _AHEAD_S:
            return
        self._sent += n
        if self._left > 0:
            self._left -= n
        seq = js + 1
        hit = set(seq.tolist()) & self.drop
        if hit or (self.loss_rate and self._rng.random() < self.loss_rate):
            self.drop -= hit  # each listed datagram is lost once
            fault_log.warning(
                "simulated fault udp_loss: RDT datagram of rdt_sequence %d lost", int(seq[0])
            )
            return
        ft = self._tick0 + js * self.ft_step
        data = p.encode_rdt(seq, ft, self.status, self._counts(walls))
        self._pending.append((float(walls[-1]), data))

    def _stream(self) -> float:
        """Send what is due; the wall time of the next thing to do."""
        now = time.monotonic()
        while not self._stop_evt.is_set():
            now = time.monotonic()
            while self._pending and self._pending[0][0] <= now:
                self.sock.sendto(self._pending.pop(0)[1], self._peer)
            if self._left == 0 or len(self._pending) > 1:
                break
            before = len(self._pending)
            sent_before = self._sent
            self._prepare()
            if len(self._pending) == before and self._sent == sent_before:
                break
        nxt = self._pending[0][0] if self._pending else now + 0.001
        if self._left != 0:
            group = self.per_datagram if self._buffered else 1
            nxt = min(nxt, self._due(self._sent + group - 1) - _AHEAD_S)
        return nxt

    def _serve_tcp(self) -> None:
        """Answer a Read Calibration Info on each connection waiting (one command each)."""
        try:
            conn, _ = self.tcp.accept()
        except (BlockingIOError, OSError):
            return
        with conn:
            conn.settimeout(1.0)
            try:
                cmd = conn.recv(20)
                if cmd[:1] == bytes([p.CalibrationInfo.READCALINFO]):
                    conn.sendall(self.calibration.encode())
            except OSError:
                log.debug("RDT simulator: TCP client went away")

    def _loop(self) -> None:
        """Requests served as they come; each datagram sent once its last record's instant has
        passed (slept for precisely: a socket timeout would round to the millisecond)."""
        self.sock.settimeout(0.0)
        try:
            while not self._stop_evt.is_set():
                while True:
                    try:
                        data, peer = self.sock.recvfrom(65535)
                    except (BlockingIOError, TimeoutError):
                        break
                    self._handle(data, peer)
                nxt = time.monotonic() + 0.001
                if self._peer is not None and (self._left != 0 or self._pending):
                    nxt = min(nxt, self._stream())
                self._serve_tcp()
                wait = nxt - time.monotonic()
                if wait > 0:
                    time.sleep(min(wait, 0.001))
        except OSError:
            if not self._stop_evt.is_set():  # closed under it at close(): not a failure
                log.exception("RDT simulator thread failed")
        except Exception:  # pragma: no cover - surfaced through the test's timeouts
            log.exception("RDT simulator thread failed")
