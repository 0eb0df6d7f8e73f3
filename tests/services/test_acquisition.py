"""Impact acquisition through the USB DAQ and CAN load cell simulators, with faults.

The virtual lab here is the deterministic test source of ``tests/_acq_support.py`` (impulses
through known resonators), so the FRFs have a closed form.
"""

from __future__ import annotations

import json
import logging

import can
import h5py
import numpy as np
import pytest
from _acq_support import ImpulseSource, no_leaks
from _block_daq import BlockDaq

from dimacq.devices.daq import DaqBlock, DaqEvent
from dimacq.drivers.daq.driver import DaqDevice, DaqTask
from dimacq.drivers.loadcell.driver import LoadCellAmplifier
from dimacq.errors import DataError, DeviceTimeoutError, SetupError
from dimacq.io.acquisition_hdf5 import AcquisitionWriter
from dimacq.services.acquisition.session import ImpactSession, ImpactSettings
from dimacq.simulators.daq.backend import DaqFaults, DaqInput, VirtualDaqBackend
from dimacq.simulators.daq.clock import SampleClock
from dimacq.simulators.loadcell.amplifier import (
    LoadCellAmplifierSim,
    LoadCellFaults,
)

__all__ = ["no_leaks"]

G = 9.80665


@pytest.fixture
def lab(request, no_leaks):
    made = []

    def build(lc_faults=None, free_running=False, daq_faults=None):
        src = ImpulseSource(n_inputs=2, n_responses=3, n_gauges=12, response_gain=0.01)
        clock = SampleClock()
        name = f"acq-{request.node.name}"
        g0 = src.n_inputs + src.n_responses
        sim = LoadCellAmplifierSim(name, src, range(g0, g0 + 12), clock=clock, faults=lc_faults)
        bus = can.Bus(interface="virtual", channel=name, fd=True)
        wiring = {j: DaqInput(j, 2.25e-3) for j in range(2)}
        wiring.update({2 + k: DaqInput(2 + k, 0.1 / G) for k in range(3)})
        backend = VirtualDaqBackend(
            src, wiring, clock=clock, free_running=free_running, faults=daq_faults
        )
        dev = DaqDevice.open(backend=backend)
        made.append((sim, bus, dev))
        task = DaqTask(dev)
        for j in range(2):
            task.add_force_channel(j, f"{10 + j}+X force", 2.25, range_v=0.5)
        for k in range(3):
            task.add_accel_channel(2 + k, f"{100 + k}+Z", 100.0)
        task.configure_timing(src.sample_rate_hz, 256)
        amp = LoadCellAmplifier(bus, timeout_s=2.0)
        return src, backend, task, amp

    yield build
    for sim, bus, dev in made:
        dev.close()
        bus.shutdown()
        sim.close()


def _gauges_session(task, amp, inputs, outputs, settings, operator):
    """An impact session on the DAQ task and the load cell ``amp`` (its gauges as outputs)."""
    return ImpactSession(
        task,
        inputs,
        outputs,
        [amp],
        settings=settings,
        operator=operator,
        loadcell_outputs="gauges",
    )


