"""A load cell whose gauges (or six conditioned F/T outputs) are DAQ inputs.

The thesis's set-up: the cell's bridge outputs go to analogue inputs of the same DAQ as the
accelerometers and the hammer, so they are sampled on one clock and need no counter alignment.
The transport of this driver is the DAQ task itself (injected): :class:`DaqSplitter` wraps a
:class:`~dimacq.devices.daq.Daq` task, adds the cell's inputs to it (:meth:`DaqSplitter.claim`)
and, on every read, hands those rows to the cell's :class:`DaqFeed` and the rest to its caller,
so the acquisition sees the DAQ with its hammer and response channels only and each load cell
as a :class:`~dimacq.devices.loadcell.LoadCell` (:class:`DaqChannelLoadCell`) whose
``read_until`` returns what the DAQ's last reads carried::

    splitter = DaqSplitter(task)                      # task: hammer + accelerometer channels
    feed = splitter.claim([ChannelConfig(25, "LC501 g01", "mV/V", 0.01, 0.1, 0, "DC"), ...])
    cell = DaqChannelLoadCell(feed, calibration_matrix=C)   # C: 6 x N, F = C g

Gauges read in the calibration's gauge unit: ``mV/V`` bridges through a sensitivity of
``excitation_v / 1000`` V per mV/V, volts as they are (a conditioned output, or a gauge
calibrated in V). Samples the DAQ lost are NaN and not valid in the cell's block too (a
``gap`` event each), an input that clipped marks its samples ``overload``. There is no second
clock: :meth:`DaqChannelLoadCell.verify_count` has nothing to check.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from typing import Any, Literal, Protocol, runtime_checkable

import numpy as np
from numpy.typing import NDArray

from dimacq.devices.daq import ChannelConfig, Daq, DaqBlock, DaqEvent
from dimacq.devices.loadcell import LoadCellBlock, LoadCellEvent, LoadCellIdentity
from dimacq.drivers.stream import CounterStream, false_runs
from dimacq.errors import SetupError

__all__ = ["ChannelDaq", "DaqChannelLoadCell", "DaqFeed", "DaqSplitter"]

log = logging.getLogger(__name__)


@runtime_checkable
class ChannelDaq(Daq, Protocol):
    """A DAQ task that takes any channel (:class:`~dimacq.devices.daq.ChannelConfig`: unit and
    sensitivity of its own), as :class:`dimacq.drivers.daq.driver.DaqTask` does."""

    def add_channel(self, config: ChannelConfig) -> None: ...


class DaqFeed:
    """The rows of one load cell's DAQ inputs, filed by sample counter as the DAQ is read."""

    def __init__(self, names: Sequence[str], splitter: DaqSplitter) -> None:
        self.names = tuple(names)
        self._splitter = splitter
        self.stream: CounterStream[LoadCellEvent] = CounterStream(
            len(self.names), flag_dtype=np.bool_
        )

    @property
    def n_channels(self) -> int:
        return len(self.names)

    @property
    def sample_rate_hz(self) -> float | None:
        return self._splitter.sample_rate_hz

    def reset(self) -> None:
        """A new run: the DAQ's counter starts at 0 again."""
        self.stream = CounterStream(len(self.names), flag_dtype=np.bool_)

    def put(
        self,
        first: int,
        data: NDArray[np.float64],
        overload: NDArray[np.bool_],
        valid: NDArray[np.bool_],
    ) -> None:
        """File samples ``first ..`` (``data``, ``overload`` shape (n_channels, n)); the ones
        the DAQ lost (``valid`` False) stay holes, one ``gap`` event per run of them."""
        ok = np.asarray(valid, dtype=bool)
        counters = first + np.flatnonzero(ok)
        over = np.any(np.asarray(overload, dtype=bool), axis=0, keepdims=False).astype(bool)
        self.stream.put_counters(counters, data.T[ok], over[ok])
        for a, b in false_runs(ok):
            self.stream.record(
                LoadCellEvent(
                    "gap",
                    first + a,
                    b - a + 1,
                    f"{b - a + 1} samples of {self.names[0]}.. lost with the DAQ's",
                )
            )


