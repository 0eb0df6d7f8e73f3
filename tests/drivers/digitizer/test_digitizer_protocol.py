"""Codec of the SD-3 wire protocol: framing, checksum, shot records, errors naming the field."""

import numpy as np
import pytest

from dimacq.devices.digitizer import DigitizerSettings, ShotRecord
from dimacq.drivers.digitizer import protocol as wire
from dimacq.errors import ProtocolError


def test_checksum_is_the_nmea_xor():
    # a published NMEA 0183 sentence and its checksum (independent answer)
    body = b"GPRMC,092750.000,A,5321.6802,N,00630.3372,W,0.02,31.66,280511,,,A"
    assert wire.checksum(body) == 0x43
    assert wire.unframe(b"$" + body + b"*43\r\n")[0] == "GPRMC"


def test_frame_literal_bytes():
    assert wire.frame("OK", "RST") == b"$OK,RST*7D\r\n"


def test_shot_record_round_trip():
    rec = ShotRecord(
        seq=65535,
        status=int(wire.Status.OVERFLOW_E2 | wire.Status.BUTTON),
        averaging=3,
        counts=np.array([[1, 2, 3, 4, 5], [6, 7, 8, 9, 3 * wire.COUNTER_MAX]]),
        bar_counts=np.array([29634, 29635]),
    )
    line = wire.encode_shot(rec)
    assert line.startswith(b"$SHT,65535,0102,2,5,3,2,1,2,3,4,5,6,")
    assert wire.decode_shot(wire.unframe(line)) == rec


def test_settings_round_trip():
    s = DigitizerSettings(emitters=1, microphones=5, averaging=4, bar_repeats=8)
    assert wire.decode_settings(wire.unframe(wire.encode_settings(s))) == s


@pytest.mark.parametrize(
    ("line", "field"),
    [
        (b"$OK,RST*7E\r\n", "'checksum' is 7E, computed 7D"),
        (b"$OK,RST\r\n", "'checksum' missing"),
        (b"$OK,RST*7\r\n", "'checksum' missing"),
        (b"OK,RST*7D\r\n", "'start'"),
        (b"$OK,RST*ZZ\r\n", "'checksum' b'ZZ' is not hex"),
    ],
)
def test_unframe_errors_name_the_field(line, field):
    with pytest.raises(ProtocolError, match=field.replace("*", r"\*")):
        wire.unframe(line)


def _fields(text: str) -> list[str]:
    return wire.unframe(wire.frame(*text.split(",")))


@pytest.mark.parametrize(
    ("text", "field"),
    [
        (
            "SHT,7,0000,2,4,1,2,11,12,13,14,21,22,23,24,31",
            "'counts' has 9 values, expected E\\*M\\+B = 10",
        ),
        ("SHT,7,0000,2,4,1,2,11,12,13,14,21,2x,23,24,31,32", "'counts\\[1,1\\]' = '2x'"),
        ("SHT,7,0000,2,4,1,2,11,12,13,14,21,22,23,24,31,-5", "'bar\\[1\\]' = -5 outside"),
        ("SHT,7,00G0,2,4,1,2,11,12,13,14,21,22,23,24,31,32", "'status'"),
        ("SHT,7,0000,3,4,1,2,11,12,13,14,21,22,23,24,31,32", "E=3"),
        ("SHT,7", "'status' missing"),
        ("IDN,DIMACQ", "expected a shot record"),
    ],
)
def test_truncated_or_malformed_shot_record(text, field):
    with pytest.raises(ProtocolError, match=field):
        wire.decode_shot(_fields(text))


def test_commands():
    assert wire.encode_command("CFG", "A=2") == b"CFG A=2\r"
    assert wire.parse_command(b"cfg a=2,B=3\r\n") == wire.Command("CFG", "a=2,B=3")
    assert wire.parse_cfg_args("a=2, B=3") == {"A": 2, "B": 3}
    with pytest.raises(ProtocolError, match="KEY=VALUE"):
        wire.parse_cfg_args("Q=1")
    with pytest.raises(ProtocolError, match="longer than 80"):
        wire.encode_command("SIM:PROBE", "1" * 90)
    with pytest.raises(ProtocolError, match=r"'\$' or '\*'"):
        wire.frame("ERR", "a*b")
