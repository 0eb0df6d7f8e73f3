"""The Net F/T's CAN frames against sources we did not write, each exchange checked against the
driver's codec (``dimacq.drivers.netft.protocol``) and against the twin's raw bytes on the wire.

Sources:

- **ATI's manual**, *Net F/T Installation and Operation Manual*, document 9620-05-Net FT-11,
  section 15 "CAN Bus Operation" (public copy: yumpu.com document 54843814, pages 89 and 90):
  §15.1 base address and bit rate set with the DIP switches (§3.10); §15.2 REQUEST LONG sends
  32-bit values in four messages, REQUEST SHORT 16-bit values in two, little endian, two's
  complement (``56 02`` = 0x0256; the 32-bit example 0xFDDACF0F = −35 991 793, printed there
  with a doubled byte, "0x0F 0xCF 0xDA 0xDA 0xFD"); Table 15.2 REQUEST SHORT = ``0x02`` (DLC 1)
  to the base, base + 5: Fx, Tx, Fy, Ty (INT), base + 6: Fz, Tz, system status, sample number
  (INT); Table 15.3 BIAS = ``0x04`` (DLC 1). Table 15.1 (REQUEST LONG) and the body of
  Table 15.4 (clear threshold latch) were not in the copy.
- **A Net F/T CAN client for an Arduino CAN shield** (S. Uchino, ``@version 2019-11-20``; the
  code index holds two revisions, ids 2470546150 and 2832105151, without their repository):
  base 0x1B0 at 500 kbit/s; ``sendMsgBuf(0x1B0, 0, 1, {0x01})`` (REQUEST LONG, DLC 1) and
  ``{0x04}`` (bias); base + 1, + 2, + 3 the x, y, z axis, "First 4bytes contain force data,
  the other 4bytes contain torque data", little endian (``convertToForce`` reads bytes 3..0,
  ``convertToTorque`` bytes 7..4); the fourth answer "StatusMessage"; its own test:
  ``0f cf da fd 00 00 00 00`` is force −35 991 793. (The other revision reads the two halves
  the other way round; the one cited here is the one with the calibration factors applied.)
- **A Net F/T CAN client for a TI Tiva** (N. Tremaroli, ``FTSensor.c``, code index id
  34713608797; Chi, ``myCAN.c`` 2021-05-11, id 34602898553): request ``0x02`` to 0x1B0
  ("a frame for asking force data"), answers filtered at 0x1B5 and 0x1B6 at 500 kbit/s ("same as
  ATI CAN rate"); 0x1B5 bytes 0-1 Fx, 2-3 Tx, 4-5 Fy, 6-7 Ty; 0x1B6 bytes 0-1 Fz, 2-3 Tz; each
  value ``binTwoCToDec(lo, hi)`` = the sign-extended ``hi << 8 | lo``.

Not in any of them: the layout of the fourth long answer (base + 4, read here as status word and
sample number, as the short answers carry them) and the clear-threshold-latch byte.
"""

from __future__ import annotations

import itertools
import os
import time
from typing import Any

import can
import numpy as np

from dimacq.drivers.netft import protocol as p
from dimacq.simulators.netft.can_sensor import NetFtCanSim

_n = itertools.count()

#: the clients' base address (their DIP switches)
BASE = 0x1B0


def tiva_int16(lo: int, hi: int) -> int:
    """``binTwoCToDec`` of ``myCAN.c``: ``hi << 8 | lo``, bit 15 extended."""
    v = hi << 8 | lo
    return v | ~((1 << 15) - 1) if v & (1 << 15) else v


def arduino_int32(buf: bytes, first: int) -> int:
    """``convertToForce`` / ``convertToTorque`` of the Arduino client: bytes ``first + 3`` down
    to ``first`` as one hexadecimal number, read as a two's-complement ``long``."""
    v = int("".join(f"{buf[i]:02x}" for i in range(first + 3, first - 1, -1)), 16)
    return v - (1 << 32) if v & (1 << 31) else v


class Constant:
    """Bridge outputs that do not change (mV/V)."""

    sample_rate_hz = 1000.0
    channel_names = tuple(f"g{c}" for c in range(12))
    channel_units = ("mV/V",) * 12

    def __init__(self, g: Any) -> None:
        self.g = np.asarray(g, float)

    def read(self, channels: Any, start: int, n: int) -> Any:
        return np.repeat(self.g[np.asarray(channels)][:, None], n, axis=1)

    def excite(self, input_index: int, at_sample: int) -> None:
        pass