class DaqSplitter:
    """A :class:`~dimacq.devices.daq.Daq` whose reads hand some inputs to load cells.

    Everything not overridden here is the wrapped task's (``reconnect`` too, when it has one).
    """

    def __init__(self, daq: ChannelDaq) -> None:
        self.inner = daq
        self._feeds: list[DaqFeed] = []
        self._claimed: set[str] = set()

    # -- the Daq protocol's attributes are the task's ------------------------------------------
    @property
    def sample_rate_hz(self) -> float | None:
        return self.inner.sample_rate_hz

    @sample_rate_hz.setter
    def sample_rate_hz(self, value: float | None) -> None:
        self.inner.sample_rate_hz = value

    @property
    def events(self) -> list[DaqEvent]:
        return self.inner.events

    @events.setter
    def events(self, value: list[DaqEvent]) -> None:
        self.inner.events = value

    @property
    def samples_clocked(self) -> int | None:
        return self.inner.samples_clocked

    @samples_clocked.setter
    def samples_clocked(self, value: int | None) -> None:
        self.inner.samples_clocked = value

    def __getattr__(self, name: str) -> Any:
        # only reached for what this class does not define (e.g. reconnect)
        if name == "inner":
            raise AttributeError(name)
        return getattr(self.inner, name)

    @property
    def channel_names(self) -> tuple[str, ...]:
        """The task's channels less the load cells' (what a read returns)."""
        return tuple(n for n in self.inner.channel_names if n not in self._claimed)

    @property
    def running(self) -> bool:
        return self.inner.running

    # -- channels -----------------------------------------------------------------------------
    def claim(self, configs: Sequence[ChannelConfig]) -> DaqFeed:
        """Add a load cell's inputs to the task; their samples go to the returned feed.

        Raises
        ------
        SetupError
            An input already in the task (the task's message), or no inputs.
        """
        if not configs:
            raise SetupError("a load cell on DAQ inputs needs at least one input; give them")
        for c in configs:
            self.inner.add_channel(c)
            self._claimed.add(c.name)
        feed = DaqFeed([c.name for c in configs], self)
        self._feeds.append(feed)
        return feed

    def add_accel_channel(
        self,
        physical_channel: int,
        name: str,
        sensitivity_mv_per_g: float,
        *,
        range_v: float = 5.0,
        iepe_current_ma: float = 4.0,
        coupling: Literal["AC", "DC"] = "AC",
    ) -> None:
        self.inner.add_accel_channel(
            physical_channel,
            name,
            sensitivity_mv_per_g,
            range_v=range_v,
            iepe_current_ma=iepe_current_ma,
            coupling=coupling,
        )

    def add_force_channel(
        self,
        physical_channel: int,
        name: str,
        sensitivity_mv_per_n: float,
        *,
        range_v: float = 5.0,
        iepe_current_ma: float = 4.0,
        coupling: Literal["AC", "DC"] = "AC",
    ) -> None:
        self.inner.add_force_channel(
            physical_channel,
            name,
            sensitivity_mv_per_n,
            range_v=range_v,
            iepe_current_ma=iepe_current_ma,
            coupling=coupling,
        )

    def configure_timing(self, sample_rate_hz: float, samples_per_frame: int = 256) -> None:
        self.inner.configure_timing(sample_rate_hz, samples_per_frame)

    def identify(self) -> object:
        return self.inner.identify()

    # -- run ----------------------------------------------------------------------------------
    def start(self) -> None:
        for f in self._feeds:
            f.reset()
        self.inner.start()

    def stop(self) -> None:
        self.inner.stop()

    def read(self, n_samples: int, timeout_s: float | None = None) -> DaqBlock:
        return self._split(self.inner.read(n_samples, timeout_s))

    def read_available(self, timeout_s: float | None = None) -> DaqBlock:
        return self._split(self.inner.read_available(timeout_s))

    def samples_clocked_now(self) -> int | None:
        return self.inner.samples_clocked_now()

    def read_buffered(self) -> DaqBlock | None:
        block = self.inner.read_buffered()
        return None if block is None else self._split(block)

    def _split(self, block: DaqBlock) -> DaqBlock:
        row = {n: k for k, n in enumerate(block.channel_names)}
        for f in self._feeds:
            idx = [row[n] for n in f.names]
            f.put(block.first_sample, block.data[idx], block.overload[idx], block.valid)
        keep = [k for k, n in enumerate(block.channel_names) if n not in self._claimed]
        return DaqBlock(
            block.first_sample,
            block.sample_rate_hz,
            tuple(block.channel_names[k] for k in keep),
            tuple(block.units[k] for k in keep),
            block.data[keep],
            block.overload[keep],
            block.valid,
            block.events,
        )


