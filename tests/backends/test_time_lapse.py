"""The simulated lab's time-lapse: the factor chosen at start (setting, or measured on this host),
whether the host kept up (from the devices' reports), the real-time path (factor 1) and the
virtual CAN bus's burst send that makes high factors affordable."""

from __future__ import annotations

import math
import time
from pathlib import Path
from typing import Any

import can
import numpy as np
import pytest

from dimacq.backends import time_lapse as tl
from dimacq.backends.time_lapse import HostLag, HostMeasurement, choose_time_lapse
from dimacq.config import load_settings
from dimacq.errors import SetupError
from dimacq.services.acquisition.rig import build_rig, run_impact_test
from dimacq.simulators.lab.scenarios import build_scenario
from dimacq.simulators.virtual_can import SimVirtualBus

RIG = {"n_channels": 25, "n_cells": 1, "sample_rate_hz": 2048.0}


def test_the_setting_wins_and_is_checked() -> None:
    got = choose_time_lapse({"daq_time_scale": 7}, **RIG)
    assert (got.scale, got.how, got.measurement) == (7.0, "setting", None)
    assert "7x real time" in got.describe() and "setting" in got.describe()
    for bad in (0, -2, "fast", True):
        with pytest.raises(SetupError, match=r"daq_time_scale = .*give a positive factor"):
            choose_time_lapse({"daq_time_scale": bad}, **RIG)
    # no time-lapse where the DAQ does not free-run
    assert choose_time_lapse({"enabled": False}, **RIG).how == "host-paced"
    assert choose_time_lapse({"daq_free_running": False}, **RIG).scale == 1.0


@pytest.mark.parametrize(
    ("wall_per_sim_s", "expected"),
    [
        (0.001, 40.0),  # 1 / (6 · 1 ms) = 167x sustainable: capped at max_scale
        (0.004, 20.0),  # 41.7x sustainable, half of it taken, whole factor: 20x
        (0.05, 1.0),  # 3.3x sustainable: 1.67 → 1 (never below real time)
    ],
)
def test_measured_factor_is_half_of_what_the_host_sustains(
    monkeypatch: pytest.MonkeyPatch, wall_per_sim_s: float, expected: float
) -> None:
    m = HostMeasurement(wall_per_sim_s, wall_per_sim_s, 0.5)
    monkeypatch.setattr(tl, "measure_host", lambda *a, **k: m)
    got = choose_time_lapse({}, **RIG)
    sustainable = 1 / (tl.FULL_OVER_PROBE * wall_per_sim_s)
    assert got.how == "measured" and got.scale == expected
    assert got.scale == min(40.0, max(1.0, math.floor(tl.HEADROOM * sustainable)))
    assert got.to_json()["sustainable_scale"] == pytest.approx(sustainable)
    assert "measured at start" in got.describe()


def test_the_probe_does_the_wire_work_of_the_rig() -> None:
    one = tl.measure_host(25, 0, 2048.0, probe_s=0.25)
    more = tl.measure_host(25, 3, 2048.0, probe_s=0.25)
    assert one.probe_sim_s >= 0.25 and one.wall_per_sim_s > 0 and one.cpu_per_sim_s > 0
    # three cells' CAN frames are work on top of the DAQ's frames (CPU: the load of the machine
    # does not enter; a factor 1.2 leaves the timer's noise room)
    assert more.cpu_per_sim_s > 1.2 * one.cpu_per_sim_s
    with pytest.raises(SetupError, match="give at least one channel"):
        tl.measure_host(0, 1, 2048.0)


def test_host_lag_from_events_and_from_the_reasons() -> None:
    lag = HostLag()
    lag.observe({"device": "loadcell0", "kind": "gap", "n_samples": 1})  # the bus's own loss
    lag.observe({"device": "daq", "kind": "stall", "n_samples": 0})
    assert lag.kept_up and "kept up" in lag.describe()
    lag.observe({"device": "daq", "kind": "overflow", "n_samples": 512})
    assert not lag.kept_up and lag.overflow_samples == 512
    assert "did NOT keep up" in lag.describe() and "daq_time_scale" in lag.describe()
    lag = HostLag()
    lag.observe({"device": "loadcell1", "kind": "gap", "n_samples": 300})  # frames dropped
    assert not lag.kept_up and lag.to_json()["loadcell_gap_samples"] == [300]
    # the API's words: rejected averages and lost strikes
    lag = HostLag()
    lag.observe_reasons(["double hit", "load cell 0 samples lost (1)"])
    assert lag.kept_up
    lag.observe_reasons(["DAQ samples lost (1280: FIFO overflow); load cell 0 samples lost (817)"])
    lag.observe_reasons(["DAQ samples lost (FIFO overflow)"])
    assert not lag.kept_up
    assert (lag.overflow_events, lag.overflow_samples, lag.loadcell_gaps) == (2, 1280, [1, 817])


