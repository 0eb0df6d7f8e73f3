"""A simulated ATI Net F/T's RDT interface on a loopback UDP socket.

It answers the RDT requests of :mod:`dimacq.drivers.netft.protocol` (the codec is all it shares
with the driver): START (real-time: one record per datagram; buffered: ``per_datagram`` records
per datagram), STOP, SET_BIAS. Its records are paced on its own clock (``rdt_rate_hz`` in wall
time × ``time_scale``), not the DAQ's, and read the lab's bridge outputs at the world sample the
DAQ's clock has reached (or sample 0 when there is none) through the sensor's own calibration,
in its counts per unit. ``drop`` lists ``rdt_sequence`` numbers whose datagram is lost (once each).
"""

from __future__ import annotations

import logging
import socket
import threading
import time
from collections.abc import Sequence
from typing import Any

import numpy as np

from dimacq.drivers.netft import protocol as p
from dimacq.simulators.daq.clock import SampleClock
from dimacq.simulators.imperfections import fault_log
from dimacq.simulators.lab.source import SampleSource

__all__ = ["NetFtUdpSim"]

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
        time_scale: float = 1.0,
        host: str = "127.0.0.1",
        port: int = 0,
        per_datagram: int = 10,
        drop: Sequence[int] = (),
    ) -> None:
        self.source = source
        self.gauges = np.asarray(gauge_channels, dtype=np.intp)
        self.C = np.asarray(factory_matrix, dtype=float)
        self.counts_per_unit = 1.0 / calibration.si_per_count()
        self.clock = clock
        self.rate = rdt_rate_hz * time_scale
        self.per_datagram = per_datagram
        self.drop = set(drop)
        self.bias_g = np.zeros(len(self.gauges))
        self.status = 0
        self.ft_sequence = 0
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
        self._seq = 0
        self._t0 = 0.0
        self._sent = 0
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

    def _world_now(self) -> int:
        if self.clock is None:
            return 0
        st = self.clock.state()
        return st.epoch + st.count

    def _read(self) -> np.ndarray:
        lock = self.clock.source_lock if self.clock is not None else self._lock
        with lock:
            return self.source.read(self.gauges, self._world_now(), 1)[:, 0]

    def _counts(self) -> tuple[int, int, int, int, int, int]:
        loads = self.C @ (self._read() - self.bias_g)
        c = np.rint(loads * self.counts_per_unit).astype(np.int64)
        return (int(c[0]), int(c[1]), int(c[2]), int(c[3]), int(c[4]), int(c[5]))

    def _handle(self, data: bytes, peer: Any) -> None:
        try:
            req = p.RdtRequest.decode(data)
        except Exception:  # a real sensor ignores what it does not understand
            log.debug("RDT simulator: ignored %s", data.hex())
            return
        if req.command == p.RdtCommand.SET_BIAS:
            self.bias_g = self._read().copy()
        elif req.command == p.RdtCommand.STOP:
            self._left = 0
        else:
            self._peer = peer
            self._buffered = req.command == p.RdtCommand.START_BUFFERED
            self._left = req.sample_count if req.sample_count else -1
            self._seq = 0
            self._sent = 0
            self._t0 = time.monotonic()

    def _stream(self) -> None:
        due = int((time.monotonic() - self._t0) * self.rate) + 1 - self._sent
        group = self.per_datagram if self._buffered else 1
        while due >= group and self._left != 0:
            n = group if self._left < 0 else min(group, self._left)
            recs = []
            for _ in range(n):
                self._seq += 1
                self.ft_sequence += 1
                recs.append(p.RdtRecord(self._seq, self.ft_sequence, self.status, self._counts()))
            self._sent += n
            due -= n
            if self._left > 0:
                self._left -= n
            hit = {r.rdt_sequence for r in recs} & self.drop
            if hit:
                self.drop -= hit  # each listed datagram is lost once
                fault_log.warning(
                    "simulated fault udp_loss: RDT datagram of rdt_sequence %d lost",
                    recs[0].rdt_sequence,
                )
                continue
            self.sock.sendto(b"".join(r.encode() for r in recs), self._peer)

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
        try:
            while not self._stop_evt.is_set():
                try:
                    data, peer = self.sock.recvfrom(65535)
                    self._handle(data, peer)
                except TimeoutError:
                    pass
                if self._left != 0 and self._peer is not None:
                    self._stream()
                self._serve_tcp()
        except Exception:  # pragma: no cover - surfaced through the test's timeouts
            log.exception("RDT simulator thread failed")
