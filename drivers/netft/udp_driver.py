"""ATI Net F/T Raw Data Transfer (RDT) over UDP: requests and records of
:mod:`dimacq.drivers.netft.protocol`, on an injected, connected UDP socket.

What it does: one record on demand (:meth:`NetFtUdp.read_once`, :meth:`NetFtUdp.identify`), the
software bias, and streams (:meth:`NetFtUdp.start_streaming`, :meth:`NetFtUdp.read_records`):
a jump of ``rdt_sequence`` is a lost datagram, counted in :attr:`NetFtUdp.lost` and logged.

What it does not do: put records on the DAQ's sample counter. RDT streams on the sensor's own
clock (its rate set on its web page) from the moment the START datagram arrives, with nothing
that ties it to the DAQ's clock, so its samples cannot be aligned to the accelerometers' to a
fraction of a sample — and at 600 Hz a 0.5 ms offset is a 108° phase error in the load cell's
FRF. As a :class:`~dimacq.devices.loadcell.LoadCell` it therefore refuses to start an
acquisition on the DAQ's clock (a :class:`~dimacq.errors.SetupError` naming the alternatives:
``netft-can`` with requests on the DAQ's clock, or the sensor's analogue outputs as
``daq-channels``); the devices check (identify) works.
"""

from __future__ import annotations

import logging
from typing import Any

import numpy as np

from dimacq.devices.loadcell import LoadCellBlock, LoadCellEvent, LoadCellIdentity
from dimacq.drivers.base import Deadline, WireDriver
from dimacq.drivers.netft import protocol as p
from dimacq.errors import DeviceError, DeviceTimeoutError, SetupError

__all__ = ["NetFtUdp"]

log = logging.getLogger(__name__)

_NOT_ON_DAQ_CLOCK = (
    "{name}: RDT over UDP streams on the sensor's own clock with nothing tying it to the "
    "DAQ's, so its samples cannot be aligned to the accelerometers' for FRFs; use "
    "loadcell = 'netft-can' with REQUEST LONG sent on the DAQ's clock, or its analogue "
    "outputs as loadcell = 'daq-channels'"
)