def test_send_frames_gives_each_receiver_what_send_gives() -> None:
    name = f"time-lapse-test-{time.monotonic_ns()}"
    tx = SimVirtualBus(channel=name, fd=True)
    rx = [can.Bus(interface="virtual", channel=name, fd=True) for _ in range(2)]
    try:
        frames = [(0x181, bytes(range(k, k + 48)), True) for k in range(5)]
        frames.insert(3, (0x701, bytes(8), False))
        tx.send_frames(frames)
        for aid, data, fd in frames:
            tx.send(can.Message(arbitration_id=aid, data=data, is_extended_id=False, is_fd=fd))
        for bus in rx:
            got = [bus.recv(1.0) for _ in range(2 * len(frames))]
            assert bus.recv(0.0) is None
            burst, single = got[: len(frames)], got[len(frames) :]
            for a, b in zip(burst, single, strict=True):
                assert a is not None and b is not None and a is not b
                assert a.equals(b, timestamp_delta=1.0, check_channel=True, check_direction=True)
                assert a.dlc == len(a.data) and isinstance(a.data, bytearray)
            assert [m.arbitration_id for m in burst] == [f[0] for f in frames]
        burst[0].data[0] = 0xFF  # each receiver its own copy
        assert frames[0][1][0] == 0
    finally:
        for bus in rx:
            bus.shutdown()
        tx.shutdown()


def test_send_frames_to_a_full_bounded_queue_fails_as_send_does() -> None:
    name = f"time-lapse-full-{time.monotonic_ns()}"
    tx = SimVirtualBus(channel=name, fd=True)
    rx = can.Bus(interface="virtual", channel=name, fd=True, rx_queue_size=3)
    try:
        with pytest.raises(can.CanOperationError, match="Could not send"):
            tx.send_frames([(0x181, bytes(48), True)] * 4)
        assert rx.queue.qsize() == 3  # as many as fitted, in order
    finally:
        rx.shutdown()
        tx.shutdown()


def test_real_time_path(tmp_path: Path) -> None:
    """The DAQ at time scale 1 (a real DAQ's pace): one input, one average through the rig
    builder; the host keeps up, nothing is lost, and the run took at least the record's real
    duration (the factor was applied)."""
    # (the test session's environment turns the imperfections off: on again, at real time)
    imperfections = {"enabled": True, "daq_time_scale": 1}
    settings = load_settings(data_dir=tmp_path, token="t", simulation_imperfections=imperfections)
    assert choose_time_lapse(settings.simulation_imperfections, **RIG).scale == 1.0
    full = build_scenario(settings.scenario).model.setup
    setup = full.model_copy(update={"excitations": full.excitations[:1]})
    cfg = {"seed": 3, "averages_per_input": 1, "min_averages": 1, "record_samples": 2048}
    lag = HostLag()
    accepted: list[bool] = []

    def on_average(j: int, k: int, ok: bool, reasons: Any, blocks: Any) -> None:
        accepted.append(ok)

    rig = build_rig(settings, setup, cfg)
    try:
        assert rig.daq.sample_rate_hz == 2048.0
        t0 = time.monotonic()
        frf = run_impact_test(
            rig,
            setup,
            cfg,
            on_average=on_average,
            on_progress=lambda f, m: None,
            on_event=lag.observe,
        )
        wall = time.monotonic() - t0
    finally:
        rig.close()
    assert lag.kept_up, lag.describe()
    assert np.isfinite(frf.H).all() and frf.H.shape[2] == 1 and accepted[-1]
    assert wall >= 2048 / 2048.0  # one record of real time, at least


def test_the_load_cell_backend_counts_in_the_probe(monkeypatch: pytest.MonkeyPatch) -> None:
    """A backend of several CAN frames per sample is probed with as many (the probe that saw one
    chose 25x for netft-can, which the host could not sustain at 8x); RDT's simulator is capped
    (the host's clock is its coarse time base)."""
    from dimacq.config import default_config_file

    seen: list[int] = []

    def fake(n_channels: int, n_cells: int, rate: float) -> HostMeasurement:
        seen.append(n_cells)
        return HostMeasurement(0.001, 0.001, 0.5)  # 167x sustainable

    monkeypatch.setattr(tl, "measure_host", fake)
    rig = default_config_file().parent / "rig.toml"
    assert tl.rig_time_lapse({}, rig).scale == 40.0
    assert tl.rig_time_lapse({}, rig, "netft-can-simulated").scale == 40.0
    assert tl.rig_time_lapse({}, rig, "cia404-simulated").scale == 40.0
    assert seen == [1, 5, 7]  # the shipped rig's one cell, in frames per sample
    assert tl.rig_time_lapse({}, rig, "netft-udp-simulated").scale == 2.0
    assert tl.rig_time_lapse({"daq_time_scale": 6}, rig, "netft-udp-simulated").scale == 6.0
    # the USB-1808X twin's 32 KiB FIFO: at most 2x
    assert tl.rig_time_lapse({}, rig, "simulated", "mcc-usb-simulated").scale == 2.0
