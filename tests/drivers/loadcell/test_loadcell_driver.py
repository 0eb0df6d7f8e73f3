"""Load cell driver against scripted CAN exchanges on python-can's virtual bus.

The peer queues its answers first, the driver runs, then the frames the driver sent are
compared with the script; leftover or missing frames fail the test.
"""

from __future__ import annotations

import zlib

import can
import numpy as np
import pytest

from dimacq.drivers.loadcell import protocol as p
from dimacq.drivers.loadcell.driver import LoadCellAmplifier
from dimacq.errors import DeviceStateError, DeviceTimeoutError, ProtocolError, SetupError

NODE = 3
CMD, RSP, DATA, HB = p.command_id(NODE), p.response_id(NODE), p.data_id(NODE), p.heartbeat_id(NODE)


class Peer:
    def __init__(self, name):
        self.drv_bus = can.Bus(interface="virtual", channel=name, fd=True)
        self.bus = can.Bus(interface="virtual", channel=name, fd=True)

    def answer(self, aid, data, fd=False):
        self.bus.send(can.Message(arbitration_id=aid, data=data, is_extended_id=False, is_fd=fd))

    def sent(self):
        out = []
        while (m := self.bus.recv(0.0)) is not None:
            out.append((m.arbitration_id, bytes(m.data)))
        return out

    def close(self):
        self.drv_bus.shutdown()
        self.bus.shutdown()


@pytest.fixture
def peer(request, no_leaks):
    pr = Peer(f"lc-{request.node.name}")
    yield pr
    pr.close()


def amp(peer, **kw):
    return LoadCellAmplifier(peer.drv_bus, node_id=NODE, timeout_s=0.2, **kw)


def test_identify_rate_start_stop_exchange(peer):
    peer.answer(RSP, bytes([0x81, 12, 2, 7]) + (501).to_bytes(4, "little"))
    peer.answer(RSP, bytes([0x84]) + (2048).to_bytes(4, "little"))
    peer.answer(RSP, bytes([0x82]))
    peer.answer(RSP, bytes([0x83]) + (0).to_bytes(4, "little"))
    a = amp(peer)
    ident = a.identify()
    assert (ident.n_gauges, ident.firmware, ident.serial_number) == (12, "2.7", 501)
    assert a.set_rate(2048) == 2048.0
    a.start()
    assert a.stop() == 0
    assert peer.sent() == [
        (CMD, b"\x01"),
        (CMD, b"\x04" + (2048).to_bytes(4, "little")),
        (CMD, b"\x02\x01"),
        (CMD, b"\x03"),
    ]


def test_calibration_download_and_upload(peer):
    m = np.arange(72, dtype=float).reshape(6, 12) / 7
    blob = p.matrix_to_blob(m)
    peer.answer(RSP, b"\x86")
    peer.answer(RSP, b"\x88")
    amp(peer).download_calibration(m)
    sent = peer.sent()
    segs = p.segments(blob)
    assert sent[0] == (CMD, b"\x06" + (288).to_bytes(2, "little"))
    assert sent[1:-1] == [(CMD, bytes([0x07, i]) + s) for i, s in enumerate(segs)]
    assert sent[-1] == (CMD, b"\x08" + zlib.crc32(blob).to_bytes(4, "little"))
    # upload: header then segments, out of order is fine
    peer.answer(RSP, b"\x89" + (288).to_bytes(2, "little") + zlib.crc32(blob).to_bytes(4, "little"))
    for i in reversed(range(len(segs))):
        peer.answer(RSP, bytes([0x8A, i]) + segs[i])
    np.testing.assert_allclose(amp(peer).upload_calibration(), m, rtol=1e-7)
    assert peer.sent() == [(CMD, b"\x09")]