class DaqChannelLoadCell:
    """A 6-DOF load cell (:class:`~dimacq.devices.loadcell.LoadCell`) whose gauges are DAQ
    inputs, read through a :class:`DaqSplitter`'s feed.

    Parameters
    ----------
    feed : DaqFeed
        The cell's inputs (:meth:`DaqSplitter.claim`), in the calibration matrix's column order.
    calibration_matrix : ndarray, shape (6, n_gauges), optional
        ``F = C g`` (None: gauges only, a cell being calibrated).
    serial_number : int
        The cell's, from its calibration file (a DAQ input cannot tell).
    label : str
        What messages call it (``"load cell 501"``).
    """

    def __init__(
        self,
        feed: DaqFeed,
        *,
        calibration_matrix: NDArray[np.float64] | None = None,
        serial_number: int = 0,
        label: str = "load cell",
    ) -> None:
        if calibration_matrix is not None:
            C = np.asarray(calibration_matrix, dtype=float)
            if C.shape != (6, feed.n_channels):
                raise SetupError(
                    f"{label}: calibration matrix {C.shape} for {feed.n_channels} DAQ inputs; "
                    f"give a 6x{feed.n_channels} matrix or list one input per matrix column"
                )
            calibration_matrix = C
        self.feed = feed
        self.calibration_matrix = calibration_matrix
        self.serial_number = serial_number
        self.label = label
        self.sample_rate_hz: float | None = feed.sample_rate_hz
        self.events: list[LoadCellEvent] = []

    @property
    def n_gauges(self) -> int:
        return self.feed.n_channels

    def identify(self) -> LoadCellIdentity:
        return LoadCellIdentity(
            n_gauges=self.feed.n_channels,
            firmware=f"DAQ inputs {self.feed.names[0]} .. {self.feed.names[-1]}",
            serial_number=self.serial_number,
        )

    def set_rate(self, rate_hz: int) -> float:
        """The DAQ's rate is the cell's: ``rate_hz`` must be it."""
        daq = self.feed.sample_rate_hz
        if daq is not None and abs(daq - rate_hz) > 0.5:
            raise SetupError(
                f"{self.label}: its gauges are DAQ inputs sampled at {daq:g} Hz, not {rate_hz} Hz"
            )
        self.sample_rate_hz = float(daq if daq is not None else rate_hz)
        return self.sample_rate_hz

    def start(self, *, external_clock: bool = True) -> None:
        if not external_clock:
            raise SetupError(
                f"{self.label}: its gauges are DAQ inputs, sampled on the DAQ's clock only; "
                "start the DAQ (external_clock=True)"
            )
        self.feed.reset()
        self.events = []

    def stop(self) -> int:
        """Samples received from the DAQ in this run (the DAQ has stopped first)."""
        return self.feed.stream.end

    def read_until(self, end_sample: int, timeout_s: float | None = None) -> LoadCellBlock:
        """Samples up to ``end_sample − 1`` of what the DAQ's reads carried (never waits: the
        DAQ has been read up to there; later samples are NaN and not valid)."""
        st = self.feed.stream
        first = st.next_sample
        if end_sample <= first:
            n = self.feed.n_channels
            return LoadCellBlock(
                first,
                np.zeros((n, 0)),
                None if self.calibration_matrix is None else np.zeros((6, 0)),
                np.zeros(0, dtype=bool),
                np.zeros(0, dtype=bool),
                (),
            )
        if end_sample > st.end:
            log.warning(
                "%s: samples %d..%d asked for before the DAQ read them",
                self.label,
                st.end,
                end_sample - 1,
            )
        got = st.take(end_sample)
        events = st.pop_events(got.first, end_sample)
        self.events.extend(events)
        gauges = got.data.T
        forces = None if self.calibration_matrix is None else self.calibration_matrix @ gauges
        return LoadCellBlock(
            got.first,
            gauges,
            forces,
            got.valid,
            got.flags.astype(bool, copy=False),
            events,
        )

    def verify_count(self, daq_samples_clocked: int) -> LoadCellEvent | None:
        """Nothing to check: the gauges are the DAQ's own samples."""
        return None
