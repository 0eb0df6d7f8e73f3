"""DAQ driver against scripted USB exchanges (tests/_exchange.py), and the DAQ's wire format
against fixed reference bytes written out from the tables of :mod:`dimacq.drivers.daq.protocol`."""

from __future__ import annotations

import contextlib
import errno

import numpy as np
import pytest
import usb.core
from _exchange import BulkIn, Ctrl, expected_exchange

from dimacq.drivers.daq import protocol as p
from dimacq.drivers.daq.driver import DaqDevice, DaqTask
from dimacq.errors import DeviceStateError, DeviceTimeoutError, ProtocolError, SetupError

IDENT = p.DeviceIdentity(1, 4, 51200, 24, 5, "SN42", "fw1").encode()


TIMEOUT = usb.core.USBTimeoutError("Operation timed out", error_code=-7, errno=110)


def status(rate=2048.0, running=False):
    return p.DeviceStatus(running, False, rate, 0, 0).encode()


def IN(req, n, answer):
    return (Ctrl(p.BM_REQUEST_IN, req, 0, 0, n), answer)


def OUT(req, value=0, index=0, data=b""):
    return (Ctrl(p.BM_REQUEST_OUT, req, value, index, data), 0)


# -- the wire format, byte for byte ---------------------------------------------------------------

#: A frame of 2 samples x 2 channels: sequence 7, first sample 1024, FIFO overflow before it,
#: channel 1 (in frame order) overloaded.
FRAME_REF = bytes.fromhex(
    "44 46"  # magic "DF"
    "01"  # protocol version
    "01"  # flags: OVERFLOW
    "07 00 00 00"  # sequence u32
    "00 04 00 00 00 00 00 00"  # first sample u64 = 1024
    "02 00"  # n_samples u16
    "02 00"  # n_channels u16
    "02 00 00 00 00 00 00 00"  # overload mask u64: enabled channel 1
    "00 ff c4 ec"  # CRC-32 of the payload
    "01 00 00  ff ff ff"  # sample 0: +1, -1 counts
    "ff ff 7f  01 00 80"  # sample 1: +(2^23 - 1), -(2^23 - 1) counts
)
COUNTS_REF = [[1, -1], [2**23 - 1, -(2**23 - 1)]]
#: IDENTIFY answer: "DQ64", version 1, 64 channels, 204800 Hz, 24 bits, 5 ranges, serial, firmware
IDENT_REF = bytes.fromhex(
    "44 51 36 34  01 00  40 00  00 20 03 00  18  05"
    + "53 4e 34 32"
    + "00" * 12  # "SN42", NUL padded to 16
    + "66 77 31"
    + "00" * 13  # "fw1", NUL padded to 16
)
#: GET_STATUS answer: running, no overflow, reserved, 2048.0 Hz (f64), 4096 samples, 2 frames lost
STATUS_REF = bytes.fromhex(
    "01 00 00 00  00 00 00 00 00 00 a0 40  00 10 00 00 00 00 00 00  02 00 00 00"
)


def test_frame_reference_bytes():
    assert p.frame_size(2, 2) == len(FRAME_REF) == 44
    assert (
        p.encode_frame(
            7, 1024, np.array(COUNTS_REF), overload_mask=0b10, flags=p.FrameFlags.OVERFLOW
        )
        == FRAME_REF
    )
    f = p.decode_frame(FRAME_REF)
    assert (f.flags, f.sequence, f.first_sample, f.n_samples, f.n_channels, f.overload_mask) == (
        p.FrameFlags.OVERFLOW,
        7,
        1024,
        2,
        2,
        0b10,
    )
    assert f.counts.tolist() == COUNTS_REF


def test_identify_and_status_reference_bytes():
    ident = p.DeviceIdentity(1, 64, 204800, 24, 5, "SN42", "fw1")
    assert ident.encode() == IDENT_REF and p.DeviceIdentity.decode(IDENT_REF) == ident
    st = p.DeviceStatus(True, False, 2048.0, 4096, 2)
    assert st.encode() == STATUS_REF and p.DeviceStatus.decode(STATUS_REF) == st
    assert p.RATE_STRUCT.pack(51200) == bytes.fromhex("00 c8 00 00")