def test_impact_test_rejects_bad_averages_and_matches_closed_form(lab, tmp_path):
    # CAN frames dropped inside what becomes input 1's first record
    src, backend, task, amp = lab(LoadCellFaults(dropped_samples={12_000, 12_001}))
    strikes = []

    def operator(j, at):
        n = len(strikes)
        strikes.append((j, at))
        world = backend.world_sample(at)
        src.excite(j, world)
        if n == 1:  # a double hit
            src.excite(j, world + 40)
        if n == 2:  # three hammers at once: 675 mV on the 500 mV range
            src.excite(j, world)
            src.excite(j, world)

    settings = ImpactSettings(record_samples=2048, averages_per_input=2, trigger_level_n=20.0)
    progress = []
    with AcquisitionWriter(
        tmp_path / "raw.h5",
        sample_rate_hz=src.sample_rate_hz,
        daq_channels=task.channel_names,
        daq_units=("N", "N", "m/s^2", "m/s^2", "m/s^2"),
        n_loadcells=1,
    ) as writer:
        session = ImpactSession(
            task,
            ["10+X force", "11+X force"],
            ["100+Z", "101+Z", "102+Z"],
            [amp],
            settings=settings,
            writer=writer,
            operator=operator,
            progress=progress.append,
            loadcell_outputs="gauges",
        )
        res = session.run()
    assert res.n_accepted == (2, 2)
    verdicts = [(a.input_index, a.accepted, a.reasons) for a in res.averages]
    assert verdicts[0] == (0, True, ())
    assert verdicts[1] == (0, False, ("double hit",))
    assert verdicts[2][:2] == (0, False) and "overload on 10+X force" in verdicts[2][2][0]
    lost = [v for v in verdicts if any("load cell 0 samples lost" in r for r in v[2])]
    assert len(lost) == 1 and lost[0][0] == 1
    assert sum(v[1] for v in verdicts) == 4 and len(progress) == len(verdicts)
    # FRFs: responses and gauges against the closed form
    h_true = src.frf(res.frequencies_hz)  # (L, 3, 2)
    band = slice(1, None)
    scale = np.abs(h_true).max()
    np.testing.assert_allclose(res.H[band, :3], h_true[band], atol=2e-3 * scale)
    g_true = np.einsum("gr,lri->lgi", src.gauge_mix, h_true)
    np.testing.assert_allclose(res.H[band, 3:], g_true[band], atol=2e-3 * np.abs(g_true).max())
    assert res.output_names[3] == "loadcell0 g01" and res.H.shape[1:] == (15, 2)
    # everything is on disk, including the rejected averages
    with h5py.File(tmp_path / "raw.h5") as f:
        n = f["daq/data"].shape[1]
        assert n >= 8 * 2048 and f["loadcell0/gauges_v"].shape[1] == n
        avgs = [json.loads(s) for s in f["averages"][()]]
        assert [a["accepted"] for a in avgs] == [v[1] for v in verdicts]
        truth = src.read(np.array([2]), backend.world_sample(0), 1000)[0]
        np.testing.assert_allclose(f["daq/data"][2, :1000], truth, atol=5 / 2**23 / (0.1 / G))


@pytest.mark.parametrize("free_running", [True, False])
def test_end_of_run_pulse_check_counts_the_samples_the_daq_clocked(lab, caplog, free_running):
    """A DAQ clocks samples the host never reads (in its FIFO at STOP); the load cell counted
    their pulses too, so the end-of-run check must use the DAQ's count, not the host's.
    Free-running (wall time, as real hardware) and with 3 frames clocked before STOP."""
    faults = None if free_running else DaqFaults(frames_clocked_before_stop=3)
    src, backend, task, amp = lab(free_running=free_running, daq_faults=faults)

    def operator(j, at):
        src.excite(j, backend.world_sample(at))

    settings = ImpactSettings(record_samples=512, averages_per_input=1, trigger_level_n=20.0)
    session = _gauges_session(task, amp, ["10+X force"], ["100+Z"], settings, operator)
    with caplog.at_level(logging.INFO, logger="dimacq"):
        res = session.run()
    assert res.n_accepted == (1,)
    assert task.samples_clocked is not None
    assert task.samples_clocked > session._daq_buf.end  # the DAQ clocked more than was read
    assert "misaligned" not in caplog.text
    assert f"stopped after {task.samples_clocked} samples clocked" in caplog.text


def test_loadcell_forces_need_a_calibration(lab):
    _, _, task, amp = lab()
    with pytest.raises(SetupError, match="calibration matrix"):
        ImpactSession(task, ["10+X force"], ["100+Z"], [amp])


