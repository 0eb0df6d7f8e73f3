"""ATI Net F/T over CAN: the manual's byte order examples, and the driver's exchanges scripted
byte for byte (base address 0x020 as DIP switches could set it)."""

from __future__ import annotations

import numpy as np
import pytest
from _exchange import Can, expected_exchange

from dimacq.drivers.netft import protocol as p
from dimacq.drivers.netft.can_driver import NetFtCan
from dimacq.errors import DeviceTimeoutError, ProtocolError, SetupError

BASE = 0x020
CAL = p.CalibrationInfo(2, 3, 1_000_000, 1_000_000)  # N, N-m, 10^6 counts per unit
REQUEST_LONG = Can(BASE, b"\x01")
BIAS = Can(BASE, b"\x04")

# one long answer: Fx = 0xFDDACF0F (the manual's example bytes 0F CF DA FD = -35 991 793),
# Tx = 0x0256 (its 16-bit example 56 02, here in a DINT), Fy = 1, Ty = -1, Fz = 1000000,
# Tz = 0, status 0, sample number 7
ANSWER = [
    Can(BASE + 1, bytes.fromhex("0fcfdafd") + bytes.fromhex("56020000")),
    Can(BASE + 2, bytes.fromhex("01000000") + bytes.fromhex("ffffffff")),
    Can(BASE + 3, bytes.fromhex("40420f00") + bytes.fromhex("00000000")),
    Can(BASE + 4, bytes.fromhex("00000000") + bytes.fromhex("07000000")),
]
COUNTS = [-35991793, 1, 1000000, 0x0256, -1, 0]  # AXES order: Fx Fy Fz Tx Ty Tz


def _driver(bus: object) -> NetFtCan:
    return NetFtCan(bus, base=BASE, calibration=CAL, serial_number=501, timeout_s=0.5)


def test_the_codecs_numbers_as_transcribed() -> None:
    """Offsets from the base address, the RDT and TCP ports, the calibration header and sizes
    (manual §11/§15 as transcribed; ATI's demo code for the RDT port and record size)."""
    assert (p.Request.OFFSET, p.LongStatus.OFFSET, p.ShortXY.OFFSET, p.ShortZ.OFFSET) == (
        0,
        4,
        5,
        6,
    )
    assert (p.RDT_PORT, p.TCP_PORT, p.RdtRecord.SIZE, p.RdtRequest.HEADER) == (
        49152,
        49151,
        36,
        0x1234,
    )
    assert (p.CalibrationInfo.HEADER, p.CalibrationInfo.READCALINFO, p.CalibrationInfo.SIZE) == (
        0x1234,
        1,
        24,
    )
    assert [int(c) for c in p.Command] == [0x01, 0x02, 0x04, 0x08]
    assert [int(c) for c in p.RdtCommand] == [0x0000, 0x0002, 0x0003, 0x0042]


def test_the_manuals_byte_order_examples() -> None:
    (b16, v16), (b32, v32) = p.MANUAL_EXAMPLES
    assert p.decode_i16(b16) == v16 == 0x0256
    assert p.decode_i32(b32) == v32 == -35991793
    assert v32 & 0xFFFFFFFF == 0xFDDACF0F


def test_message_table_round_trips_and_refuses() -> None:
    assert p.Request(p.Command.REQUEST_LONG).encode() == b"\x01"
    assert p.Request(p.Command.REQUEST_SHORT).encode() == b"\x02"
    assert p.Request(p.Command.BIAS).encode() == b"\x04"
    frames = p.long_frames(COUNTS, 0, 7)
    assert [(BASE + o, d) for o, d in frames] == [(c.id, c.data) for c in ANSWER]
    assert p.decode(BASE, BASE + 1, ANSWER[0].data) == p.LongPair(0, -35991793, 0x0256)
    assert p.decode(BASE, BASE + 4, ANSWER[3].data) == p.LongStatus(0, 7)
    short = p.ShortZ(-2, 3, 0, 9)
    assert short.encode() == bytes.fromhex("feff030000000900")
    assert p.decode(BASE, BASE + 6, short.encode()) == short
    with pytest.raises(ProtocolError, match="not a Net F/T message"):
        p.decode(BASE, BASE + 7, b"")
    with pytest.raises(ProtocolError, match="3 bytes, expected 8"):
        p.decode(BASE, BASE + 2, b"abc")
    with pytest.raises(ProtocolError, match="0x03 is not a known command"):
        p.decode(BASE, BASE, b"\x03")
    with pytest.raises(SetupError, match="base address 0x7fa"):
        p.check_base(0x7FA)