def _frames(bus: can.BusABC, want: int, timeout_s: float = 3.0) -> list[can.Message]:
    out: list[can.Message] = []
    end = time.monotonic() + timeout_s
    while len(out) < want and time.monotonic() < end:
        m = bus.recv(0.05)
        if m is not None:
            out.append(m)
    return out


def _exchange(g: list[float], requests: list[tuple[bytes, int]]) -> list[dict[int, bytes]]:
    """The twin at base 0x1B0 (10^6 counts per N and per N·m, one bridge per axis) sent each
    request ``(data, answers)`` in turn on its own virtual channel: the answers to each, by
    identifier."""
    C = np.eye(6, 12)
    cal = p.CalibrationInfo(2, 3, 1_000_000, 1_000_000)
    name = f"netft-ref-{os.getpid()}-{next(_n)}"
    seen: list[dict[int, bytes]] = []
    with NetFtCanSim(name, Constant(g + [0.0] * 6), range(12), C, cal, base=BASE):
        bus = can.Bus(interface="virtual", channel=name)
        try:
            for req, answers in requests:
                bus.send(can.Message(arbitration_id=BASE, data=req, is_extended_id=False))
                if not answers:
                    time.sleep(0.1)
                frames = _frames(bus, answers) if answers else []
                seen.append({m.arbitration_id: bytes(m.data) for m in frames})
        finally:
            bus.shutdown()
    return seen


def test_the_arduino_clients_long_exchange() -> None:
    """REQUEST LONG ``01`` (DLC 1) to 0x1B0; 0x1B1..0x1B3 force in bytes 0-3, torque in 4-7,
    little endian; the fourth answer at 0x1B4: the clients' bytes through the codec, then the
    twin's answer through the clients' own decoder."""
    assert p.Request(p.Command.REQUEST_LONG).encode() == b"\x01"
    assert p.Request(p.Command.BIAS).encode() == b"\x04"
    # the client's own test vectors
    force_first = bytes.fromhex("0fcfdafd00000000")
    torque_second = bytes.fromhex("000000000fcfdafd")
    assert arduino_int32(force_first, 0) == -35991793 == arduino_int32(torque_second, 4)
    assert p.decode_long(1, force_first) == (-35991793, 0)
    assert p.decode_long(1, torque_second) == (0, -35991793)
    assert p.decode(BASE, 0x1B1, force_first) == p.LongPair(0, -35991793, 0)
    assert p.decode(BASE, 0x1B2, torque_second) == p.LongPair(1, 0, -35991793)
    assert p.decode(BASE, 0x1B3, force_first) == p.LongPair(2, -35991793, 0)
    assert isinstance(p.decode(BASE, 0x1B4, bytes(8)), p.LongStatus)
    # the twin: Fx 1, Fy -2, Fz 3 N; Tx -4, Ty 5, Tz -6 N·m (x 10^6 counts)
    g = [1.0, -2.0, 3.0, -4.0, 5.0, -6.0]
    (got,) = _exchange(g, [(b"\x01", 4)])
    assert sorted(got) == [0x1B1, 0x1B2, 0x1B3, 0x1B4]
    assert all(len(d) == 8 for d in got.values())
    by_axis = {
        k: (arduino_int32(got[k], 0), arduino_int32(got[k], 4)) for k in (0x1B1, 0x1B2, 0x1B3)
    }
    assert by_axis == {
        0x1B1: (1_000_000, -4_000_000),
        0x1B2: (-2_000_000, 5_000_000),
        0x1B3: (3_000_000, -6_000_000),
    }
    assert got[0x1B1] == bytes.fromhex("40420f0000f7c2ff")  # 1 000 000, -4 000 000