def test_reference_frame_read_by_a_task():
    """The reference frame through the driver: the overflow before it is a reported gap."""
    script = [
        IN(p.Request.IDENTIFY, p.IDENTIFY_STRUCT.size, IDENT_REF),
        OUT(p.Request.SET_SAMPLE_RATE, data=bytes.fromhex("00 08 00 00")),
        *(OUT(p.Request.SET_CHANNEL_ENABLE, int(k < 2), k) for k in range(64)),
        *(
            step
            for k in range(2)
            for step in (
                OUT(p.Request.SET_RANGE, 0, k),
                OUT(p.Request.SET_IEPE, 0, k),
                OUT(p.Request.SET_COUPLING, 0, k),
            )
        ),
        IN(p.Request.GET_STATUS, p.STATUS_STRUCT.size, STATUS_REF),
        (BulkIn(p.DATA_ENDPOINT, 44), TIMEOUT),  # nothing stale to drain
        OUT(p.Request.START, 2),
        (BulkIn(p.DATA_ENDPOINT, 44), FRAME_REF),
    ]
    with expected_exchange("usb", script, connect=DaqDevice) as dev:
        task = DaqTask(dev)
        task.add_voltage_channel(0, "a")
        task.add_voltage_channel(1, "b")
        task.configure_timing(2048, samples_per_frame=2)
        task.start()
        block = task.read(1026)
    assert [(e.kind, e.first_sample, e.n_samples) for e in block.events] == [
        ("overflow", 0, 1024),
        ("overload", 1024, 2),
    ]
    assert block.valid.sum() == 2 and np.isnan(block.data[:, :1024]).all()
    np.testing.assert_array_equal(block.data[:, 1024:] * 2**23 / 10, np.array(COUNTS_REF).T)


# -- the driver's logic -----------------------------------------------------------------------------


def test_identify_exchange():
    script = [IN(p.Request.IDENTIFY, p.IDENTIFY_STRUCT.size, IDENT)]
    with expected_exchange("usb", script, connect=DaqDevice) as dev:
        ident = dev.identify()
    assert (ident.n_channels, ident.serial_number, ident.firmware) == (4, "SN42", "fw1")


def start_script(spf=4, stale=()):
    """The exchange of ``DaqTask.start``; ``stale``: frames left in the FIFO, drained first."""
    R = p.Request
    drain = [(BulkIn(p.DATA_ENDPOINT, p.frame_size(spf, 2)), f) for f in (*stale, TIMEOUT)]
    return [
        IN(R.IDENTIFY, p.IDENTIFY_STRUCT.size, IDENT),
        OUT(R.SET_SAMPLE_RATE, data=bytes.fromhex("00 08 00 00")),  # u32 2048
        OUT(R.SET_CHANNEL_ENABLE, 0, 0),
        OUT(R.SET_CHANNEL_ENABLE, 1, 1),
        OUT(R.SET_CHANNEL_ENABLE, 0, 2),
        OUT(R.SET_CHANNEL_ENABLE, 1, 3),
        OUT(R.SET_RANGE, 1, 1),  # ±5 V
        OUT(R.SET_IEPE, 4000, 1),
        OUT(R.SET_COUPLING, 1, 1),
        OUT(R.SET_RANGE, 0, 3),  # ±10 V
        OUT(R.SET_IEPE, 0, 3),
        OUT(R.SET_COUPLING, 0, 3),
        IN(R.GET_STATUS, p.STATUS_STRUCT.size, status()),
        *drain,
        OUT(R.START, spf),
    ]


