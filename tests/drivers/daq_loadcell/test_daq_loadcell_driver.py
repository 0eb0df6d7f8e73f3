"""A load cell read as DAQ inputs (:mod:`dimacq.drivers.daq_loadcell`): the splitter hands the
cell's rows to it and the rest to the acquisition, on the DAQ's one sample counter; the loads
are ``C g``; samples the DAQ lost are NaN, not valid and a gap; clipped inputs are overloads."""

from __future__ import annotations

from collections import deque
from typing import Any

import numpy as np
import pytest

from dimacq.devices.daq import ChannelConfig, DaqBlock, DaqEvent
from dimacq.devices.loadcell import LoadCell
from dimacq.drivers.daq_loadcell import ChannelDaq, DaqChannelLoadCell, DaqSplitter
from dimacq.errors import SetupError


class ScriptedDaq:
    """A DAQ task whose reads return the blocks the test queued (its channels as added)."""

    def __init__(self) -> None:
        self.sample_rate_hz: float | None = 2048.0
        self.events: list[DaqEvent] = []
        self.samples_clocked: int | None = None
        self.configs: list[ChannelConfig] = []
        self.blocks: deque[DaqBlock] = deque()
        self._running = False
        self.reconnected = 0

    @property
    def channel_names(self) -> tuple[str, ...]:
        return tuple(c.name for c in sorted(self.configs, key=lambda c: c.physical_channel))

    @property
    def running(self) -> bool:
        return self._running

    def add_channel(self, config: ChannelConfig) -> None:
        if any(c.physical_channel == config.physical_channel for c in self.configs):
            raise SetupError(f"physical channel {config.physical_channel} is already in task")
        self.configs.append(config)

    def add_accel_channel(self, ch: int, name: str, mv_per_g: float, **_: Any) -> None:
        self.add_channel(ChannelConfig(ch, name, "m/s^2", mv_per_g / 9806.65))

    def add_force_channel(self, ch: int, name: str, mv_per_n: float, **_: Any) -> None:
        self.add_channel(ChannelConfig(ch, name, "N", mv_per_n / 1e3))

    def configure_timing(self, sample_rate_hz: float, samples_per_frame: int = 256) -> None:
        self.sample_rate_hz = sample_rate_hz

    def identify(self) -> object:
        return "scripted"

    def start(self) -> None:
        self._running = True

    def stop(self) -> None:
        self._running = False

    def read(self, n_samples: int, timeout_s: float | None = None) -> DaqBlock:
        b = self.blocks.popleft()
        assert b.n_samples == n_samples
        return b

    def read_available(self, timeout_s: float | None = None) -> DaqBlock:
        return self.blocks.popleft()

    def read_buffered(self) -> DaqBlock | None:
        return self.blocks.popleft() if self.blocks else None

    def samples_clocked_now(self) -> int | None:
        return None

    def reconnect(self) -> None:
        self.reconnected += 1

    def queue(self, first: int, data: np.ndarray, valid: Any = None, overload: Any = None) -> None:
        n = data.shape[1]
        names = self.channel_names
        self.blocks.append(
            DaqBlock(
                first,
                2048.0,
                names,
                tuple("V" for _ in names),
                data,
                np.zeros(data.shape, bool) if overload is None else overload,
                np.ones(n, bool) if valid is None else valid,
            )
        )


def _rig(n_gauges: int = 12) -> tuple[ScriptedDaq, DaqSplitter, DaqChannelLoadCell, np.ndarray]:
    daq = ScriptedDaq()
    assert isinstance(daq, ChannelDaq)
    split = DaqSplitter(daq)
    split.add_force_channel(0, "hammer ch0", 2.25)
    split.add_accel_channel(1, "1+X", 100.0)
    feed = split.claim(
        [ChannelConfig(10 + k, f"LC501 g{k + 1:02d}", "mV/V", 0.01) for k in range(n_gauges)]
    )
    C = np.random.default_rng(3).normal(size=(6, n_gauges))
    cell = DaqChannelLoadCell(feed, calibration_matrix=C, serial_number=501, label="load cell 501")
    return daq, split, cell, C


