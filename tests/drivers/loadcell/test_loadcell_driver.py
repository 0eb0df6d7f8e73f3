"""Load cell driver against scripted CAN exchanges (tests/_exchange.py).

Each test lists the frames the driver sends and the amplifier's answers; control frames are
literal bytes (the layout is pinned in test_loadcell_protocol.py), data frames and heartbeats
are built with the protocol's codec. Leftover or unexpected frames fail the test.
"""

from __future__ import annotations

import can
import numpy as np
import pytest
from _exchange import Can, expected_exchange

from dimacq.drivers.loadcell import protocol as p
from dimacq.drivers.loadcell.driver import LoadCellAmplifier
from dimacq.drivers.stream import CounterStream
from dimacq.errors import (
    DeviceError,
    DeviceStateError,
    DeviceTimeoutError,
    ProtocolError,
    SetupError,
)

NODE = 3
CMD, RSP, DATA, HB = 0x603, 0x583, 0x183, 0x703


def cmd(hexbytes):
    return Can(CMD, bytes.fromhex(hexbytes))


def rsp(hexbytes):
    return Can(RSP, bytes.fromhex(hexbytes))


def amp(**kw):
    return lambda bus: LoadCellAmplifier(bus, node_id=NODE, timeout_s=0.2, **kw)


def test_identifiers_of_the_node():
    assert (p.command_id(NODE), p.response_id(NODE), p.data_id(NODE), p.heartbeat_id(NODE)) == (
        CMD,
        RSP,
        DATA,
        HB,
    )


def test_identify_rate_start_stop_exchange():
    script = [
        (cmd("01"), rsp("81 0c 02 07 f5 01 00 00")),
        (cmd("04 00 08 00 00"), rsp("84 00 08 00 00")),
        (cmd("02 01"), rsp("82")),
        (cmd("03"), rsp("83 00 00 00 00")),
    ]
    with expected_exchange("can", script, connect=amp()) as a:
        ident = a.identify()
        assert (ident.n_gauges, ident.firmware, ident.serial_number) == (12, "2.7", 501)
        assert a.set_rate(2048) == 2048.0
        a.start()
        assert a.stop() == 0


def test_status_and_tare():
    script = [(cmd("0b"), rsp("8b 02 01 00 4d 00 00 00")), (cmd("05 00 01"), rsp("85"))]
    with expected_exchange("can", script, connect=amp()) as a:
        assert a.get_status() == (2, 1, 77)
        a.tare(256)


def test_calibration_download_and_upload():
    m = np.arange(72, dtype=float).reshape(6, 12) / 7
    blob = p.matrix_to_blob(m)
    segs = p.segments(blob)
    crc = p.blob_crc(blob)
    script = [(cmd("06 20 01"), rsp("86"))]
    script += [(Can(CMD, p.CalSegment(i, s).encode()), None) for i, s in enumerate(segs)]
    script += [(Can(CMD, p.CalDownloadEnd(crc).encode()), rsp("88"))]
    with expected_exchange("can", script, connect=amp()) as a:
        a.download_calibration(m)
    # upload: header then segments, out of order is fine
    answers = [Can(RSP, p.CalUploadReply(288, crc).encode())]
    answers += [Can(RSP, p.CalUploadSegment(i, segs[i]).encode()) for i in reversed(range(48))]
    with expected_exchange("can", [(cmd("09"), answers)], connect=amp()) as a:
        np.testing.assert_allclose(a.upload_calibration(), m, rtol=1e-7)


def test_upload_with_a_bad_crc_is_refused():
    blob = p.matrix_to_blob(np.ones((6, 12)))
    answers = [rsp("89 20 01 00 00 00 00")]
    answers += [Can(RSP, p.CalUploadSegment(i, s).encode()) for i, s in enumerate(p.segments(blob))]
    with expected_exchange("can", [(cmd("09"), answers)], connect=amp()) as a:
        with pytest.raises(ProtocolError, match="fails its CRC"):
            a.upload_calibration()