@contextlib.contextmanager
def started_task(script, stale=()):
    """A task of two channels started by the start script, then ``script``."""
    with expected_exchange("usb", start_script(stale=stale) + script, connect=DaqDevice) as dev:
        task = DaqTask(dev)
        task.add_voltage_channel(3, "aux")
        task.add_accel_channel(1, "1103+Y", 100.0)
        task.configure_timing(2048, samples_per_frame=4)
        task.start()
        yield task


def frame(seq, first, counts, **kw):
    return p.encode_frame(seq, first, np.asarray(counts), **kw)


FRAME_4x2 = p.frame_size(4, 2)


def read(answer, size=FRAME_4x2):
    return (BulkIn(p.DATA_ENDPOINT, size), answer)


def test_start_exchange_and_engineering_units():
    counts = np.array([[2**22, 0], [-(2**22), 2**22], [0, 0], [1, -1]])
    stop = [OUT(p.Request.STOP), IN(p.Request.GET_STATUS, p.STATUS_STRUCT.size, status())]
    with started_task([read(frame(0, 0, counts)), *stop]) as task:
        block = task.read(4)
        task.stop()
    assert task.channel_names == ("1103+Y", "aux")  # ascending physical channel
    # 2^22 counts on ±5 V = 2.5 V; at 100 mV/g that is 25 g
    assert block.data[0, 0] == pytest.approx(25 * 9.80665, rel=1e-12)
    assert block.data[1, 1] == pytest.approx(5.0, rel=1e-12)  # ±10 V voltage channel
    assert block.data[0, 3] == pytest.approx(5 / 2**23 / 0.1 * 9.80665, rel=1e-12)


def test_stale_frames_are_drained_before_start_and_stop_reads_samples_clocked():
    """Frames a previous run left in the FIFO are read and dropped before START (else the
    first one, sequence 5 at sample 640, would read as lost transfers); after STOP the task
    knows the samples the DAQ clocked (GET_STATUS), not just those it received, and reads what
    the FIFO still holds up to them (the short last frame), so nothing is left stale."""
    c = np.ones((4, 2), dtype=int)
    stale = [frame(5, 640, c), frame(6, 644, c)]
    clocked = p.DeviceStatus(False, False, 2048.0, 11, 0).encode()
    stop = [
        OUT(p.Request.STOP),
        IN(p.Request.GET_STATUS, p.STATUS_STRUCT.size, clocked),
        read(frame(2, 8, 4 * np.ones((3, 2), dtype=int))),
    ]
    with started_task([read(frame(0, 0, 2 * c)), read(frame(1, 4, 3 * c)), *stop], stale) as task:
        block = task.read(8)
        assert task.samples_clocked is None
        task.stop()
        rest = task.read_buffered()
    assert block.first_sample == 0 and block.valid.all() and not block.events
    np.testing.assert_array_equal(block.data[1] * 2**23 / 10, [2] * 4 + [3] * 4)
    assert task.samples_clocked == 11
    assert rest is not None and (rest.first_sample, rest.n_samples) == (8, 3) and rest.valid.all()


def test_overflow_gap_is_nan_filled_and_reported():
    c = np.ones((4, 2), dtype=int)
    with started_task(
        [read(frame(0, 0, c)), read(frame(1, 8, 2 * c, flags=p.FrameFlags.OVERFLOW))]
    ) as task:
        block = task.read(12)
    assert [(e.kind, e.first_sample, e.n_samples) for e in block.events] == [("overflow", 4, 4)]
    assert (
        np.isnan(block.data[:, 4:8]).all() and block.valid.tolist() == [1] * 4 + [0] * 4 + [1] * 4
    )


def test_lost_transfer_is_reported():
    c = np.ones((4, 2), dtype=int)
    with started_task([read(frame(0, 0, c)), read(frame(2, 8, c))]) as task:
        block = task.read(12)
    assert [(e.kind, e.first_sample) for e in block.events] == [("lost_transfer", 4)]


def test_overload_event_names_the_channel():
    c = np.zeros((4, 2), dtype=int)
    with started_task([read(frame(0, 0, c, overload_mask=0b10))]) as task:
        block = task.read(4)
    (ev,) = block.events
    assert ev.kind == "overload" and ev.channels == ("aux",)
    assert block.overload[1].all() and not block.overload[0].any()