def test_split_rows_and_loads_on_one_counter() -> None:
    daq, split, cell, C = _rig()
    assert isinstance(split, type(split)) and isinstance(cell, LoadCell)
    assert split.channel_names == ("hammer ch0", "1+X")  # the acquisition sees no gauges
    assert cell.identify().n_gauges == 12 and cell.identify().serial_number == 501
    rng = np.random.default_rng(0)
    data = rng.normal(size=(14, 512))
    cell.set_rate(2048)
    cell.start()
    split.start()
    daq.queue(0, data[:, :256])
    daq.queue(256, data[:, 256:])
    b = split.read(256)
    assert b.channel_names == ("hammer ch0", "1+X") and b.data.shape == (2, 256)
    np.testing.assert_array_equal(b.data, data[:2, :256])
    lc = cell.read_until(256)
    assert lc.first_sample == 0 and lc.n_samples == 256 and lc.valid.all()
    np.testing.assert_array_equal(lc.gauges_v, data[2:, :256])
    assert lc.forces is not None
    np.testing.assert_allclose(lc.forces, C @ data[2:, :256])
    split.stop()
    tail = split.read_buffered()
    assert tail is not None and tail.first_sample == 256
    assert cell.stop() == 512  # what the DAQ carried
    rest = cell.read_until(512)
    np.testing.assert_array_equal(rest.gauges_v, data[2:, 256:])
    assert cell.verify_count(600) is None  # one clock: nothing to drift
    assert cell.read_until(512).n_samples == 0


def test_lost_samples_are_gaps_and_clipped_inputs_overloads() -> None:
    daq, split, cell, _ = _rig()
    cell.start()
    split.start()
    valid = np.ones(256, bool)
    valid[100:110] = False
    over = np.zeros((14, 256), bool)
    over[5, 200] = True  # gauge 4 clipped
    data = np.ones((14, 256))
    data[:, ~valid] = np.nan
    daq.queue(0, data, valid, over)
    split.read(256)
    lc = cell.read_until(256)
    assert not lc.valid[100:110].any() and lc.valid[:100].all() and lc.valid[110:].all()
    assert np.isnan(lc.gauges_v[:, 100:110]).all()
    assert [(e.kind, e.first_sample, e.n_samples) for e in lc.events] == [("gap", 100, 10)]
    assert lc.overload[200] and lc.overload.sum() == 1


def test_a_new_run_starts_the_counter_again_and_reconnect_is_the_tasks() -> None:
    daq, split, cell, _ = _rig()
    cell.start()
    split.start()
    daq.queue(0, np.zeros((14, 64)))
    split.read(64)
    split.reconnect()  # what the session calls after the DAQ dropped off: the task's own
    assert daq.reconnected == 1
    cell.start()
    split.start()
    daq.queue(0, np.ones((14, 64)))
    split.read(64)
    lc = cell.read_until(64)
    assert lc.first_sample == 0 and (lc.gauges_v == 1).all()


def test_six_conditioned_outputs() -> None:
    daq = ScriptedDaq()
    split = DaqSplitter(daq)
    split.add_force_channel(0, "hammer ch0", 2.25)
    names = ["LC9 Fx", "LC9 Fy", "LC9 Fz", "LC9 Mx", "LC9 My", "LC9 Mz"]
    feed = split.claim([ChannelConfig(20 + k, n, "V", 1.0) for k, n in enumerate(names)])
    C = np.diag([100.0, 100.0, 200.0, 10.0, 10.0, 10.0])  # N/V, N·m/V
    cell = DaqChannelLoadCell(feed, calibration_matrix=C)
    cell.start()
    split.start()
    v = np.arange(7 * 32, dtype=float).reshape(7, 32)
    daq.queue(0, v)
    split.read(32)
    lc = cell.read_until(32)
    assert lc.forces is not None
    np.testing.assert_allclose(lc.forces, C @ v[1:])


def test_refusals() -> None:
    _daq, split, cell, _ = _rig(6)
    with pytest.raises(SetupError, match=r"6x6 matrix"):
        DaqChannelLoadCell(cell.feed, calibration_matrix=np.ones((6, 12)))
    with pytest.raises(SetupError, match="DAQ's clock only"):
        cell.start(external_clock=False)
    with pytest.raises(SetupError, match="not 1000 Hz"):
        cell.set_rate(1000)
    with pytest.raises(SetupError, match="already in task"):
        split.claim([ChannelConfig(1, "LC7 g01", "V", 1.0)])
