"""ATI Net F/T Raw Data Transfer over UDP (port 49152, big endian): the request and record
bytes, the driver on a loopback socket to the simulator (one record, bias, a stream with a lost
datagram, buffered records), and the refusal to acquire on the DAQ's clock."""

from __future__ import annotations

import socket

import numpy as np
import pytest
from numpy.typing import NDArray

from dimacq.drivers.netft import protocol as p
from dimacq.drivers.netft.udp_driver import NetFtUdp
from dimacq.errors import DeviceTimeoutError, ProtocolError, SetupError
from dimacq.simulators.netft.udp_sensor import NetFtUdpSim

CAL = p.CalibrationInfo(2, 3, 1_000_000, 1_000_000)


class Bridges:
    sample_rate_hz = 2048.0
    channel_names = tuple(f"LC1 g{k + 1:02d}" for k in range(12))
    channel_units = ("mV/V",) * 12

    def __init__(self, g: NDArray[np.float64]) -> None:
        self.g = g

    def read(self, channels: NDArray[np.intp], start: int, n: int) -> NDArray[np.float64]:
        return np.repeat(self.g[channels][:, None], n, axis=1)


def test_request_and_record_bytes() -> None:
    assert p.RDT_PORT == 49152
    assert p.RdtRequest(p.RdtCommand.START_REALTIME, 0).encode() == bytes.fromhex(
        "1234000200000000"
    )
    assert p.RdtRequest(p.RdtCommand.STOP).encode() == bytes.fromhex("1234000000000000")
    assert p.RdtRequest(p.RdtCommand.SET_BIAS).encode() == bytes.fromhex("1234004200000000")
    assert p.RdtRequest(p.RdtCommand.START_BUFFERED, 10).encode() == bytes.fromhex(
        "123400030000000a"
    )
    raw = bytes.fromhex("000000010000002a0000000000000064ffffff9c000f42400000000100000002fffffffd")
    (rec,) = p.RdtRecord.decode_all(raw)
    assert rec == p.RdtRecord(1, 42, 0, (100, -100, 1000000, 1, 2, -3))
    assert rec.encode() == raw
    with pytest.raises(ProtocolError, match="whole number of 36-byte records"):
        p.RdtRecord.decode_all(raw[:-1])
    with pytest.raises(ProtocolError, match="header 0x4321"):
        p.RdtRequest.decode(bytes.fromhex("4321000200000000"))


def _driver(sim: NetFtUdpSim) -> tuple[NetFtUdp, socket.socket]:
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.connect(sim.address)
    return NetFtUdp(sock, calibration=CAL, timeout_s=2.0), sock


def test_driver_on_the_loopback_simulator() -> None:
    rng = np.random.default_rng(2)
    C = rng.normal(size=(6, 12)) * 100.0
    src = Bridges(rng.normal(size=12) * 0.1)
    with NetFtUdpSim(src, range(12), C, CAL, rdt_rate_hz=2000.0, drop=[5]) as sim:
        drv, sock = _driver(sim)
        try:
            rec = drv.read_once()
            np.testing.assert_allclose(drv.loads(rec), C @ src.g, atol=1e-6)
            assert drv.identify().n_gauges == 6
            drv.bias()
            assert drv.read_once().counts == (0,) * 6
            drv.start_streaming(8)
            got: list[p.RdtRecord] = []
            while len(got) < 7:
                recs = drv.read_records(1.0)
                assert recs, "stream stopped early"
                got += recs
            assert [r.rdt_sequence for r in got] == [1, 2, 3, 4, 6, 7, 8]
            assert drv.lost == 1
            drv.start_streaming(20, buffered=True)
            recs = drv.read_records(1.0)
            assert len(recs) == 10 and recs[0].rdt_sequence == 1
            drv.stop_streaming()
            with pytest.raises(SetupError, match="cannot be aligned to the accelerometers'"):
                drv.start(external_clock=True)
        finally:
            sock.close()


def test_a_silent_address_times_out_naming_the_port() -> None:
    quiet = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    quiet.bind(("127.0.0.1", 0))
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.connect(quiet.getsockname())
    try:
        drv = NetFtUdp(sock, calibration=CAL, timeout_s=0.2)
        with pytest.raises(DeviceTimeoutError, match="UDP port 49152"):
            drv.read_once()
    finally:
        sock.close()
        quiet.close()


def test_calibration_read_from_the_device_over_tcp() -> None:
    from dimacq.drivers.netft.tcp_calibration import read_calibration_info

    cal = p.CalibrationInfo(1, 1, 2000, 3000, (1, 2, 3, 4, 5, 6))  # lbf, lbf-in
    src = Bridges(np.zeros(12))
    with NetFtUdpSim(src, range(12), np.zeros((6, 12)), cal) as sim:
        with socket.create_connection(sim.tcp_address, timeout=2.0) as tcp:
            got = read_calibration_info(tcp)
    assert got == cal
    assert cal.encode()[:4] == bytes.fromhex("12340101")  # header 0x1234, units, big endian