def test_input_below_min_averages_is_struck_again_then_reported_incomplete(lab):
    """Issue 10: an input with 1 of its averages accepted gave an FRF with coherence 1
    identically. Now it is struck again within the budget, then reported incomplete (no FRF)."""
    src, backend, task, amp = lab()
    strikes = []

    def operator(j, at):
        world = backend.world_sample(at)
        src.excite(j, world)
        if j == 0 and sum(1 for s in strikes if s == 0) >= 1:
            src.excite(j, world + 40)  # every strike after the first on input 0: a double hit
        strikes.append(j)

    settings = ImpactSettings(
        record_samples=2048, averages_per_input=3, min_averages=2, trigger_level_n=20.0
    )
    session = _gauges_session(
        task, amp, ["10+X force", "11+X force"], ["100+Z", "101+Z", "102+Z"], settings, operator
    )
    res = session.run()
    # input 0 struck until the budget (3 × 3) was spent; input 1 needed only its 3
    assert strikes.count(0) == settings.max_attempts_factor * settings.averages_per_input
    assert strikes.count(1) == 3
    assert res.n_accepted == (1, 3)
    assert res.incomplete_inputs == ("10+X force",) and res.min_averages == 2
    assert res.input_names == ("11+X force",) and res.input_indices == (1,)
    assert res.H.shape[2] == 1 and res.coherence.shape[2] == 1
    # the complete input's FRF against the closed form
    h_true = src.frf(res.frequencies_hz)[:, :, 1]
    band = slice(1, None)
    np.testing.assert_allclose(res.H[band, :3, 0], h_true[band], atol=2e-3 * np.abs(h_true).max())
    rejected = [a.reasons for a in res.averages if a.input_index == 0 and not a.accepted]
    assert len(rejected) == 8 and all(r == ("double hit",) for r in rejected)


def test_one_average_gives_no_coherence_of_one(lab):
    """One average asked (min_averages capped at it): the FRF is kept, its coherence is NaN."""
    src, backend, task, amp = lab()

    def operator(j, at):
        src.excite(j, backend.world_sample(at))

    settings = ImpactSettings(record_samples=2048, averages_per_input=1, trigger_level_n=20.0)
    res = _gauges_session(
        task, amp, ["10+X force", "11+X force"], ["100+Z", "101+Z", "102+Z"], settings, operator
    ).run()
    assert res.n_accepted == (1, 1) and res.incomplete_inputs == () and res.min_averages == 1
    assert np.isnan(res.coherence).all()


def test_every_input_incomplete_is_refused(lab):
    src, backend, task, amp = lab()

    def operator(j, at):
        world = backend.world_sample(at)
        src.excite(j, world)
        src.excite(j, world + 40)  # always a double hit

    settings = ImpactSettings(
        record_samples=2048, averages_per_input=1, max_attempts_factor=2, trigger_level_n=20.0
    )
    session = _gauges_session(task, amp, ["10+X force"], ["100+Z"], settings, operator)
    with pytest.raises(DataError, match=r"inputs \['10\+X force'\]: fewer than 1 acceptable"):
        session.run()


def test_trigger_wait_holds_only_the_pretrigger_history():
    """A long wait for the hammer keeps at most pre-trigger + one block in memory (it used to
    grow the whole history by np.concatenate per block: quadratic CPU, unbounded memory), and
    the record around the late hit is still whole and exact."""
    daq = BlockDaq(4, 2048.0, 512)
    settings = ImpactSettings(record_samples=1024, averages_per_input=1, trigger_level_n=20.0)
    hit_after = 20 * 2048  # 20 s of nothing
    session = ImpactSession(
        daq,
        ["0+X force"],
        ["1+Z", "2+Z", "3+Z"],
        settings=settings,
        operator=lambda j, at: daq.strike(at + hit_after),
    )
    held: list[int] = []
    waited: list[bool] = []

    def on_read():
        if daq._next < daq.hits[0]:  # still waiting for the trigger
            held.append(session._daq_buf.data.shape[1])
            waited.append(True)

    daq.on_read = on_read
    res = session.run()
    assert res.n_accepted == (1,) and len(waited) > 70
    assert max(held) <= settings.pretrigger_samples + settings.block_samples
    (avg,) = res.averages
    assert avg.first_sample == daq.hits[0] - settings.pretrigger_samples


