"""The driver against scripted byte exchanges (tests/_exchange.py, pymeasure ``expected_protocol``)."""

import numpy as np
import pytest
from _digitizer_support import SCRIPT, expected_protocol
from _exchange import ScriptedSerial

from dimacq.drivers.digitizer import SerialDigitizer
from dimacq.errors import (
    DeviceNotFoundError,
    DeviceStateError,
    DeviceTimeoutError,
    ProtocolError,
    SetupError,
)

SHT7 = b"$SHT,7,0000,2,4,1,2,11,12,13,14,21,22,23,24,31,32*7E\r\n"
SHT8 = b"$SHT,8,0000,2,4,1,2,11,12,13,14,21,22,23,24,31,32*71\r\n"


def test_script_shared_with_pty():
    with expected_protocol(SCRIPT) as d:
        ident = d.identify()
        assert (ident.vendor, ident.model, ident.serial, ident.n_microphones) == (
            "DIMACQ",
            "SD-3-SIM",
            "SIM-T",
            4,
        )
        d.reset()
        assert d.settings().averaging == 1
        s = d.configure(averaging=3, bar_repeats=2)
        assert (s.averaging, s.bar_repeats, s.clock_hz, s.delay_counts) == (3, 2, 10e6, 500)
        with pytest.raises(ProtocolError, match="error 1 \\(unknown command BOGUS\\)"):
            d.command("BOGUS")
        assert d.command("SIM:ECHOES?", expect="SIM") == ["SIM", "ECHOES", "0"]
        d.reset()


def test_fire_decodes_counts():
    with expected_protocol([(b"SHOT\r", SHT7)]) as d:
        rec = d.fire()
    assert rec.seq == 7 and rec.averaging == 1
    np.testing.assert_array_equal(rec.counts, [[11, 12, 13, 14], [21, 22, 23, 24]])
    np.testing.assert_array_equal(rec.bar_counts, [31, 32])


def test_resync_after_garbage_bytes():
    with expected_protocol([(b"SHOT\r", b"\x00\xff\x13noise*12\r\n" + SHT7)]) as d:
        assert d.fire().seq == 7
        assert d.stats.garbage_bytes == len(b"\x00\xff\x13noise*12\r\n")


def test_truncated_line_dropped_and_next_record_read():
    with expected_protocol([(b"SHOT\r", SHT7[:25] + SHT7)]) as d:
        assert d.fire().seq == 7
        assert d.stats.truncated_lines == 1


def test_checksum_error_names_field_and_stream_stays_in_step():
    bad = SHT7.replace(b"*7E", b"*7F")
    with expected_protocol([(b"SHOT\r", bad), (b"SHOT\r", SHT8)]) as d:
        with pytest.raises(ProtocolError, match="field 'checksum' is 7F, computed 7E"):
            d.fire()
        assert d.fire().seq == 8
        assert d.stats.bad_lines == 1


def test_truncated_record_with_valid_frame():
    line = b"$SHT,7,0000,2,4,1,2,11,12*"
    from dimacq.drivers.digitizer.protocol import checksum

    line += f"{checksum(line[1:-1]):02X}".encode() + b"\r\n"
    with expected_protocol([(b"SHOT\r", line)]) as d:
        with pytest.raises(ProtocolError, match="'counts' has 2 values"):
            d.fire()


def test_timeout_when_device_silent():
    with expected_protocol([(b"*IDN?\r", None)], timeout_s=0.05) as d:
        with pytest.raises(DeviceTimeoutError, match=r"no reply to \*IDN\? within 0\.05 s"):
            d.identify()


def test_timeout_is_also_builtin_timeout():
    with expected_protocol([(b"SHOT\r", SHT7[:20])], timeout_s=0.02) as d:
        with pytest.raises(TimeoutError):
            d.fire()
        d._buf.clear()


def test_stream_yields_records_then_ok():
    with expected_protocol([(b"STRM 2\r", SHT7 + SHT8 + b"$OK,STRM,2*2E\r\n")]) as d:
        assert [r.seq for r in d.stream(2)] == [7, 8]