def test_calibration_info_of_the_ethernet_interface() -> None:
    assert p.CalibrationInfo.command() == b"\x01" + bytes(19)
    raw = bytes.fromhex("12340203000f4240000f4240" + "0001" * 6)
    info = p.CalibrationInfo.decode(raw)
    assert info == CAL and info.encode() == raw
    np.testing.assert_allclose(info.si_per_count(), [1e-6] * 6)
    lbf = p.CalibrationInfo(1, 1, 1000, 500)
    np.testing.assert_allclose(
        lbf.si_per_count(), [4.4482216152605e-3] * 3 + [0.112984829027617 / 500] * 3
    )
    with pytest.raises(ProtocolError, match="header 0x4321"):
        p.CalibrationInfo.decode(bytes.fromhex("4321") + raw[2:])
    with pytest.raises(SetupError, match="unit code"):
        p.CalibrationInfo(9, 3, 1, 1)


def test_identify_is_one_request_long_answered() -> None:
    with expected_exchange("can", [(REQUEST_LONG, ANSWER)], connect=_driver) as drv:
        counts, status, sample = drv.read_once()
    np.testing.assert_array_equal(counts, COUNTS)
    assert (status, sample) == (0, 7)
    with expected_exchange("can", [(REQUEST_LONG, ANSWER)], connect=_driver) as drv:
        ident = drv.identify()
    assert ident.n_gauges == 6 and ident.serial_number == 501
    assert "base 0x20" in ident.firmware and "status 0x00000000" in ident.firmware


def test_a_silent_sensor_times_out_naming_the_fix() -> None:
    with (
        expected_exchange("can", [(REQUEST_LONG, ANSWER[:2])], connect=_driver) as drv,
        pytest.raises(DeviceTimeoutError, match=r"answers \[1, 2\] .* base address DIP"),
    ):
        drv.read_once(timeout_s=0.2)


def _sample(k: int, counts: list[int], status: int = 0, lose: int | None = None) -> list[Can]:
    """The trigger's request of sample k and the sensor's answers (answer ``lose`` lost)."""
    out = [REQUEST_LONG]
    for off, data in p.long_frames(counts, status, 100 + k):
        if off != lose:
            out.append(Can(BASE + off, data))
    return out


def test_a_run_counts_the_requests_on_the_daqs_clock() -> None:
    c = [[10 * k + j for j in range(6)] for k in range(4)]
    stream = _sample(0, c[0]) + _sample(1, c[1], lose=3) + _sample(2, c[2]) + _sample(3, c[3])
    with expected_exchange("can", [(BIAS, None), (None, stream)], connect=_driver) as drv:
        drv.set_rate(256)  # its held values' phase within 2 deg up to 135 Hz: 0.32 x 256
        drv.start()
        blk = drv.read_until(3)
        assert blk.first_sample == 0 and blk.n_samples == 3
        assert blk.valid.tolist() == [True, False, True]  # sample 1 lost Fz, Tz on the bus
        np.testing.assert_array_equal(blk.gauges_v[:, 0], c[0])
        np.testing.assert_array_equal(blk.gauges_v[:, 2], c[2])
        assert np.isnan(blk.gauges_v[:, 1]).all()
        assert blk.forces is not None
        np.testing.assert_allclose(blk.forces[:, 2], np.array(c[2]) * 1e-6)
        assert [(e.kind, e.first_sample, e.n_samples) for e in blk.events] == [("gap", 1, 1)]
        assert drv.stop() == 4
        rest = drv.read_until(4)
        np.testing.assert_array_equal(rest.gauges_v[:, 0], c[3])
        assert drv.verify_count(4) is None
        ev = drv.verify_count(5)
        assert ev is not None and ev.kind == "drift" and "4 requests counted" in ev.message


def test_a_status_word_is_a_device_error_and_rejects_its_samples() -> None:
    stream = _sample(0, [0] * 6) + _sample(1, [0] * 6, status=0x80000001) + _sample(2, [0] * 6)
    with expected_exchange("can", [(BIAS, None), (None, stream)], connect=_driver) as drv:
        drv.start()
        blk = drv.read_until(3)
        drv.stop()
    assert blk.overload.tolist() == [False, True, False]
    (ev,) = blk.events
    assert ev.kind == "device_error" and "0x80000001" in ev.message