def test_timeout_keeps_received_samples():
    c = np.arange(8).reshape(4, 2)
    timeout = usb.core.USBTimeoutError("Operation timed out", error_code=-7, errno=110)
    with started_task([read(frame(0, 0, c)), read(timeout), read(frame(1, 4, c + 100))]) as task:
        with pytest.raises(DeviceTimeoutError, match="4 samples received and kept"):
            task.read(8)
        block = task.read(8)
    assert block.first_sample == 0
    np.testing.assert_array_equal(block.data[1] * 2**23 / 10, [1, 3, 5, 7, 101, 103, 105, 107])
    assert [e.kind for e in task.events] == ["timeout"]


def test_corrupt_frame_and_backwards_counter_are_protocol_errors():
    c = np.ones((4, 2), dtype=int)
    bad = bytearray(frame(0, 0, c))
    bad[-1] ^= 0xFF
    with started_task([read(bytes(bad))]) as task:
        with pytest.raises(ProtocolError, match="CRC"):
            task.read(4)
    with started_task([read(frame(0, 4, c)), read(frame(1, 2, c))]) as task:
        with pytest.raises(ProtocolError, match="backwards"):
            task.read(12)


def test_stall_becomes_device_state_error():
    stall = usb.core.USBError("Pipe error", error_code=-9, errno=errno.EPIPE)
    script = [(Ctrl(p.BM_REQUEST_OUT, p.Request.SET_IEPE, 2000, 70, b""), stall)]
    with expected_exchange("usb", script, connect=DaqDevice) as dev:
        with pytest.raises(DeviceStateError, match="SET_IEPE"):
            dev.set_iepe(70, 2000)


def test_queries_are_retried_when_asked_for_and_closed_device_refuses():
    timeout = usb.core.USBTimeoutError("Operation timed out", error_code=-7, errno=110)
    script = [
        IN(p.Request.GET_STATUS, p.STATUS_STRUCT.size, timeout),
        IN(p.Request.GET_STATUS, p.STATUS_STRUCT.size, STATUS_REF),
    ]
    with expected_exchange("usb", script, connect=lambda u: DaqDevice(u, retries=1)) as dev:
        assert dev.get_status().samples_clocked == 4096
        dev.close()
        with pytest.raises(
            DeviceStateError, match=r"closed; open it again with DaqDevice\.open\(\)"
        ):
            dev.get_status()
    script = [IN(p.Request.GET_STATUS, p.STATUS_STRUCT.size, timeout)]
    with expected_exchange("usb", script, connect=DaqDevice) as dev:
        with pytest.raises(DeviceTimeoutError, match=r"did not answer GET_STATUS within 1\.0 s"):
            dev.get_status()


def test_bad_channel_setup_is_refused():
    with expected_exchange("usb", [], connect=DaqDevice) as dev:  # nothing reaches the wire
        task = DaqTask(dev)
        task.add_accel_channel(0, "a", 100.0)
        with pytest.raises(SetupError, match="already in task"):
            task.add_accel_channel(0, "b", 100.0)
        with pytest.raises(SetupError, match="range"):
            task.add_accel_channel(1, "c", 100.0, range_v=3.0)
        with pytest.raises(SetupError, match="sensitivity"):
            task.add_force_channel(2, "d", 0.0)
        with pytest.raises(SetupError, match="configure_timing"):
            task.start()


def test_int24_codec_round_trip_and_sign():
    vals = np.array([-(2**23) + 1, -1, 0, 1, 2**23 - 1, 123456, -654321])
    assert p.unpack_int24(p.pack_int24(vals)).tolist() == vals.tolist()
    x = p.int24_to_float(p.pack_int24(vals.reshape(-1, 1)), 1, np.array([0.5]))
    np.testing.assert_array_equal(x[:, 0], vals * 0.5)
