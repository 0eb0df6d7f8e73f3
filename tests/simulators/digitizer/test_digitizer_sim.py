"""Sonic physics of the virtual lab and the simulated digitizer's transports."""

import subprocess
import sys

import numpy as np
import pytest
import serial
from _digitizer_support import make_device

import dimacq.simulators.digitizer as simdig
from dimacq.simulators.lab.sonic import (
    SonicEnvironment,
    SonicLab,
    SonicProbe,
    default_array,
    speed_of_sound_m_s,
)


def test_speed_of_sound():
    assert speed_of_sound_m_s(0.0) == pytest.approx(331.3)
    # 331.3 * sqrt(293.15 / 273.15)
    assert speed_of_sound_m_s(20.0) == pytest.approx(343.2146, abs=1e-4)


def test_counts_are_quantised_times_of_flight():
    lab = SonicLab(array=default_array(), probe=SonicProbe(0.12, 0.06))
    lab.environment = SonicEnvironment(temperature_c=20.0, timing_noise_s=0.0)
    lab.place_probe(np.array([0.1, -0.2, 1.3]), np.array([0.0, 0.3, 1.0]))
    shot = lab.shot(np.random.default_rng(0), averaging=3, n_bar=2)
    c = 331.3 * np.sqrt(1 + 20 / 273.15)
    u = np.array([0.0, 0.3, 1.0]) / np.linalg.norm([0.0, 0.3, 1.0])
    e1 = np.array([0.1, -0.2, 1.3]) - 0.06 * u
    e2 = e1 - 0.12 * u
    mics = np.array([[-0.5, -0.5, 0], [0.5, -0.5, 0], [0.5, 0.5, 0], [-0.5, 0.5, 0]])
    want = np.floor((50e-6 + np.linalg.norm(np.stack([e1, e2])[:, None] - mics, axis=2) / c) * 1e7)
    np.testing.assert_array_equal(shot.counts, 3 * want)
    np.testing.assert_array_equal(shot.bar_counts, np.floor((50e-6 + 1.0 / c) * 1e7))
    assert not shot.echo and not shot.overflow.any()


def test_echo_is_a_late_arrival_and_far_paths_overflow():
    lab = SonicLab(array=default_array())
    lab.environment = SonicEnvironment(timing_noise_s=0.0, echo_probability=1.0)
    rng = np.random.default_rng(1)
    lab.environment.echo_probability = 0.0
    clean = lab.shot(rng).counts
    lab.environment.echo_probability = 1.0
    echo = lab.shot(rng)
    late = echo.counts - clean
    assert echo.echo and (late >= 0).all()
    n_late = (late > 0).sum()
    assert 1 <= n_late <= 3
    assert late[late > 0].min() >= 0.05 / 343.3 * 1e7 - 1
    lab.place_probe(np.array([0, 0, 7.0]), np.array([0, 0, 1.0]))
    far = lab.shot(rng)
    assert far.overflow.all() and (far.counts == lab.array.counter_max).all()


def test_same_seed_same_bytes():
    a, b = make_device(seed=5), make_device(seed=5)
    for dev in (a, b):
        dev.receive(b"SIM:ECHO 0.5\rSTRM 20\r")
    assert a.poll() == b.poll()
    assert a.echo_seqs == b.echo_seqs and len(a.echo_seqs) > 0


def test_sim_commands_and_bad_arguments():
    dev = make_device()
    dev.receive(b"SIM:PROBE 0.1,0.2,1.1,0,0,1\rSIM:TRUTH?\rSIM:TEMP 99\rSIM:PROBE 1,2\rSTRM 0\r")
    out = dev.poll().split(b"\r\n")
    assert out[0].startswith(b"$OK,SIM:PROBE")
    assert out[1].startswith(b"$SIM,TRUTH,0.100000000,0.200000000,1.100000000,343.21")
    assert all(line.startswith(b"$ERR,2,") for line in out[2:5])


def test_url_handler_options_and_registry():
    url = "simdigitizer://opts?seed=4&echo=0.25&temp=30"
    try:
        port = serial.serial_for_url(url, timeout=0.5)
        dev = simdig.get_device(url)
        assert dev.seed == 4 and dev.lab.environment.echo_probability == 0.25
        assert dev.lab.environment.temperature_c == 30.0
        port.write(b"*IDN?\r")
        assert port.read_until(b"\n").startswith(b"$IDN,DIMACQ,SD-3-SIM,SIM-opts")
        port.close()
    finally:
        simdig.unregister_device("opts")
    with pytest.raises(serial.SerialException, match="unknown option"):
        serial.serial_for_url("simdigitizer://bad?colour=red")


def test_module_runs_on_a_pty():
    proc = subprocess.Popen(
        [sys.executable, "-m", "dimacq.simulators.digitizer", "--pty", "--duration", "20"],
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        text=True,
    )
    try:
        assert proc.stdout is not None
        path = proc.stdout.readline().strip()
        assert path.startswith("/dev/")
        port = serial.serial_for_url(path, baudrate=115200, timeout=2.0)
        try:
            port.write(b"*IDN?\r\n")  # a terminal sends CR LF
            assert port.read_until(b"\n") == b"$IDN,DIMACQ,SD-3-SIM,SIM-PTY,1.0,4*33\r\n"
        finally:
            port.close()
    finally:
        proc.terminate()
        proc.wait(timeout=5)
        if proc.stdout is not None:
            proc.stdout.close()