def test_refusals_map_to_errors():
    with expected_exchange("can", [(cmd("05 00 01"), rsp("ff 05 03"))], connect=amp()) as a:
        with pytest.raises(DeviceStateError, match="streaming"):
            a.tare(256)
    crc_end = [(cmd("06 20 01"), rsp("86"))]
    crc_end += [
        (Can(CMD, p.CalSegment(i, s).encode()), None) for i, s in enumerate(p.segments(bytes(288)))
    ]
    crc_end += [(Can(CMD, p.CalDownloadEnd(p.blob_crc(bytes(288))).encode()), rsp("ff 08 04"))]
    with expected_exchange("can", crc_end, connect=amp()) as a:
        with pytest.raises(ProtocolError, match="CRC"):
            a.download_calibration(np.zeros((6, 12)))
    with expected_exchange("can", [(cmd("01"), rsp("85"))], connect=amp()) as a:
        with pytest.raises(ProtocolError, match="expected response 0x81, got 85"):
            a.identify()


def test_timeout_and_bad_setup():
    with expected_exchange("can", [(cmd("01"), None)], connect=amp()) as a:
        with pytest.raises(DeviceTimeoutError, match="did not answer"):
            a.identify()
    with pytest.raises(SetupError, match="6x12"):
        LoadCellAmplifier(None, node_id=NODE, calibration_matrix=np.zeros((6, 11)))  # type: ignore[arg-type]
    with pytest.raises(SetupError, match="timeout_s"):
        LoadCellAmplifier(None, node_id=NODE, timeout_s=0.0)  # type: ignore[arg-type]


def test_queries_are_retried_when_asked_for():
    script = [(cmd("01"), None), (cmd("01"), rsp("81 0c 02 07 f5 01 00 00"))]
    with expected_exchange("can", script, connect=amp(retries=1)) as a:
        assert a.identify().serial_number == 501


def test_send_failure_is_a_device_error():
    class Failing:
        def send(self, msg):
            raise can.CanError("bus off")

    with pytest.raises(DeviceError, match="cannot send IDENTIFY: bus off"):
        LoadCellAmplifier(Failing(), node_id=NODE).identify()  # type: ignore[arg-type]


def data_frames(counters, gauges):
    frames, _ = p.encode_data_frames(np.asarray(counters), gauges)
    return [Can(DATA, f, fd=True) for f in frames]


def started(*more, **kw):
    """The script that arms the amplifier at 1000 Hz, then ``more`` (what the amplifier sends)."""
    return [
        (cmd("04 e8 03 00 00"), rsp("84 e8 03 00 00")),
        (cmd("02 01"), rsp("82")),
        *((None, m) for m in more),
    ]


def arm(a):
    a.set_rate(1000)
    a.start()
    return a


def test_stream_gap_is_nan_and_reported_and_matrix_applied():
    C = np.random.default_rng(0).standard_normal((6, 12))
    g = np.random.default_rng(1).uniform(-5, 5, (10, 12))
    kept = [k for k in range(10) if k not in (4, 5)]
    with expected_exchange(
        "can", started(data_frames(kept, g[kept])), connect=amp(calibration_matrix=C)
    ) as a:
        block = arm(a).read_until(8)
        assert block.first_sample == 0 and block.gauges_v.shape == (12, 8)
        assert block.valid.tolist() == [1, 1, 1, 1, 0, 0, 1, 1]
        assert np.isnan(block.gauges_v[:, 4:6]).all()
        np.testing.assert_allclose(block.gauges_v[:, :4], g[:4].T, atol=10 / 2**23)
        np.testing.assert_allclose(block.forces[:, 7], C @ g[7], atol=1e-4)
        assert [(e.kind, e.first_sample, e.n_samples) for e in block.events] == [("gap", 4, 2)]
        rest = a.read_until(10)
        assert rest.first_sample == 8 and rest.valid.all()