def test_errors_and_timeout(peer):
    peer.answer(RSP, bytes([0xFF, 0x05, 3]))
    with pytest.raises(DeviceStateError, match="streaming"):
        amp(peer)._command(p.Command.TARE, b"\x00\x01")
    peer.answer(RSP, bytes([0xFF, 0x08, 4]))
    with pytest.raises(ProtocolError, match="CRC"):
        amp(peer)._command(p.Command.CAL_DOWNLOAD_END, bytes(4))
    with pytest.raises(DeviceTimeoutError, match="did not answer"):
        amp(peer).identify()
    with pytest.raises(SetupError, match="6x12"):
        amp(peer, calibration_matrix=np.zeros((6, 11)))


def data_frames(counters, gauges):
    frames, _ = p.encode_data_frames(0, gauges)
    return [
        (int(c) & 0xFFFFFFFF).to_bytes(4, "little") + f[4:]
        for c, f in zip(counters, frames, strict=False)
    ]


def started(peer, **kw):
    peer.answer(RSP, bytes([0x84]) + (1000).to_bytes(4, "little"))
    peer.answer(RSP, b"\x82")
    a = amp(peer, **kw)
    a.set_rate(1000)
    a.start()
    peer.sent()
    return a


def test_stream_gap_is_nan_and_reported_and_matrix_applied(peer):
    C = np.random.default_rng(0).standard_normal((6, 12))
    a = started(peer, calibration_matrix=C)
    g = np.random.default_rng(1).uniform(-5, 5, (10, 12))
    kept = [k for k in range(10) if k not in (4, 5)]
    for f in data_frames(kept, g[kept]):
        peer.answer(DATA, f, fd=True)
    block = a.read_until(8)
    assert block.first_sample == 0 and block.gauges_v.shape == (12, 8)
    assert block.valid.tolist() == [1, 1, 1, 1, 0, 0, 1, 1]
    assert np.isnan(block.gauges_v[:, 4:6]).all()
    np.testing.assert_allclose(block.gauges_v[:, :4], g[:4].T, atol=10 / 2**23)
    np.testing.assert_allclose(block.forces[:, 7], C @ g[7], atol=1e-4)
    assert [(e.kind, e.first_sample, e.n_samples) for e in block.events] == [("gap", 4, 2)]
    rest = a.read_until(10)
    assert rest.first_sample == 8 and rest.valid.all()


def test_counter_wraps_without_a_gap(peer):
    a = started(peer)
    a._stream.next_sample = 2**32 - 2
    a._stream.last_counter = 2**32 - 3
    for f in data_frames([2**32 - 2, 2**32 - 1, 0, 1], np.zeros((4, 12))):
        peer.answer(DATA, f, fd=True)
    block = a.read_until(2**32 + 2)
    assert block.valid.all() and not block.events


def test_heartbeat_drift_is_reported(peer):
    a = started(peer)
    # counter vs the amplifier's own time at 1000 Hz: 3 pulses missed by the second heartbeat
    peer.answer(HB, p.HEARTBEAT.pack(256, 256_000))
    peer.answer(HB, p.HEARTBEAT.pack(512, 515_000))
    for f in data_frames(range(520), np.zeros((520, 12))):
        peer.answer(DATA, f, fd=True)
    block = a.read_until(520)
    drift = [e for e in block.events if e.kind == "drift"]
    assert len(drift) == 1 and "-3.0 samples" in drift[0].message


def test_overload_status_is_reported(peer):
    a = started(peer)
    g = np.zeros((4, 12))
    g[2, 5] = 12.0  # beyond ±10 V
    for f in data_frames(range(4), g):
        peer.answer(DATA, f, fd=True)
    block = a.read_until(4)
    assert block.overload.tolist() == [False, False, True, False]
    assert [e.kind for e in block.events] == ["overload"]


def test_short_data_frame_is_a_protocol_error(peer):
    a = started(peer)
    peer.answer(DATA, bytes(8))
    with pytest.raises(ProtocolError, match="CAN FD"):
        a.read_until(1)
