"""Reference exchanges of every message the CAN load cells' drivers use, written out byte by
byte from the vendor's code or the standard, each checked against the driver's codec **and**
against the twin (raw bytes on the wire, not through the codec).

Sources:

- Net F/T RDT (UDP 49152): ATI's Java demo library, ``com.atiia.automation.sensors.
  NetFTSensor`` (Sam Skuce, ATI Industrial Automation; as vendored in aoklyunin/KawasakiFX,
  ``src/com/atiia/automation/sensors/NetFTSensor.java``): ``getDatagramPacketFromNetFTRDTCommand``
  (8 bytes: header 0x1234, command, count, each big endian), ``startHighSpeedDataCollection``
  (command 2), ``tare`` (0x0042, count 1), ``stopDataCollection`` (0, 0),
  ``getNetFTRDTPacketFromDatagramPacket`` (36 bytes: nine big-endian 32-bit fields RDT
  sequence, F/T sequence, status, Fx, Fy, Fz, Tx, Ty, Tz).
- Net F/T configuration page: ATI's ``NetFTSampleGUI.readConfigurationInfo`` (same demo):
  ``netftapi2.xml?index=0`` → ``setcfgsel``, then ``cfgcpf``, ``cfgcpt``, ``scfgfu``,
  ``scfgtu``, ``comrdtrate``.
- Net F/T Read Calibration Info (TCP 49151) and the CAN frames: the Net F/T Installation and
  Operation Manual (ATI 9620-05-Net FT) sections 11 and 15 as transcribed in
  :mod:`dimacq.drivers.netft.protocol`; the manual itself was not in the reference corpus this
  test was written from, so these stay marked unverified there (base address, latch code,
  long-answer order).
- CiA 404 over CANopen: CiA 301 SDO expedited transfer (command byte 0x2B = download 2 bytes,
  0x23 = 4 bytes, 0x40 upload request, 0x43 upload answer of 4 bytes, 0x60 download confirmed),
  NMT (0x000, [command, node]), SYNC (0x080, no data), PDO mapping entry ``index << 16 |
  sub << 8 | bits``; CiA 404 object indices 0x6130, 0x6131, 0x6114.
"""

from __future__ import annotations

import http.client
import itertools
import os
import socket
import struct
import time
from pathlib import Path
from typing import Any

import can
import numpy as np

from dimacq.drivers.cia404 import protocol as cp
from dimacq.drivers.netft import protocol as p
from dimacq.drivers.netft.config_page import parse_config_page
from dimacq.simulators.cia404.node import Cia404NodeSim
from dimacq.simulators.netft.can_sensor import NetFtCanSim
from dimacq.simulators.netft.ethernet import NetFtEthernetSim
from dimacq.simulators.netft.udp_sensor import NetFtUdpSim

EDS = Path(__file__).resolve().parents[2] / "config" / "canopen" / "cia404-generic.eds"
_n = itertools.count()

# -- Net F/T RDT (NetFTSensor.java) ------------------------------------------------------------
RDT_START_10 = bytes.fromhex("123400020000000a")  # startHighSpeedDataCollection(10)
RDT_TARE = bytes.fromhex("1234004200000001")  # tare()
RDT_STOP = bytes.fromhex("1234000000000000")  # stopDataCollection()
# one record: rdt seq 1, ft seq 7000, status 0, Fx..Tz = 1, -2, 3, -4, 5, -6 (big endian)
RDT_RECORD = bytes.fromhex(
    "0000000100001b580000000000000001fffffffe00000003fffffffc00000005fffffffa"
)

# -- Net F/T Read Calibration Info (manual §11, as transcribed) ---------------------------------
READCALINFO = bytes([1]) + bytes(19)
# header 0x1234, N (2), N-m (3), 1 000 000 counts per N and per N-m, six scale factors 1
CALINFO = bytes.fromhex("12340203000f4240000f4240") + bytes.fromhex("0001") * 6

# -- Net F/T CAN (manual §15, as transcribed) ---------------------------------------------------
REQUEST_LONG, BIAS = b"\x01", b"\x04"


class Constant:
    sample_rate_hz = 1000.0
    channel_names = tuple(f"g{c}" for c in range(12))
    channel_units = ("mV/V",) * 12

    def __init__(self, g: Any) -> None:
        self.g = np.asarray(g, float)

    def read(self, channels: Any, start: int, n: int) -> Any:
        return np.repeat(self.g[np.asarray(channels)][:, None], n, axis=1)

    def excite(self, input_index: int, at_sample: int) -> None:
        pass


