"""An impact test with the load cell on CANopen, under faults: TPDO frames lost in the first
record, an EMCY inside the fourth, the heartbeat lost mid-run. Each is reported naming the node, the acquisition goes
on, the averages that hold a faulty sample are rejected, and the accepted ones give the closed-form
FRFs (nothing accepted is lost or wrong)."""

from __future__ import annotations

import can
import numpy as np
import pytest
from _acq_support import ImpulseSource, no_leaks

from dimacq.config import Settings
from dimacq.drivers.canopen_loadcell import protocol as p
from dimacq.drivers.canopen_loadcell.driver import CanopenLoadCell
from dimacq.drivers.daq.driver import DaqDevice, DaqTask
from dimacq.services.acquisition.session import ImpactSession, ImpactSettings
from dimacq.simulators.canopen_loadcell.amplifier import CanopenAmplifierSim, CanopenFaults
from dimacq.simulators.daq.backend import DaqInput, VirtualDaqBackend
from dimacq.simulators.daq.clock import SampleClock

__all__ = ["no_leaks"]

G = 9.80665
NODE = 12


@pytest.mark.slow
def test_faults_are_reported_survived_and_nothing_accepted_is_lost(no_leaks) -> None:
    src = ImpulseSource(n_inputs=2, n_responses=3, n_gauges=12, response_gain=0.01)
    clock = SampleClock()
    name = "canopen-acq-faults"
    g0 = src.n_inputs + src.n_responses
    faults = CanopenFaults(emcy_at={8_000: p.EMCY_HARDWARE}, dropped_frames={1_000, 1_001})
    eds = Settings().loadcell_canopen_eds_path
    wiring = {j: DaqInput(j, 2.25e-3) for j in range(2)}
    wiring.update({2 + k: DaqInput(2 + k, 0.1 / G) for k in range(3)})
    with CanopenAmplifierSim(
        name, eds, src, range(g0, g0 + 12), clock=clock, node_id=NODE, faults=faults
    ) as sim:
        bus = can.Bus(interface="virtual", channel=name)
        backend = VirtualDaqBackend(src, wiring, clock=clock)
        dev = DaqDevice.open(backend=backend)
        amp = CanopenLoadCell(bus, node_id=NODE, eds=eds, timeout_s=2.0, heartbeat_ms=100)
        try:
            task = DaqTask(dev)
            for j in range(2):
                task.add_force_channel(j, f"{10 + j}+X force", 2.25, range_v=0.5)
            for k in range(3):
                task.add_accel_channel(2 + k, f"{100 + k}+Z", 100.0)
            task.configure_timing(src.sample_rate_hz, 256)
            amp.identify()
            strikes: list[int] = []

            def operator(j: int, at: int) -> None:
                strikes.append(at)
                if len(strikes) == 2:
                    sim.lose_heartbeat()
                src.excite(j, backend.world_sample(at))

            settings = ImpactSettings(
                record_samples=2048, averages_per_input=2, trigger_level_n=20.0
            )
            session = ImpactSession(
                task,
                ["10+X force", "11+X force"],
                ["100+Z", "101+Z", "102+Z"],
                [amp],
                settings=settings,
                operator=operator,
                loadcell_outputs="gauges",
            )
            res = session.run()
        finally:
            amp.close()
            bus.shutdown()
            dev.close()
    assert res.n_accepted == (2, 2)
    rejected = [a for a in res.averages if not a.accepted]
    assert rejected and all(
        any("load cell 0 samples lost" in r for r in a.reasons) for a in rejected
    ), rejected
    faulty = [1_000, 8_000]
    for a in res.averages:  # an average is rejected exactly when its record holds a faulty sample
        holds = any(a.first_sample <= s < a.first_sample + a.n_samples for s in faulty)
        assert a.accepted == (not holds), a
        if a.first_sample <= 8_000 < a.first_sample + a.n_samples:  # the EMCY's: named in review
            assert any("device error" in r and "EMCY 0x5000" in r for r in a.reasons), a
    messages = [e.message for e in amp.events if e.kind == "device_error"]
    assert any("EMCY 0x5000" in m and f"node {NODE}" in m for m in messages), messages
    assert any("no heartbeat" in m and f"node {NODE}" in m for m in messages), messages
    assert any(e.kind == "gap" and e.first_sample == 1_000 for e in amp.events)
    h_true = src.frf(res.frequencies_hz)
    band = slice(1, None)
    scale = np.abs(h_true).max()
    np.testing.assert_allclose(res.H[band, :3], h_true[band], atol=2e-3 * scale)
    g_true = np.einsum("gr,lri->lgi", src.gauge_mix, h_true)
    np.testing.assert_allclose(res.H[band, 3:], g_true[band], atol=2e-3 * np.abs(g_true).max())