def test_fifo_overflow_rejects_the_average_it_hits_and_names_it(lab):
    """A FIFO overflow inside a record: that average is rejected with the overflow named, the
    operator strikes again, the accepted ones are unaffected."""
    src, backend, task, amp = lab(daq_faults=DaqFaults(fifo_overflow_frames={12}))

    def operator(j, at):
        src.excite(j, backend.world_sample(at))

    settings = ImpactSettings(record_samples=2048, averages_per_input=2, trigger_level_n=20.0)
    session = _gauges_session(
        task, amp, ["10+X force", "11+X force"], ["100+Z"], settings, operator
    )
    res = session.run()
    assert res.n_accepted == (2, 2)
    rejected = [a for a in res.averages if not a.accepted]
    assert len(rejected) == 1
    assert rejected[0].reasons == ("DAQ samples lost (256: FIFO overflow)",)
    # frame 12 holds samples 3072..3327: inside the rejected record
    assert rejected[0].first_sample <= 12 * 256 < rejected[0].first_sample + 2048


def test_a_daq_that_stops_answering_is_reported_lost(lab):
    """Three reads in a row time out: the run fails, and the session's events (the service's
    device state, ``/api/status``) say the DAQ is lost, after the three timeouts."""
    _, _, task, amp = lab(daq_faults=DaqFaults(timeout_reads=set(range(10_000))))
    events: list[dict] = []
    session = ImpactSession(
        task,
        ["10+X force"],
        ["100+Z"],
        [amp],
        settings=ImpactSettings(record_samples=512, averages_per_input=1),
        operator=lambda j, at: None,
        loadcell_outputs="gauges",
        on_event=events.append,
    )
    with pytest.raises(DeviceTimeoutError):
        session.run()
    kinds = [e["kind"] for e in events]
    assert kinds.count("daq_timeout") == 3 and kinds[-1] == "lost", kinds


def test_a_session_resumed_with_kept_averages_strikes_only_the_missing(lab):
    """Issue 24: a session given the averages an interrupted one kept (``prior``) strikes only
    the missing ones; an input whose averages were all kept has the first run's FRFs bit for
    bit, and records_frf (finish after a crash) gives the session's numbers from the same
    records."""
    from dimacq.model.setup import Excitation, ResponseChannel, TestSetup
    from dimacq.services.acquisition.session import records_frf

    src, backend, task, amp = lab()
    strikes = []

    def operator(j, at):
        src.excite(j, backend.world_sample(at))
        strikes.append(j)

    settings = ImpactSettings(
        record_samples=2048, averages_per_input=3, min_averages=2, trigger_level_n=20.0
    )
    chans = (["10+X force", "11+X force"], ["100+Z", "101+Z", "102+Z"])
    records: list[list] = [[], []]
    first = _gauges_session(task, amp, *chans, settings, operator)
    first.on_average = lambda j, _n, ok, _r, rec: records[j].append(rec) if ok else None
    full = first.run()
    kept = [records[0], records[1][:1]]  # the kill: after input 11's first average
    strikes.clear()
    again = _gauges_session(task, amp, *chans, settings, operator)
    again.prior = kept
    new: list[list] = [[], []]
    again.on_average = lambda j, _n, ok, _r, rec: new[j].append(rec) if ok else None
    res = again.run()
    assert strikes == [1, 1] and res.n_accepted == (3, 3) and len(new[1]) == 2
    # equal to rounding: the FFTs batch several records per SIMD pass, so how many records share
    # a pass (the outputs' count) can move the last bits (3e-14 seen), not the numbers
    np.testing.assert_allclose(res.H[:, :, 0], full.H[:, :, 0], rtol=1e-12, atol=0)
    h_true = src.frf(res.frequencies_hz)[:, :, 1]
    np.testing.assert_allclose(res.H[1:, :3, 1], h_true[1:], atol=2e-3 * np.abs(h_true).max())
    # the finish path: the same records, the same numbers
    setup = TestSetup(
        name="impulse",
        responses=tuple(
            ResponseChannel(node=100 + k, direction=3, position_m=(0.1 * k, 0, 0),
                            direction_gcs=(0, 0, 1))
            for k in range(3)
        ),
        excitations=tuple(
            Excitation(node=10 + j, direction=1, position_m=(0, 0.1 * j, 0),
                       direction_gcs=(1, 0, 0))
            for j in range(2)
        ),
    )  # fmt: skip
    fs = task.sample_rate_hz

    def accels(recs):  # the setup has no load cell: the responses' rows (H1 is per output)
        return [{"force": r["force"], "outputs": r["outputs"][:3]} for r in recs]

    frf = records_frf([accels(kept[0]), accels(kept[1] + new[1])], fs, settings, setup)
    np.testing.assert_allclose(frf.H[:, :3], res.H[1:, :3], rtol=1e-12, atol=0)