def test_rdt_request_and_record_codec() -> None:
    assert p.RdtRequest(p.RdtCommand.START_REALTIME, 10).encode() == RDT_START_10
    assert p.RdtRequest(p.RdtCommand.SET_BIAS, 1).encode() == RDT_TARE
    assert p.RdtRequest(p.RdtCommand.STOP, 0).encode() == RDT_STOP
    assert p.RDT_PORT == 49152 and p.RdtRecord.SIZE == len(RDT_RECORD) == 36
    (r,) = p.RdtRecord.decode_all(RDT_RECORD)
    assert (r.rdt_sequence, r.ft_sequence, r.status) == (1, 7000, 0)
    assert r.counts == (1, -2, 3, -4, 5, -6)
    b = p.decode_rdt(RDT_RECORD)
    assert b.counts.tolist() == [[1, -2, 3, -4, 5, -6]] and int(b.ft_sequence[0]) == 7000


def test_rdt_twin_answers_the_vendors_request_bytes() -> None:
    """The twin streams 36-byte big-endian records to ATI's own start bytes, sequence from 1,
    and stops on ATI's stop bytes."""
    cal = p.CalibrationInfo(2, 3, 1_000_000, 1_000_000)
    C = np.zeros((6, 12))
    C[0, 0] = 1.0  # Fx = bridge 0
    with NetFtUdpSim(Constant([2.5] + [0.0] * 11), range(12), C, cal, per_datagram=1) as sim:
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            s.settimeout(2.0)
            s.connect(sim.address)
            s.send(RDT_START_10)
            got = [s.recv(65535) for _ in range(10)]
            s.send(RDT_STOP)
    assert all(len(d) == 36 for d in got)
    seq = [int.from_bytes(d[0:4], "big") for d in got]
    fx = [int.from_bytes(d[12:16], "big", signed=True) for d in got]
    assert seq == list(range(1, 11)) and set(fx) == {2_500_000}


def test_read_calibration_info_codec_and_twins() -> None:
    assert p.CalibrationInfo.command() == READCALINFO and len(CALINFO) == p.CalibrationInfo.SIZE
    cal = p.CalibrationInfo.decode(CALINFO)
    assert (cal.force_unit, cal.torque_unit, cal.counts_per_force, cal.counts_per_torque) == (
        2,
        3,
        1_000_000,
        1_000_000,
    )
    assert cal.encode() == CALINFO
    with NetFtEthernetSim(cal) as eth:
        with socket.create_connection(eth.tcp_address, timeout=2.0) as s:
            s.sendall(READCALINFO)
            assert s.recv(64) == CALINFO
        with socket.create_connection(eth.tcp_address, timeout=2.0) as s:
            s.sendall(bytes([2]) + bytes(19))  # not READCALINFO: no answer, closed
            assert s.recv(64) == b""


def test_config_page_as_atis_demo_reads_it() -> None:
    """``?index=0`` names the active configuration; its page holds the calibration."""
    cal = p.CalibrationInfo(2, 3, 1_000_000, 500_000)
    with NetFtEthernetSim(cal, rdt_rate_hz=7000, active=3) as eth:
        conn = http.client.HTTPConnection(*eth.http_address, timeout=2.0)
        conn.request("GET", "/netftapi2.xml?index=0")
        first = conn.getresponse().read().decode()
        conn.request("GET", "/netftapi2.xml?index=3")
        page = conn.getresponse().read()
        conn.close()
    assert "<setcfgsel>3</setcfgsel>" in first
    text = page.decode()
    for tag, v in (
        ("cfgcpf", "1000000"),
        ("cfgcpt", "500000"),
        ("scfgfu", "N"),
        ("scfgtu", "N-m"),
        ("comrdtrate", "7000"),
    ):
        assert f"<{tag}>{v}</{tag}>" in text, tag
    got = parse_config_page(page)
    assert got.index == 3 and got.calibration() == cal and got.rdt_rate_hz == 7000


def _frames(
    bus: Any, want: int, timeout_s: float = 2.0, cob: int | None = None
) -> list[can.Message]:
    """Up to ``want`` frames (of identifier ``cob`` when given) within ``timeout_s``."""
    out: list[can.Message] = []
    end = time.monotonic() + timeout_s
    while len(out) < want and time.monotonic() < end:
        m = bus.recv(0.05)
        if m is not None and (cob is None or m.arbitration_id == cob):
            out.append(m)
    return out