class NetFtUdp(WireDriver):
    """A Net F/T's RDT interface on ``sock`` (``socket.socket(AF_INET, SOCK_DGRAM)`` connected
    to its address, port 49152).

    Parameters
    ----------
    sock : socket.socket
    calibration : CalibrationInfo
        Its counts per force and torque unit.
    serial_number : int
        What :meth:`identify` reports.
    """

    def __init__(
        self,
        sock: Any,
        *,
        calibration: p.CalibrationInfo,
        serial_number: int = 0,
        timeout_s: float = 1.0,
        label: str = "Net F/T",
    ) -> None:
        peer = "?"
        try:
            host, port = sock.getpeername()[:2]
            peer = f"{host}:{port}"
        except (OSError, TypeError):
            pass
        super().__init__(f"{label} (RDT {peer})", timeout_s=timeout_s, log=log)
        self.sock = sock
        self.calibration = calibration
        self.calibration_matrix: np.ndarray | None = calibration.matrix()
        self.serial_number = serial_number
        self.sample_rate_hz: float | None = None
        self.events: list[LoadCellEvent] = []
        #: datagrams lost in the current stream (rdt_sequence jumps)
        self.lost = 0
        self._next_seq: int | None = None

    @property
    def n_gauges(self) -> int:
        return 6

    # -- wire steps ------------------------------------------------------------------------------
    def _send(self, req: p.RdtRequest) -> None:
        try:
            self.sock.send(req.encode())
        except OSError as err:
            raise DeviceError(f"{self.name}: cannot send {req.command.name}: {err}") from err

    def _recv(self, timeout_s: float) -> bytes | None:
        self.sock.settimeout(max(timeout_s, 1e-4))
        try:
            return bytes(self.sock.recv(65535))
        except (TimeoutError, BlockingIOError):
            return None
        except OSError as err:  # ICMP port unreachable on a connected socket, ...
            raise DeviceError(f"{self.name}: {err}") from err

    def _drain(self) -> None:
        while self._recv(1e-4) is not None:
            pass

    # -- commands ----------------------------------------------------------------------------------
    def bias(self) -> None:
        """Set the software bias: zero the readings at the current load."""
        self._require_open()
        self._send(p.RdtRequest(p.RdtCommand.SET_BIAS))

    def start_streaming(self, sample_count: int = 0, *, buffered: bool = False) -> None:
        """Start records (``sample_count`` of them, 0: until :meth:`stop_streaming`)."""
        self._require_open()
        cmd = p.RdtCommand.START_BUFFERED if buffered else p.RdtCommand.START_REALTIME
        self._next_seq = None
        self.lost = 0
        self._send(p.RdtRequest(cmd, sample_count))

    def stop_streaming(self) -> None:
        self._send(p.RdtRequest(p.RdtCommand.STOP))

    def read_records(self, timeout_s: float | None = None) -> list[p.RdtRecord]:
        """The records of the next datagram (empty when none came in time); sequence jumps are
        counted in :attr:`lost`."""
        data = self._recv(self.timeout_s if timeout_s is None else timeout_s)
        if data is None:
            return []
        recs = p.RdtRecord.decode_all(data)
        for r in recs:
            if self._next_seq is not None and r.rdt_sequence != self._next_seq:
                missed = (r.rdt_sequence - self._next_seq) & 0xFFFFFFFF
                self.lost += missed
                log.warning(
                    "%s: rdt_sequence jumped from %d to %d: %d record(s) lost",
                    self.name,
                    self._next_seq - 1,
                    r.rdt_sequence,
                    missed,
                )
            self._next_seq = (r.rdt_sequence + 1) & 0xFFFFFFFF
        return recs

    def read_once(self, timeout_s: float | None = None) -> p.RdtRecord:
        """One record: START with sample_count 1, its answer.

        Raises
        ------
        DeviceTimeoutError
            No record in time (names the port and the fix).
        """

        def attempt(deadline: Deadline) -> p.RdtRecord:
            self._drain()
            self.start_streaming(1)
            while True:
                recs = self.read_records(deadline.left())
                if recs:
                    return recs[-1]
                if deadline.passed:
                    raise DeviceTimeoutError(
                        f"{self.name} sent no RDT record within {deadline.timeout_s:g} s; check "
                        f"its IP address, that RDT is enabled, and UDP port {p.RDT_PORT}"
                    )

        return self._exchange("RDT read", attempt, timeout_s=timeout_s, idempotent=True)

    def loads(self, record: p.RdtRecord) -> np.ndarray:
        """A record's loads: N (Fx Fy Fz) and N·m (Tx Ty Tz)."""
        assert self.calibration_matrix is not None
        return self.calibration_matrix @ np.asarray(record.counts, dtype=float)

    def identify(self) -> LoadCellIdentity:
        rec = self.read_once()
        return LoadCellIdentity(
            n_gauges=6,
            firmware=f"Net F/T RDT, status {rec.status:#010x}",
            serial_number=self.serial_number,
        )

    # -- the LoadCell protocol: no acquisition on the DAQ's clock ----------------------------------
    def set_rate(self, rate_hz: int) -> float:
        raise SetupError(_NOT_ON_DAQ_CLOCK.format(name=self.name))

    def start(self, *, external_clock: bool = True) -> None:
        raise SetupError(_NOT_ON_DAQ_CLOCK.format(name=self.name))

    def stop(self) -> int:
        self.stop_streaming()
        return 0

    def read_until(self, end_sample: int, timeout_s: float | None = None) -> LoadCellBlock:
        raise SetupError(_NOT_ON_DAQ_CLOCK.format(name=self.name))

    def verify_count(self, daq_samples_clocked: int) -> LoadCellEvent | None:
        return None

    def _close_transport(self) -> None:
        """The socket belongs to whoever opened it (the backend closes it)."""
