"""DAQ driver against scripted USB exchanges (the bytes sent and answered are listed)."""

from __future__ import annotations

import errno

import numpy as np
import pytest
import usb.core

from dimacq.drivers.daq import protocol as p
from dimacq.drivers.daq.driver import DaqDevice, DaqTask
from dimacq.errors import DeviceStateError, DeviceTimeoutError, ProtocolError, SetupError

IDENT = p.DeviceIdentity(1, 4, 51200, 24, 5, "SN42", "fw1").encode()


def status(rate=2048.0, running=False):
    return p.DeviceStatus(running, False, rate, 0, 0).encode()


class _Ctx:
    def dispose(self, device):
        return None


class ScriptedUsb:
    """A stand-in for usb.core.Device that plays a script; leftover steps fail the test."""

    def __init__(self, script):
        self.script = list(script)
        self._ctx = _Ctx()

    def set_configuration(self):
        return None

    def _next(self, kind, args):
        assert self.script, f"unexpected {kind}{args}: the script is finished"
        exp_kind, exp_args, answer = self.script.pop(0)
        assert (kind, args) == (exp_kind, exp_args)
        if isinstance(answer, Exception):
            raise answer
        return answer

    def ctrl_transfer(self, bm, req, value, index, data, timeout):
        payload = data if isinstance(data, int) else bytes(data)
        return self._next("ctrl", (bm, req, value, index, payload))

    def read(self, ep, size, timeout):
        return self._next("read", (ep, size))

    def assert_done(self):
        assert not self.script, f"script steps left: {self.script}"


def IN(req, n, answer):
    return ("ctrl", (p.BM_REQUEST_IN, req, 0, 0, n), answer)


def OUT(req, value=0, index=0, data=b""):
    return ("ctrl", (p.BM_REQUEST_OUT, req, value, index, data), 0)


def test_identify_exchange():
    usb_dev = ScriptedUsb([IN(p.Request.IDENTIFY, p.IDENTIFY_STRUCT.size, IDENT)])
    ident = DaqDevice(usb_dev).identify()
    assert (ident.n_channels, ident.serial_number, ident.firmware) == (4, "SN42", "fw1")
    usb_dev.assert_done()


def start_script(spf=4):
    R = p.Request
    return [
        IN(R.IDENTIFY, p.IDENTIFY_STRUCT.size, IDENT),
        OUT(R.SET_SAMPLE_RATE, data=(2048).to_bytes(4, "little")),
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
        OUT(R.START, spf),
    ]


def make_task(script):
    usb_dev = ScriptedUsb(start_script() + script)
    task = DaqTask(DaqDevice(usb_dev))
    task.add_voltage_channel(3, "aux")
    task.add_accel_channel(1, "1103+Y", 100.0)
    task.configure_timing(2048, samples_per_frame=4)
    task.start()
    return usb_dev, task


def frame(seq, first, counts, **kw):
    return p.encode_frame(seq, first, np.asarray(counts), **kw)


FRAME_4x2 = p.frame_size(4, 2)


def read(answer, size=FRAME_4x2):
    return ("read", (p.DATA_ENDPOINT, size), answer)


def test_start_exchange_and_engineering_units():
    counts = np.array([[2**22, 0], [-(2**22), 2**22], [0, 0], [1, -1]])
    usb_dev, task = make_task([read(frame(0, 0, counts)), OUT(p.Request.STOP)])
    block = task.read(4)
    task.stop()
    usb_dev.assert_done()
    assert task.channel_names == ("1103+Y", "aux")  # ascending physical channel
    # 2^22 counts on ±5 V = 2.5 V; at 100 mV/g that is 25 g
    assert block.data[0, 0] == pytest.approx(25 * 9.80665, rel=1e-12)
    assert block.data[1, 1] == pytest.approx(5.0, rel=1e-12)  # ±10 V voltage channel
    assert block.data[0, 3] == pytest.approx(5 / 2**23 / 0.1 * 9.80665, rel=1e-12)


def test_overflow_gap_is_nan_filled_and_reported():
    c = np.ones((4, 2), dtype=int)
    usb_dev, task = make_task(
        [read(frame(0, 0, c)), read(frame(1, 8, 2 * c, flags=p.FrameFlags.OVERFLOW))]
    )
    block = task.read(12)
    usb_dev.assert_done()
    assert [(e.kind, e.first_sample, e.n_samples) for e in block.events] == [("overflow", 4, 4)]
    assert (
        np.isnan(block.data[:, 4:8]).all() and block.valid.tolist() == [1] * 4 + [0] * 4 + [1] * 4
    )


def test_lost_transfer_is_reported():
    c = np.ones((4, 2), dtype=int)
    _usb_dev, task = make_task([read(frame(0, 0, c)), read(frame(2, 8, c))])
    block = task.read(12)
    assert [(e.kind, e.first_sample) for e in block.events] == [("lost_transfer", 4)]


def test_overload_event_names_the_channel():
    c = np.zeros((4, 2), dtype=int)
    _usb_dev, task = make_task([read(frame(0, 0, c, overload_mask=0b10))])
    block = task.read(4)
    (ev,) = block.events
    assert ev.kind == "overload" and ev.channels == ("aux",)
    assert block.overload[1].all() and not block.overload[0].any()


def test_timeout_keeps_received_samples():
    c = np.arange(8).reshape(4, 2)
    timeout = usb.core.USBTimeoutError("Operation timed out", error_code=-7, errno=110)
    usb_dev, task = make_task([read(frame(0, 0, c)), read(timeout), read(frame(1, 4, c + 100))])
    with pytest.raises(DeviceTimeoutError, match="4 samples received and kept"):
        task.read(8)
    block = task.read(8)
    usb_dev.assert_done()
    assert block.first_sample == 0
    np.testing.assert_array_equal(block.data[1] * 2**23 / 10, [1, 3, 5, 7, 101, 103, 105, 107])
    assert [e.kind for e in task.events] == ["timeout"]


def test_corrupt_frame_and_backwards_counter_are_protocol_errors():
    c = np.ones((4, 2), dtype=int)
    bad = bytearray(frame(0, 0, c))
    bad[-1] ^= 0xFF
    _, task = make_task([read(bytes(bad))])
    with pytest.raises(ProtocolError, match="CRC"):
        task.read(4)
    _usb_dev, task = make_task([read(frame(0, 4, c)), read(frame(1, 2, c))])
    with pytest.raises(ProtocolError, match="backwards"):
        task.read(12)


def test_stall_becomes_device_state_error():
    stall = usb.core.USBError("Pipe error", error_code=-9, errno=errno.EPIPE)
    usb_dev = ScriptedUsb([("ctrl", (p.BM_REQUEST_OUT, p.Request.SET_IEPE, 2000, 70, b""), stall)])
    with pytest.raises(DeviceStateError, match="SET_IEPE"):
        DaqDevice(usb_dev).set_iepe(70, 2000)


def test_bad_channel_setup_is_refused():
    task = DaqTask(DaqDevice(ScriptedUsb([])))
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
