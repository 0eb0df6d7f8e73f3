"""The same behavioural tests against the simulator on the pyserial URL handler and on a real pty."""

import contextlib
import os

import numpy as np
import pytest
import serial
from _digitizer_support import SCRIPT, make_device, pty_backend, url_backend

from dimacq.errors import DeviceNotFoundError, DeviceStateError, ProtocolError

pytestmark = pytest.mark.usefixtures("no_thread_leaks")


@contextlib.contextmanager
def backend(kind, **env):
    device = make_device(seed=3, **env)
    if kind == "url":
        with url_backend(device) as (_, driver):
            yield device, driver
    else:
        with pty_backend(device) as (_, driver):
            yield device, driver


BACKENDS = ["url", pytest.param("pty", marks=pytest.mark.skipif(os.name != "posix", reason="pty"))]


@pytest.mark.parametrize("kind", BACKENDS)
def test_identify_configure_fire(kind):
    with backend(kind) as (_, d):
        assert d.identify().serial == "SIM-T"
        d.reset()
        s = d.configure(averaging=2, bar_repeats=3)
        assert (s.emitters, s.microphones, s.averaging, s.bar_repeats) == (2, 4, 2, 3)
        a, b = d.fire(), d.fire()
        assert (a.seq, b.seq) == (0, 1)
        assert a.counts.shape == (2, 4) and a.bar_counts.shape == (3,) and a.averaging == 2
        # bar at 1 m, 20 degC, clock 10 MHz, tau_0 = 500 counts: n = 500 + 1/343.21 s * 1e7
        assert abs(np.median(a.bar_counts) - (500 + 1e7 / 343.2146)) < 3


@pytest.mark.parametrize("kind", BACKENDS)
def test_stream_and_errors(kind):
    with backend(kind) as (_, d):
        recs = list(d.stream(25))
        assert [r.seq for r in recs] == list(range(25))
        with pytest.raises(ProtocolError, match="unknown command"):
            d.command("BOGUS")
        with pytest.raises(ProtocolError, match="error 2"):
            d.command("CFG M=9", expect="CFG")
        assert d.fire().seq == 25


@pytest.mark.parametrize("kind", BACKENDS)
@pytest.mark.parametrize("fault", ["garbage", "truncate", "checksum"])
def test_link_faults(kind, fault):
    with backend(kind) as (device, d):
        device.corrupt_next(fault)
        if fault == "checksum":
            with pytest.raises(ProtocolError, match="'checksum'"):
                d.fire()
        else:
            assert d.fire().seq == 0
        assert d.fire().seq == 1  # the damaged reply consumed seq 0 in every case
        assert d.stats.garbage_bytes + d.stats.truncated_lines + d.stats.bad_lines > 0


def test_script_bytes_identical_on_pty(no_thread_leaks):
    """The scripted exchanges of the driver tests are exactly what the pty simulator sends."""
    with pty_backend(make_device(seed=0)) as (server, d):
        d.close()
        port = serial.serial_for_url(server.path, baudrate=115200, timeout=1.0)
        try:
            for sent, answered in SCRIPT:
                port.write(sent)
                assert port.read_until(b"\n") == answered
        finally:
            port.close()


def test_url_port_vanishes_and_reconnects(no_thread_leaks):
    with backend("url") as (device, d):
        assert d.fire().seq == 0
        device.unplug()
        with pytest.raises(DeviceNotFoundError, match="vanished"):
            d.fire()
        with pytest.raises(DeviceNotFoundError, match="reconnect failed"):
            d.reconnect(attempts=2, delay_s=0.0)
        device.plug()
        d.reconnect(attempts=1)
        assert d.fire().seq == 1  # the device kept its sequence: nothing lost


def test_pty_port_vanishes(no_thread_leaks):
    device = make_device()
    with pty_backend(device) as (server, d):
        assert d.fire().seq == 0
        server.stop()
        with pytest.raises(DeviceNotFoundError, match="vanished"):
            for _ in range(3):
                d.fire()


def test_streaming_device_is_busy(no_thread_leaks):
    device = make_device()
    device.shot_rate_hz = 200.0
    with url_backend(device) as (_, d):
        it = d.stream(3)
        assert next(it).seq == 0
        d._send(b"SHOT\r")  # another command while the device is still streaming
        with pytest.raises(DeviceStateError, match="busy"):
            list(it)