def test_internal_clock_is_refused() -> None:
    with (
        expected_exchange("can", [], connect=_driver) as drv,
        pytest.raises(SetupError, match="requests sent on the DAQ's clock"),
    ):
        drv.start(external_clock=False)


def test_every_unit_code_and_its_si_factor() -> None:
    """Read Calibration Info's unit codes (manual §11.6, as transcribed: force 1 lbf, 2 N,
    3 klbf, 4 kN, 5 kgf, 6 gf; torque 1 lbf-in, 2 lbf-ft, 3 N-m, 4 N-mm, 5 kgf-cm, 6 kN-m), each
    factor built here from the exact definitions (NIST SP 811: lb = 0.45359237 kg,
    g₀ = 9.80665 m/s², in = 0.0254 m, ft = 0.3048 m), not copied from the codec."""
    g0, lb, inch, ft = 9.80665, 0.45359237, 0.0254, 0.3048
    lbf, kgf = lb * g0, g0
    force = {1: ("lbf", lbf), 2: ("N", 1.0), 3: ("klbf", 1e3 * lbf), 4: ("kN", 1e3)}
    force |= {5: ("kgf", kgf), 6: ("gf", 1e-3 * kgf)}
    torque = {1: ("lbf-in", lbf * inch), 2: ("lbf-ft", lbf * ft), 3: ("N-m", 1.0)}
    torque |= {4: ("N-mm", 1e-3), 5: ("kgf-cm", kgf * 0.01), 6: ("kN-m", 1e3)}
    for ours, want in ((p.FORCE_UNITS, force), (p.TORQUE_UNITS, torque)):
        assert sorted(ours) == sorted(want)
        for code, (name, si) in want.items():
            assert ours[code][0] == name
            assert ours[code][1] == pytest.approx(si, rel=1e-12), name


def test_the_highest_base_address_keeps_its_answers_11_bit() -> None:
    """base + 6 (the last short answer) must be an 11-bit identifier, at most 0x7FF: 0x7F9 is
    the highest base taken, 0x7FA the lowest refused."""
    p.check_base(0x7FF - 6)
    with pytest.raises(SetupError):
        p.check_base(0x7FF - 5)


def test_the_axes_in_the_order_of_the_rdt_record() -> None:
    """ATI's RDT record (its demo ``NetFTSensor.java``) and the long answers carry Fx, Fy, Fz,
    Tx, Ty, Tz in that order: the order every ``counts`` array of the codec is in."""
    assert p.AXES == ("Fx", "Fy", "Fz", "Tx", "Ty", "Tz")


def test_the_32_bit_words_wrap_and_keep_every_bit() -> None:
    """The unsigned 32-bit words a sensor sends (status, sample number, RDT and F/T sequence
    numbers) keep every bit, the lowest and the highest, and a counter past 2^32 wraps as the
    device's does; the scalar and the vectorised encoders agree."""
    status, sample = 0x8000_0001, 2**32 + 0x7654_3211  # odd, top bit set; one past a wrap
    want = (0x8000_0001, 0x7654_3211)
    got = p.LongStatus.decode(p.LongStatus(status, sample).encode())
    assert (got.status, got.sample) == want
    counts = np.array([[1, -2, 3, -4, 5, -6]], dtype=np.int64)
    block = p.long_payloads(counts, 0xFFFF_FFFF, np.array([sample]))
    got = p.LongStatus.decode(bytes(block[0, 3]))
    assert (got.status, got.sample) == (0xFFFF_FFFF, want[1])
    assert [bytes(b) for b in block[0]] == [d for _o, d in p.long_frames(counts[0], -1, sample)]
    seq = np.array([2**32 + 1, 0xFFFF_FFFF, 0x8000_0003], dtype=np.int64)
    ft = seq + 2
    one = p.RdtRecord(int(seq[0]), int(ft[0]), status, (1, 2, 3, 4, 5, 6))
    (back,) = p.RdtRecord.decode_all(one.encode())
    assert (back.rdt_sequence, back.ft_sequence, back.status) == (1, 3, want[0])
    rdt = p.decode_rdt(p.encode_rdt(seq, ft, status, np.tile(counts, (3, 1))))
    np.testing.assert_array_equal(rdt.rdt_sequence, [1, 0xFFFF_FFFF, 0x8000_0003])
    np.testing.assert_array_equal(rdt.ft_sequence, [3, 1, 0x8000_0005])
    np.testing.assert_array_equal(rdt.status, [want[0]] * 3)