def test_netft_can_request_long_and_its_four_answers_on_the_twin() -> None:
    """REQUEST LONG (one byte 0x01 to the base) answered by base+1..+4: Fx Tx, Fy Ty, Fz Tz,
    status and sample number, 32-bit little endian; BIAS (0x04) zeros them."""
    base = 0x140
    C = np.zeros((6, 12))
    C[0, 0], C[3, 1], C[2, 2] = 1.0, 1.0, 1.0  # Fx, Tx, Fz from bridges 0, 1, 2
    g = [-35.991793, 0.000598, 1.0] + [0.0] * 9  # Fx -35 991 793 counts, Tx 598, Fz 10^6
    cal = p.CalibrationInfo(2, 3, 1_000_000, 1_000_000)
    assert p.Request(p.Command.REQUEST_LONG).encode() == REQUEST_LONG
    assert p.Request(p.Command.BIAS).encode() == BIAS
    name = f"ref-netft-{os.getpid()}-{next(_n)}"
    with NetFtCanSim(name, Constant(g), range(12), C, cal, base=base):
        bus = can.Bus(interface="virtual", channel=name)
        try:
            bus.send(can.Message(arbitration_id=base, data=REQUEST_LONG, is_extended_id=False))
            ans = {m.arbitration_id - base: bytes(m.data) for m in _frames(bus, 4)}
            bus.send(can.Message(arbitration_id=base, data=BIAS, is_extended_id=False))
            time.sleep(0.1)
            bus.send(can.Message(arbitration_id=base, data=REQUEST_LONG, is_extended_id=False))
            zero = {m.arbitration_id - base: bytes(m.data) for m in _frames(bus, 4)}
        finally:
            bus.shutdown()
    assert sorted(ans) == [1, 2, 3, 4]
    assert ans[1] == bytes.fromhex("0fcfdafd56020000")  # the manual's example bytes
    assert ans[2] == bytes(8)
    assert ans[3] == bytes.fromhex("40420f0000000000")
    assert ans[4][:4] == bytes(4)  # status 0; then its own sample number
    assert [zero[k] for k in (1, 2, 3)] == [bytes(8)] * 3
    # the driver's codec reads the same bytes
    assert p.decode_long(1, ans[1]) == (-35991793, 0x0256)


def test_cia404_sdo_nmt_sync_and_pdo_bytes_on_the_twin() -> None:
    """CiA 301 bytes against the codec and the node: an expedited download of the heartbeat
    time (0x1017, U16 200 ms) confirmed, an upload of 0x6131:1 (the unit), NMT start, SYNC, a
    synchronous TPDO of 0x6130:1 mapped as 0x61300120."""
    node_id = 5
    heartbeat = bytes.fromhex("2b171000c8000000")
    assert cp.sdo_expedited_download(node_id, 0x1017, 0, b"\xc8\x00") == (0x605, heartbeat)
    assert cp.sdo_download_answer(node_id, 0x1017, 0) == (0x585, bytes.fromhex("6017100000000000"))
    assert cp.nmt_frame(cp.NmtCommand.START, node_id) == (0x000, b"\x01\x05")
    assert cp.sync_frame() == (0x080, b"")
    assert struct.pack("<I", cp.mapping_entry(0x6130, 1, 32)) == bytes.fromhex("20013061")
    assert cp.AI_PHYSICAL_UNIT == 0x6131 and cp.AI_ADC_SAMPLE_RATE == 0x6114
    name = f"ref-cia404-{os.getpid()}-{next(_n)}"
    node = Cia404NodeSim(
        name, EDS, Constant([0.5] * 12), range(12), node_id=node_id, hear_sync=True
    )
    bus = can.Bus(interface="virtual", channel=name)
    try:
        _frames(bus, 1, 0.3)  # its boot-up

        def exchange(cob: int, data: bytes) -> bytes:
            bus.send(can.Message(arbitration_id=cob, data=data, is_extended_id=False))
            (got,) = _frames(bus, 1, 2.0, cob=0x580 + node_id)
            return bytes(got.data)

        assert exchange(0x605, heartbeat) == bytes.fromhex("6017100000000000")
        assert exchange(0x605, bytes.fromhex("4031610100000000")) == bytes.fromhex(
            "43316101000000fd"  # 0xFD000000: mV/V
        )
        # map TPDO1: 0x6130:1 as REAL32, synchronous (CiA 301 order)
        writes = [
            (0x1800, 1, struct.pack("<I", 0x80000185)),
            (0x1A00, 0, b"\x00"),
            (0x1A00, 1, bytes.fromhex("20013061")),
            (0x1A00, 0, b"\x01"),
            (0x1800, 2, b"\x01"),
            (0x1800, 1, struct.pack("<I", 0x185)),
        ]
        for index, sub, data in writes:
            cob, frame = cp.sdo_expedited_download(node_id, index, sub, data)
            assert exchange(cob, frame)[0] == 0x60
        bus.send(can.Message(arbitration_id=0x000, data=b"\x01\x05", is_extended_id=False))
        time.sleep(0.2)
        bus.send(can.Message(arbitration_id=0x080, data=b"", is_extended_id=False))
        tpdo = _frames(bus, 1, 2.0, cob=0x185)
    finally:
        bus.shutdown()
        node.close()
    assert tpdo and len(tpdo[0].data) == 4
    assert struct.unpack("<f", bytes(tpdo[0].data))[0] == np.float32(0.5)
