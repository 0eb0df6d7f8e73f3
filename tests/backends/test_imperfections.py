"""The simulated devices' imperfections (on by default) and the drivers and sessions that survive
them: USB re-enumeration, CAN bus-off and frame loss, serial line noise and port loss."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
from _digitizer_support import make_device, url_backend

from dimacq.config import load_settings
from dimacq.errors import SetupError
from dimacq.services.acquisition.rig import build_rig, run_impact_test
from dimacq.services.geometry.digitizer_config import load_array_config
from dimacq.services.geometry.digitizing import DigitizingSession
from dimacq.simulators.imperfections import DEFAULT, NONE, Imperfections
from dimacq.simulators.lab.scenarios import build_scenario


def test_defaults_are_on_and_the_setting_is_checked() -> None:
    assert DEFAULT.enabled and DEFAULT.daq_free_running and DEFAULT.daq_stale_frames
    assert DEFAULT.loadcell_oscillator_ppm == 50.0 and DEFAULT.daq_fifo_bytes > 0
    assert Imperfections.from_mapping({}) == DEFAULT
    assert Imperfections.from_mapping({"enabled": False}) == NONE
    got = Imperfections.from_mapping({"can_bus_off_rate": 0.5})
    assert got.can_bus_off_rate == 0.5 and got.daq_free_running
    with pytest.raises(SetupError, match=r"unknown key\(s\) \['can_bus_of_rate'\]"):
        Imperfections.from_mapping({"can_bus_of_rate": 0.5})
    with pytest.raises(SetupError, match=r"daq_stall_rate = 2.*give 0 \.\. 1"):
        Imperfections.from_mapping({"daq_stall_rate": 2})
    with pytest.raises(SetupError, match=r"daq_stall_s = nan"):
        Imperfections.from_mapping({"daq_stall_s": float("nan")})


@pytest.mark.slow
def test_impact_test_survives_re_enumeration_bus_off_and_frame_loss(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """Through the rig builder on the simulated lab with faults turned up: the DAQ drops off
    the bus (the run restarts), the amplifier goes bus-off and loses frames (gaps: averages
    rejected and struck again). Every average handed over as accepted is in the FRFs, and every
    fault injected is reported, to the log and as the session's events (the service's device
    state: the DAQ lost, then found again). The faults fall where the seed puts them in the
    stream (re-enumerations per read, bus-offs and frame losses per pulse streamed), not where
    the threads' timing on a loaded machine would: 3 re-enumerations and 4 bus-offs each run."""
    imperfections = {
        "daq_time_scale": 6.0,
        "daq_reenumerate_rate": 0.015,
        "daq_reenumerate_s": 0.1,
        "can_bus_off_rate": 0.15,
        "can_bus_off_s": 0.02,
        "can_frame_loss_rate": 3e-5,
    }
    settings = load_settings(data_dir=tmp_path, token="t", simulation_imperfections=imperfections)
    full = build_scenario(settings.scenario).model.setup
    setup = full.model_copy(update={"excitations": full.excitations[:2]})
    accepted: list[tuple[int, int]] = []

    def on_average(j: int, k: int, ok: bool, reasons: Any, blocks: Any) -> None:
        if ok:
            accepted.append((j, k))

    cfg = {"seed": 7, "averages_per_input": 2, "min_averages": 2, "max_attempts_factor": 5}
    events: list[dict[str, Any]] = []
    rig = build_rig(settings, setup, cfg)
    try:
        with caplog.at_level("WARNING"):
            frf = run_impact_test(
                rig,
                setup,
                cfg,
                on_average=on_average,
                on_progress=lambda f, m: None,
                on_event=events.append,
            )
    finally:
        rig.close()
    assert frf.H.shape[2] == 2 and np.isfinite(frf.H).all()
    assert len(accepted) == 4  # 2 per input: none lost by the restarts
    text = caplog.text
    injected = {
        kind: text.count(f"simulated fault {kind}:")
        for kind in ("usb_reenumeration", "can_bus_off", "can_frame_loss")
    }
    assert injected["usb_reenumeration"] >= 1 and injected["can_bus_off"] >= 1
    assert text.count("run restarted") == injected["usb_reenumeration"]
    assert "lost on the CAN bus" in text
    lost_found = [e["kind"] for e in events if e["kind"] in ("restart", "reconnected")]
    assert lost_found == ["restart", "reconnected"] * injected["usb_reenumeration"], lost_found


@pytest.mark.slow
def test_digitizing_survives_line_noise_and_port_loss() -> None:
    """Damaged reply lines are read again (a command) or fired again (a shot); a port that
    drops off is reopened; every point is kept. The session tells the service's device state
    each loss and each reopening (``on_device``). (Seeded: 11 noisy lines, 6 port losses.)"""
    cfg = load_array_config()
    device = make_device(seed=4)
    device.set_imperfections(noise_rate=0.2, port_loss_rate=0.1, port_loss_s=0.05)
    with url_backend(device) as (_, d):
        s = DigitizingSession(d, cfg.geometry(), cfg.limits(), max_reconnects=10)
        seen: list[str] = []
        s.on_device = seen.append
        for i in range(6):
            tip = (0.05 * i, 0.0, 1.0)
            d.command("SIM:PROBE " + ",".join(f"{v:.6f}" for v in (*tip, 0.1, -0.1, 1.0)))
            s.digitize(f"P{i}")
    assert [p.label for p in s.points] == [f"P{i}" for i in range(6)]
    assert device.injected.get("serial_noise", 0) >= 3
    assert device.injected.get("serial_port_loss", 0) >= 1
    assert d.stats.reconnects >= device.injected["serial_port_loss"]
    # each loss the session met: "port lost (...)" then "" once reopened
    assert s.reconnects >= 1 and seen == [seen[0], ""] * s.reconnects, seen
    assert all(x.startswith("port lost (") for x in seen[::2]), seen


def test_unseeded_worlds_do_not_replay_one_frame_loss() -> None:
    """CAN frame losses at 1e-6 per frame: seed 0's stream (what every unseeded world used) loses
    node 1's frame 3705, about 1.8 s after START at 2048 Hz, so the first strike of every
    unseeded acquisition came back "load cell 0 samples lost (1)". An unseeded world draws its
    own bus seed; a seeded one keeps its seed (runs replayable)."""
    from dimacq.backends.simulated import SimulatedWorld
    from dimacq.io.rig_file import load_rig_file

    first_loss = np.flatnonzero(np.random.default_rng([0, 1]).random(10_000) < 1e-6)
    assert first_loss.tolist() == [3705]  # the replayed loss
    rig = load_rig_file(Path(__file__).resolve().parents[2] / "config" / "rig.toml")
    worlds = [SimulatedWorld("calibration-mass-bungee", rig, seed) for seed in (None, None, 7, 7)]
    try:
        seeds = [[s.faults.seed for s in w._sims] for w in worlds]
        assert all(seeds) and all(len(set(x)) == 1 for x in seeds), seeds
        assert seeds[0] != seeds[1]  # unseeded: each world its own losses
        assert seeds[2] == seeds[3] == [7] * len(seeds[2])  # seeded: replayable
    finally:
        for w in worlds:
            w.close()