def test_frames_lost_at_the_end_of_a_run_are_a_gap_not_a_timeout():
    """A bus-off over a run's last pulses: no frame comes again once the SYNC stops. The
    stalled driver asks the amplifier's counter (GET_STATUS): past the end, the rest is a gap."""
    g = np.ones((6, 12))
    script = [*started(data_frames(range(6), g)), (cmd("0b"), rsp("8b 02 00 00 0a 00 00 00"))]
    with expected_exchange("can", script, connect=amp()) as a:
        block = arm(a).read_until(10, timeout_s=5.0)
        assert block.valid.tolist() == [1] * 6 + [0] * 4
        assert [(e.kind, e.first_sample, e.n_samples) for e in block.events] == [("gap", 6, 4)]


def test_a_stalled_stream_short_of_the_end_still_times_out():
    script = [*started(data_frames(range(6), np.ones((6, 12))))]
    script += [(cmd("0b"), rsp("8b 02 00 00 07 00 00 00"))] * 2
    with expected_exchange("can", script, connect=amp()) as a, pytest.raises(DeviceTimeoutError):
        arm(a).read_until(10, timeout_s=1.2)


def test_counter_wraps_without_a_gap():
    frames = data_frames([2**32 - 2, 2**32 - 1, 0, 1], np.zeros((4, 12)))
    with expected_exchange("can", started(frames), connect=amp()) as a:
        arm(a)
        a._stream.samples = CounterStream(12, first_sample=2**32 - 2)
        a._stream.last_counter = 2**32 - 3
        block = a.read_until(2**32 + 2)
        assert block.valid.all() and not block.events


def test_heartbeat_drift_is_reported():
    # counter vs the amplifier's own time at 1000 Hz: 3 pulses missed by the second heartbeat
    beats = [
        Can(HB, p.Heartbeat(256, 256_000).encode()),
        Can(HB, p.Heartbeat(512, 515_000).encode()),
    ]
    with expected_exchange(
        "can", started(beats, data_frames(range(520), np.zeros((520, 12)))), connect=amp()
    ) as a:
        block = arm(a).read_until(520)
        drift = [e for e in block.events if e.kind == "drift"]
        assert len(drift) == 1 and "-3.0 samples" in drift[0].message


def test_overload_status_is_reported():
    g = np.zeros((4, 12))
    g[2, 5] = 12.0  # beyond ±10 V
    with expected_exchange("can", started(data_frames(range(4), g)), connect=amp()) as a:
        block = arm(a).read_until(4)
        assert block.overload.tolist() == [False, False, True, False]
        assert [e.kind for e in block.events] == ["overload"]


def test_short_data_frame_is_a_protocol_error():
    with expected_exchange("can", started(Can(DATA, bytes(8))), connect=amp()) as a:
        with pytest.raises(ProtocolError, match="CAN FD"):
            arm(a).read_until(1)


def test_leftover_frames_fail_the_test():
    with pytest.raises(AssertionError, match="script not consumed"):
        with expected_exchange("can", [(cmd("01"), rsp("81 0c 02 07 f5 01 00 00"))]):
            pass
    with pytest.raises(AssertionError, match="answers left unread"):
        with expected_exchange("can", [(None, rsp("85"))]):
            pass
    with pytest.raises(AssertionError, match="script expected"):
        with expected_exchange("can", [(cmd("01"), None)], connect=amp()) as a:
            a.get_status()


def test_the_amplifiers_u32_counter_is_unwrapped_against_the_stream():
    from dimacq.drivers.loadcell.counting import unwrap_u32

    assert unwrap_u32(5, 2**32 - 3) == 2**32 + 5
    assert unwrap_u32(2**32 - 1, 2**32 - 3) == 2**32 - 1
    assert unwrap_u32(10, -1) == 10  # nothing received yet
