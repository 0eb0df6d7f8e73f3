"""A host whose receive thread falls behind: a CAN simulator (the CANopen amplifier, the
Net F/T, the CiA 404 SYNC producer) stops sending (its clock slips, its pulses wait, an
adaptive DAQ clock waits with them) while the host's queue holds more than
:data:`RX_BACKLOG_FRAMES` frames, so the answer to the host's next request is not queued
behind seconds of frames; nothing is lost, the sample counters stay contiguous when the host
reads again."""

from __future__ import annotations

import time

import can
import numpy as np
from _acq_support import ImpulseSource

from dimacq.config import Settings
from dimacq.drivers.canopen_loadcell import protocol as p
from dimacq.simulators.canopen_loadcell import amplifier
from dimacq.simulators.canopen_loadcell.amplifier import CanopenAmplifierSim
from dimacq.simulators.virtual_can import RX_BACKLOG_FRAMES

EDS = Settings().loadcell_canopen_eds_path
NODE = 4


def _held_backlog(host: can.BusABC, most: int) -> int:
    """Wait (up to 60 s: a slow host) until the simulator has filled the host's queue past
    the limit, give it 0.5 s more to overshoot, and return what the queue holds then."""
    deadline = time.monotonic() + 60.0
    while host.queue.qsize() <= RX_BACKLOG_FRAMES and time.monotonic() < deadline:
        time.sleep(0.05)
    time.sleep(0.5)
    queued = int(host.queue.qsize())
    assert RX_BACKLOG_FRAMES < queued <= most, (queued, most)
    return queued


def test_the_stream_waits_for_a_host_that_does_not_read(request) -> None:
    name = f"rx-{request.node.name}"
    src = ImpulseSource(n_gauges=12, background=0.3)
    g0 = src.n_inputs + src.n_responses
    # 2048 S/s at 40x: 490 000 frames a wall second if nothing held it back
    sim = CanopenAmplifierSim(name, EDS, src, range(g0, g0 + 12), node_id=NODE, time_scale=40)
    with sim:
        layout = sim.layout  # decoding only: the mapping in the node's dictionary
        sim.node.sdo[p.CLOCK_SOURCE].raw = 0  # its own oscillator (set locally, as a bench is)
        host = can.Bus(interface="virtual", channel=name)
        try:
            host.send(can.Message(arbitration_id=0, data=[0x01, NODE], is_extended_id=False))
            # the host's receive thread takes nothing: at most one burst past the limit
            # (a chunk of pulses x 6 TPDOs, and a heartbeat or two)
            _held_backlog(host, RX_BACKLOG_FRAMES + amplifier._CHUNK * 6 + 16)
            got: list[can.Message] = []
            first, n_first = layout.tpdos[0].cob_id, 0
            deadline = time.monotonic() + 60.0
            # the host reads again: the stream goes on past what was held
            while n_first <= 2 * RX_BACKLOG_FRAMES // 6 and time.monotonic() < deadline:
                m = host.recv(0.05)
                if m is not None:
                    got.append(m)
                    n_first += m.arbitration_id == first
        finally:
            host.send(can.Message(arbitration_id=0, data=[0x80, NODE], is_extended_id=False))
            host.shutdown()
    low, _g, _v = layout.decode(0, [bytes(m.data) for m in got if m.arbitration_id == first])
    c = np.unwrap(low, period=2**16)  # the 16-bit low words of the sample counter
    assert len(c) > 2 * RX_BACKLOG_FRAMES // 6, len(c)  # it went on past the held backlog
    np.testing.assert_array_equal(np.diff(c), 1)  # nothing skipped while it waited


def test_the_netft_requests_wait_for_a_host_that_does_not_read(request) -> None:
    """The same rule for the Net F/T on the DAQ's pulses: the pulses not yet requested wait
    (none skipped) while the host holds more than the limit."""
    from dimacq.drivers.netft import protocol as nft
    from dimacq.simulators.daq.clock import SampleClock
    from dimacq.simulators.netft import can_sensor
    from dimacq.simulators.netft.can_sensor import NetFtCanSim

    src = ImpulseSource(n_gauges=12, background=0.3)
    g0 = src.n_inputs + src.n_responses
    name = f"rx-netft-{request.node.name}"
    clock = SampleClock()
    cal = nft.CalibrationInfo(2, 3, 1_000_000, 500_000)
    with NetFtCanSim(name, src, range(g0, g0 + 12), np.eye(6, 12), cal, clock=clock) as sim:
        host = can.Bus(interface="virtual", channel=name)
        try:
            clock.start(0, 2048.0, wall_scale=40.0)  # 82 000 pulses a wall second
            # at most one chunk past the limit: its pulses x (request + 4 answers)
            _held_backlog(host, RX_BACKLOG_FRAMES + can_sensor._CHUNK * 5)
            requested = sim._sent
            while host.recv(0.0) is not None:
                pass
            deadline = time.monotonic() + 60.0
            while sim._sent == requested and time.monotonic() < deadline:
                time.sleep(0.05)
            assert sim._sent > requested  # it goes on once the host has read
        finally:
            clock.stop()
            host.shutdown()


def test_an_adaptive_daq_clock_waits_with_the_cia404_sync_producer(request) -> None:
    """The CiA 404 SYNC producer on an adaptive DAQ clock: while the host holds more than the
    limit, the clock counts no further than the last SYNC sent (it waits, slower from then
    on); once the host reads again, the SYNCs and the clock go on, none skipped."""
    from dimacq.simulators.cia404 import node as cia
    from dimacq.simulators.daq.clock import SampleClock

    name = f"rx-cia404-{request.node.name}"
    clock = SampleClock()
    with cia.SyncProducerSim(name, clock, []) as prod:
        host = can.Bus(interface="virtual", channel=name)
        try:
            clock.start(0, 1000.0, wall_scale=400.0, adaptive=True)  # 400 000 SYNCs a wall second
            # at most one chunk of SYNCs past the limit
            _held_backlog(host, RX_BACKLOG_FRAMES + cia._CHUNK)
            held = prod.sent
            time.sleep(1.5)  # without the hold the clock would count 600 000 more
            assert prod.sent == held
            assert clock.count() <= held + cia._MAX_BACKLOG, (clock.count(), held)
            got = 0
            deadline = time.monotonic() + 60.0
            while got <= 3 * RX_BACKLOG_FRAMES and time.monotonic() < deadline:
                got += host.recv(0.05) is not None
            assert got > 3 * RX_BACKLOG_FRAMES  # it went on once the host read
        finally:
            clock.stop()
            host.shutdown()
    report = clock.run_report()
    assert report is not None and report.waits > 0
    assert min(report.factors) < 400.0  # the clock slowed down for the host