class _BehindDaq(BlockDaq):
    """A DAQ whose clock runs ``backlog`` samples ahead of what the host has read (its FIFO
    holds them), with samples lost in ``gaps`` (NaN, not valid, an overflow event), and strikes
    of their own force each (``strike(at, force_n)``) to tell whose hit a record holds."""

    def __init__(self, backlog: int, gaps: list[tuple[int, int]]) -> None:
        super().__init__(4, 2048.0, 512)
        self.backlog, self.gaps = backlog, gaps
        self.force: dict[int, float] = {}

    def samples_clocked_now(self) -> int | None:
        return self._next + self.backlog if self._running else None

    def read(self, n_samples: int, timeout_s: float | None = None) -> DaqBlock:
        b = super().read(n_samples, timeout_s)
        data, valid = b.data.copy(), np.ones(n_samples, dtype=bool)
        k = b.first_sample + np.arange(n_samples)
        for h, f in self.force.items():
            data[0, k == h] = f
        events = []
        for a, e in self.gaps:
            lost = (k >= a) & (k < e)
            if lost.any():
                data[:, lost], valid[lost] = np.nan, False
                events.append(DaqEvent("overflow", a, e - a, message="FIFO overflow"))
        return DaqBlock(
            b.first_sample,
            b.sample_rate_hz,
            b.channel_names,
            b.units,
            data,
            b.overload,
            valid,
            tuple(events),
        )


@pytest.mark.parametrize("clock_known", [True, False])
def test_a_strike_asked_again_after_a_gap_is_not_filed_under_the_next_input(
    clock_known: bool,
) -> None:
    """The host is 1 s behind the DAQ (its FIFO), and samples are lost in that backlog, after
    the host's read position and before the strike of input 0 (struck at the clock's present
    sample, as the simulated lab's hand does when the asked sample is past). Searched from what
    the host had read, the gap "lost" the strike, it was asked again, the first strike was
    filed for input 0 and the second one — input 0's — under input 1, and so on down the
    inputs (each carried the one before's FRFs; seen in the demo at 37x on a loaded machine).
    Searched from the DAQ's clock at the time of asking, every record holds its own input's
    strike. A DAQ that cannot say its clock (None) keeps the old search: the mix-up shows."""
    backlog = 2048
    daq = _BehindDaq(backlog, gaps=[(600, 856)])
    if not clock_known:
        daq.backlog = 0  # the strike still lands a second ahead, as before; the host cannot say

    struck: list[tuple[int, int]] = []

    def operator(j: int, at: int) -> None:
        h = max(at, daq._next + backlog + 1)  # the asked sample or, when past, the hand's now
        daq.strike(h)
        daq.force[h] = 1000.0 + 100.0 * j
        struck.append((j, h))

    settings = ImpactSettings(
        record_samples=1024, averages_per_input=1, trigger_level_n=20.0, max_attempts_factor=3
    )
    session = ImpactSession(
        daq,
        ["0+X force"] * 3,  # a roving hammer: three inputs on its one channel
        ["1+Z", "2+Z", "3+Z"],
        settings=settings,
        operator=operator,
        input_labels=["10+X", "11+X", "12+X"],
    )
    res = session.run()
    whose = {h: j for j, h in struck}
    filed = [
        (a.input_index, whose.get(a.first_sample + settings.pretrigger_samples))
        for a in res.averages
        if a.accepted
    ]
    assert len(filed) == 3
    if clock_known:
        assert filed == [(0, 0), (1, 1), (2, 2)], (filed, struck)
    else:
        assert any(i != j for i, j in filed), (filed, struck)