def test_the_tiva_clients_short_exchange() -> None:
    """REQUEST SHORT ``02`` to 0x1B0; 0x1B5 Fx Tx Fy Ty, 0x1B6 Fz Tz (then status, sample),
    each ``hi << 8 | lo`` sign-extended: the twin's bytes through the client's decoder and
    the codec."""
    assert p.Request(p.Command.REQUEST_SHORT).encode() == b"\x02"
    g = [-0.000002, -0.000003, -0.000004, -0.000005, -0.000006, -0.000007]  # counts -2 .. -7
    (got,) = _exchange(g, [(b"\x02", 2)])
    assert sorted(got) == [0x1B5, 0x1B6]
    xy, z = got[0x1B5], got[0x1B6]
    fx, tx, fy, ty = (tiva_int16(xy[i], xy[i + 1]) for i in (0, 2, 4, 6))
    fz, tz = (tiva_int16(z[i], z[i + 1]) for i in (0, 2))
    assert (fx, fy, fz, tx, ty, tz) == (-2, -3, -4, -5, -6, -7)
    assert xy == bytes.fromhex("fefffbfffdfffaff")
    assert p.decode(BASE, 0x1B5, xy) == p.ShortXY(-2, -5, -3, -6)
    short_z = p.decode(BASE, 0x1B6, z)
    assert isinstance(short_z, p.ShortZ)
    assert (short_z.fz, short_z.tz, short_z.status) == (-4, -7, 0)
    # the client's decoder and the codec agree on every 16-bit pattern's sign
    for lo, hi in ((0xFF, 0x7F), (0x00, 0x80), (0xFE, 0xFF), (0x56, 0x02)):
        assert tiva_int16(lo, hi) == p.decode_i16(bytes([lo, hi]))


def test_the_manuals_bias_zeros_the_answers() -> None:
    """Table 15.3 (and the Arduino client's ``setup``): BIAS ``04`` (DLC 1) to the base zeros the
    readings at the current load; the next REQUEST LONG answers zeros."""
    g = [1.0, -2.0, 3.0, -4.0, 5.0, -6.0]
    first, none, zeroed = _exchange(g, [(b"\x01", 4), (b"\x04", 0), (b"\x01", 4)])
    assert none == {}  # BIAS is not answered
    assert [first[k] != bytes(8) for k in (0x1B1, 0x1B2, 0x1B3)] == [True] * 3
    assert [zeroed[k] for k in (0x1B1, 0x1B2, 0x1B3)] == [bytes(8)] * 3


def test_read_calibration_info_as_atis_manuals_give_it() -> None:
    """Net F/T manual §11.1-11.2: TCP port 49151, commands of 20 bytes, every response begins
    with the bytes ``12 34``, READCALINFO = 1. ATI's Ethernet Axia manual (9610-05-Ethernet
    Axia-09) §10.4-10.5, the same interface: ``uint8 command; uint8 reserved[19]`` and ``uint16
    header; uint8 forceUnits; uint8 torqueUnits; uint32 countsPerForce; uint32 countsPerTorque;
    uint16 scaleFactors[6]``; force units 1 pound, 2 newton, 3 kilopound, 4 kilonewton,
    5 kilogram, 6 gram; torque units 1 pound-inch, 2 pound-foot, 3 newton-meter, 4
    newton-millimeter, 5 kilogram-centimeter, 6 kilonewton-meter."""
    assert p.TCP_PORT == 49151
    cmd = p.CalibrationInfo.command()
    assert len(cmd) == 20 and cmd == b"\x01" + bytes(19)
    # a response: N, N-m, 1 000 000 counts per N, 1 000 counts per N-m, scale factors 1..6
    answer = (
        bytes([0x12, 0x34, 2, 3])
        + (1_000_000).to_bytes(4, "big")
        + (1_000).to_bytes(4, "big")
        + b"".join(k.to_bytes(2, "big") for k in range(1, 7))
    )
    assert len(answer) == p.CalibrationInfo.SIZE == 24
    info = p.CalibrationInfo.decode(answer)
    assert (info.force_unit, info.torque_unit) == (2, 3)
    assert (info.counts_per_force, info.counts_per_torque) == (1_000_000, 1_000)
    assert info.scale_factors == (1, 2, 3, 4, 5, 6)
    assert info.encode() == answer
    assert {k: v[0] for k, v in p.FORCE_UNITS.items()} == {
        1: "lbf",
        2: "N",
        3: "klbf",
        4: "kN",
        5: "kgf",
        6: "gf",
    }
    assert {k: v[0] for k, v in p.TORQUE_UNITS.items()} == {
        1: "lbf-in",
        2: "lbf-ft",
        3: "N-m",
        4: "N-mm",
        5: "kgf-cm",
        6: "kN-m",
    }