def test_stream_skips_bad_record_and_counts_gap():
    bad = SHT7.replace(b"*7E", b"*00")
    with expected_protocol(
        [(b"STRM 2\r", bad + SHT8 + b"$OK,STRM,2*2E\r\n"), (b"SHOT\r", SHT7)]
    ) as d:
        d._last_seq = 6
        assert [r.seq for r in d.stream(2)] == [8]
        assert d.stats.seq_gaps == 1 and d.stats.bad_lines == 1
        d.fire()


def test_interrupted_stream_sends_stop():
    script = [(b"STRM 5\r", SHT7), (b"STOP\r", SHT8 + b"$OK,STOP*30\r\n")]
    with expected_protocol(script) as d:
        for rec in d.stream(5):
            assert rec.seq == 7
            break
    assert d.stats.stale_records == 1


def test_busy_maps_to_state_error():
    with expected_protocol([(b"SHOT\r", b"$ERR,3,streaming; send STOP*35\r\n")]) as d:
        with pytest.raises(DeviceStateError, match="busy"):
            d.fire()


def test_configure_validates_before_sending():
    with expected_protocol([]) as d:
        with pytest.raises(SetupError, match=r"averaging = 17; give an integer 1\.\.16"):
            d.configure(averaging=17)
        with pytest.raises(SetupError, match="n_shots"):
            next(d.stream(0))


def test_port_vanishes_then_reconnect():
    first = ScriptedSerial([(b"SHOT\r", SHT7), (b"SHOT\r", SHT8)], vanish_after=1)
    second = ScriptedSerial([(b"*IDN?\r", SCRIPT[0][1]), (b"SHOT\r", SHT8)])
    ports = iter([second])
    d = SerialDigitizer(first, reopen=lambda: next(ports), timeout_s=0.05, name="scripted")
    assert d.fire().seq == 7
    with pytest.raises(DeviceNotFoundError, match=r"port vanished .* call reconnect"):
        d.fire()
    assert first.closed
    with pytest.raises(DeviceNotFoundError, match="port is gone"):
        d.fire()
    assert d.reconnect(attempts=1).serial == "SIM-T"
    assert d.fire().seq == 8
    assert not second.pairs and d.stats.reconnects == 1
    d.close()
    with pytest.raises(DeviceStateError, match="closed"):
        d.fire()


def test_reply_damaged_while_reconnecting_is_reported(caplog: pytest.LogCaptureFixture) -> None:
    # the 30-minute soak: a checksum error on *IDN? during the reopening was retried silently,
    # so one injected line fault of 330 went unreported
    idn = SCRIPT[0][1]
    bad = idn[:-4] + (b"00" if idn[-4:-2] != b"00" else b"11") + idn[-2:]  # wrong checksum
    first = ScriptedSerial([], vanish_after=0)
    second = ScriptedSerial([(b"*IDN?\r", bad)])
    third = ScriptedSerial([(b"*IDN?\r", idn)])
    ports = iter([second, third])
    d = SerialDigitizer(first, reopen=lambda: next(ports), timeout_s=0.05, name="scripted")
    with caplog.at_level("WARNING", logger="dimacq.drivers.digitizer.driver"):
        assert d.reconnect(attempts=2, delay_s=0.0).serial == "SIM-T"
    failed = [
        r.getMessage()
        for r in caplog.records
        if "reconnect attempt 1 of 2 failed" in r.getMessage()
    ]
    assert len(failed) == 1 and "checksum" in failed[0]
    assert "bytes were corrupted on the link" in failed[0]  # what the soak counts
    d.close()


def test_reconnect_without_factory_fails_clearly():
    d = SerialDigitizer(ScriptedSerial([]), timeout_s=0.05)
    with pytest.raises(DeviceNotFoundError, match="reconnect failed after 2 attempts"):
        d.reconnect(attempts=2, delay_s=0.0)
    d.close()


def test_leftover_pairs_fail_the_test():
    with pytest.raises(AssertionError, match="script not consumed"):
        with expected_protocol([(b"SHOT\r", SHT7)]):
            pass
