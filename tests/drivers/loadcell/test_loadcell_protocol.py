"""The load cell message table against fixed reference bytes (the protocol's documented layout).

Each message encodes to, and decodes from, the bytes written out here by hand from the tables of
:mod:`dimacq.drivers.loadcell.protocol`; the codec is not used to make the expected values.
"""

from __future__ import annotations

import numpy as np
import pytest

from dimacq.drivers.loadcell import protocol as p

REQUESTS = [
    (p.Identify(), "01"),
    (p.Start(1), "02 01"),
    (p.Stop(), "03"),
    (p.SetRate(2048), "04 00 08 00 00"),
    (p.Tare(256), "05 00 01"),
    (p.CalDownloadBegin(288), "06 20 01"),
    (p.CalSegment(3, b"abcdef"), "07 03 61 62 63 64 65 66"),
    (p.CalDownloadEnd(0x12345678), "08 78 56 34 12"),
    (p.CalUpload(), "09"),
    (p.GetStatus(), "0b"),
]
REPLIES = [
    (p.IdentifyReply(12, 2, 7, 501), "81 0c 02 07 f5 01 00 00"),
    (p.StartReply(), "82"),
    (p.StopReply(1024), "83 00 04 00 00"),
    (p.SetRateReply(2048), "84 00 08 00 00"),
    (p.TareReply(), "85"),
    (p.CalDownloadBeginReply(), "86"),
    (p.CalDownloadEndReply(), "88"),
    (p.CalUploadReply(288, 0x12345678), "89 20 01 78 56 34 12"),
    (p.CalUploadSegment(3, b"abcdef"), "8a 03 61 62 63 64 65 66"),
    (p.StatusReply(2, 1, 77), "8b 02 01 00 4d 00 00 00"),
    (p.ErrorReply(0x05, 3), "ff 05 03"),
]


@pytest.mark.parametrize(("msg", "hexbytes"), REQUESTS, ids=lambda v: type(v).__name__)
def test_requests_have_the_documented_bytes(msg, hexbytes):
    raw = bytes.fromhex(hexbytes)
    assert msg.encode() == raw
    assert p.decode_request(raw) == msg
    assert len(raw) <= 8  # control frames are classic CAN


@pytest.mark.parametrize(("msg", "hexbytes"), REPLIES, ids=lambda v: type(v).__name__)
def test_replies_have_the_documented_bytes(msg, hexbytes):
    raw = bytes.fromhex(hexbytes)
    assert msg.encode() == raw
    assert p.decode_reply(raw) == msg
    assert len(raw) <= 8


def test_every_command_is_in_the_table_with_its_reply():
    assert set(p.REQUESTS) == set(p.Command)
    for op, cls in p.REQUESTS.items():
        assert cls.OPCODE == op
        assert cls.REPLY is None or cls.REPLY.OPCODE == op | 0x80


@pytest.mark.parametrize(
    ("raw", "code"),
    [
        ("0c", p.ErrorCode.UNKNOWN_COMMAND),
        ("02", p.ErrorCode.BAD_ARGUMENT),  # START without its clock byte
        ("02 05", p.ErrorCode.BAD_ARGUMENT),  # clock neither 0 nor 1
        ("04 00 00 00 00", p.ErrorCode.BAD_ARGUMENT),  # rate 0 Hz
        ("07 03 61 62", p.ErrorCode.BAD_ARGUMENT),  # short segment
    ],
)
def test_bad_commands_carry_the_code_the_amplifier_answers(raw, code):
    with pytest.raises(p.BadMessage) as info:
        p.decode_request(bytes.fromhex(raw))
    assert info.value.code == code


def test_heartbeat_bytes_and_wrap():
    assert p.Heartbeat(256, 256_000).encode() == bytes.fromhex("00 01 00 00 00 e8 03 00")
    assert p.Heartbeat.decode(bytes.fromhex("00 01 00 00 00 e8 03 00")) == p.Heartbeat(256, 256_000)
    assert p.Heartbeat(2**32 + 5, 2**32 + 7).encode() == bytes.fromhex("05 00 00 00 07 00 00 00")


DATA_FRAME = bytes.fromhex(
    "04 03 02 01"  # counter 0x01020304
    "01"  # status: overload
    "00 00 00"  # reserved
    "00 00 40"  # gauge 1: +2^22 counts = +5 V
    "00 00 c0"  # gauge 2: -2^22 counts = -5 V
    "ff ff 7f"  # gauge 3: +(2^23 - 1) counts, clipped from 12 V
    + "00 00 00" * 9  # gauges 4..12
    + "00 00 00 00"  # padding to 48 bytes
)


def test_data_frame_layout():
    g = np.zeros((1, 12))
    g[0, :3] = [5.0, -5.0, 12.0]
    frames, over = p.encode_data_frames([0x01020304], g)
    assert frames == [DATA_FRAME] and over.tolist() == [True]
    counters, status, gauges = p.decode_data_frames([DATA_FRAME])
    assert counters.tolist() == [0x01020304] and status.tolist() == [1]
    np.testing.assert_array_equal(gauges[0, :3], [5.0, -5.0, 10.0 * (2**23 - 1) / 2**23])
    assert not gauges[0, 3:].any()


def test_calibration_blob_segments_and_crc():
    m = np.arange(72, dtype=float).reshape(6, 12)
    blob = p.matrix_to_blob(m)
    assert blob[:8] == bytes.fromhex("00000000 0000803f")  # float32 0.0, 1.0 little-endian
    segs = p.segments(blob)
    assert len(segs) == p.n_segments(288) == 48
    assert p.join_segments(dict(enumerate(segs)), 288) == blob
    assert p.blob_crc(b"123456789") == 0xCBF43926  # the CRC-32 check value
    with pytest.raises(p.BadMessage) as info:
        p.join_segments({i: s for i, s in enumerate(segs) if i != 7}, 288)
    assert info.value.code == p.ErrorCode.MISSING_SEGMENT
