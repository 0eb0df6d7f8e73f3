"""The simulated lab's time-lapse: chosen from what this host sustains, and whether it kept up.

The simulated DAQ clocks in wall time ``daq_time_scale`` times faster than a real one
(:mod:`dimacq.simulators.imperfections`); the host must read, decode, align and check
``daq_time_scale`` times the real data rate or the DAQ's FIFO overflows and CAN frames are
dropped, as on a real rig whose PC is too slow. :func:`choose_time_lapse` picks the factor at
start, from a measurement of this host now (its load included), for the demo and ``dimacq
acquire``; :class:`HostLag` then tells from the devices' own reports (DAQ overflow events, load
cell gaps) whether the host kept up.

The measurement (:func:`measure_host`): the wire work of ``probe_s`` simulated seconds of the
rig, done for real — the DAQ frames of ``n_channels`` encoded and decoded with the DAQ codec
(24-bit pack, CRC-32, unpack), each load cell's CAN FD data frames encoded, sent through
python-can's ``virtual`` bus as the amplifier simulator sends them, taken by a receiver as the
driver takes them and decoded — timed in wall time, so a loaded machine measures slower. The
whole acquisition (the virtual lab's physics, trigger search, checks, FRFs, the simulators'
threads, GIL hand-overs) costs ``FULL_OVER_PROBE`` times that wire work per simulated second
(measured on the 2-core reference machine, ``tests/benchmarks/bench_time_lapse.py``), so

    s_max = 1 / (FULL_OVER_PROBE · w),     w = wall seconds of probe work per simulated second

is the time-lapse at which the host would be busy all the time; the chosen factor is
``HEADROOM · s_max`` (room for the service, other processes, bursts), rounded down to a whole
factor within ``[1, max_scale]``.

The probe's load cell work is the CAN FD amplifier's (one data frame per sample). Other load cell
backends put more frames per sample on the virtual bus, each with python-can's per-message cost
(which dominates): :data:`LOADCELL_FRAMES_PER_SAMPLE` says how many, and the probe sends that
many per sample per cell (an ATI Net F/T on CAN: the rig's REQUEST LONG and four answers; a
CiA 404 node: the SYNC and its six TPDOs). Without it the probe, which saw one frame per sample,
chose 25x for ``netft-can-simulated`` where the host sustained less than 8x (2026-11-27, load
average ~5: DAQ FIFO overflows from the twelfth input on, the demo refused). The RDT simulator
(``netft-udp-simulated``) sends datagrams, not frames, but its alignment is what limits it: the
host's clock is its coarse time base, and every wall microsecond of the host's floor is
``daq_time_scale`` microseconds of the lab's time; :data:`LOADCELL_MAX_SCALE` caps its factor.
"""

from __future__ import annotations

import logging
import math
import re
import time
from collections.abc import Iterable, Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from dimacq.drivers.daq import protocol as daq_p
from dimacq.drivers.loadcell import protocol as lc_p
from dimacq.errors import SetupError

__all__ = [
    "DAQ_MAX_SCALE",
    "FULL_OVER_PROBE",
    "HEADROOM",
    "LOADCELL_FRAMES_PER_SAMPLE",
    "LOADCELL_MAX_SCALE",
    "HostLag",
    "HostMeasurement",
    "TimeLapse",
    "choose_time_lapse",
    "measure_host",
    "rig_time_lapse",
]

#: whole acquisition's host cost per simulated second over the probe's (reference machine)
FULL_OVER_PROBE = 6.0
#: fraction of the host the chosen time-lapse may take
HEADROOM = 0.5
#: virtual CAN frames per sample and cell of a load cell backend, where not one (the CAN FD
#: amplifier's single data frame): the probe sends as many
LOADCELL_FRAMES_PER_SAMPLE: dict[str, int] = {
    "netft-can-simulated": 5,  # REQUEST LONG on the DAQ's pulse + four answers
    "cia404-simulated": 7,  # SYNC + six TPDOs (0x6130 of config/canopen/cia404-generic.eds)
}
#: the highest time-lapse of a load cell backend, where lower than ``max_scale``
LOADCELL_MAX_SCALE: dict[str, float] = {
    # the host's clock is its coarse time base (100 us of wall time is 400 us of the lab's at
    # 4x), and the simulator sends on wall time: at 4x under a load average of 12-14 it sent
    # seconds late and the DAQ's FIFO overflowed from the second input on (2026-11-27)
    "netft-udp-simulated": 2.0,
}
#: the highest time-lapse of a simulated DAQ whose FIFO is small: the USB-1808X twin holds the
#: device's 32 KiB, 1024 scans of 8 inputs (0.5 s at 2048 Hz of the lab's time, 0.5/s s of wall
#: time at s x): at 4x under a load average of 30 it overran at the start (2026-11-29)
DAQ_MAX_SCALE: dict[str, float] = {"mcc-usb-simulated": 2.0}


@dataclass(frozen=True)
class HostMeasurement:
    """Wall and CPU seconds of the probe's wire work per simulated second of the rig."""

    wall_per_sim_s: float
    cpu_per_sim_s: float
    probe_sim_s: float

    @property
    def sustainable_scale(self) -> float:
        """``1 / (FULL_OVER_PROBE · w)``: the time-lapse that would keep the host busy."""
        return 1.0 / (FULL_OVER_PROBE * max(self.wall_per_sim_s, 1e-9))


@dataclass(frozen=True)
class TimeLapse:
    """The DAQ's time-lapse factor and how it was chosen (``"measured"`` or ``"setting"``)."""

    scale: float
    how: str
    measurement: HostMeasurement | None = None

    def describe(self) -> str:
        if self.how == "host-paced":
            return "the simulated DAQ clocks as the host reads (daq_free_running = false)"
        if self.measurement is None:
            return (
                f"the simulated DAQ at {self.scale:g}x real time "
                "(setting simulation_imperfections.daq_time_scale)"
            )
        m = self.measurement
        return (
            f"the simulated DAQ at {self.scale:g}x real time (measured at start: this host "
            f"sustains about {m.sustainable_scale:.0f}x now; {HEADROOM:.0%} of it taken)"
        )

    def to_json(self) -> dict[str, object]:
        out: dict[str, object] = {"daq_time_scale": self.scale, "how": self.how}
        if self.measurement is not None:
            out["sustainable_scale"] = self.measurement.sustainable_scale
            out["probe_wall_ms_per_sim_s"] = 1e3 * self.measurement.wall_per_sim_s
            out["probe_cpu_ms_per_sim_s"] = 1e3 * self.measurement.cpu_per_sim_s
        return out


def measure_host(
    n_channels: int, n_cells: int, sample_rate_hz: float, *, probe_s: float = 0.5
) -> HostMeasurement:
    """Time the wire work of ``probe_s`` simulated seconds of the rig (see the module doc).

    Parameters
    ----------
    n_channels : int
        DAQ channels (hammer and accelerometer axes).
    n_cells : int
        Load cells on their CAN FD amplifiers.
    sample_rate_hz : float
    probe_s : float
        Simulated seconds of data the probe handles.
    """
    from can.interfaces.virtual import VirtualBus

    from dimacq.simulators.virtual_can import SimVirtualBus

    if n_channels < 1 or sample_rate_hz <= 0 or probe_s <= 0:
        raise SetupError(
            f"time-lapse probe: {n_channels} DAQ channels at {sample_rate_hz} Hz for {probe_s} s; "
            "give at least one channel, a positive rate and duration"
        )
    n = max(1, round(probe_s * sample_rate_hz))
    min_wall_s = 0.25  # repeated up to this long: one preemption does not decide the factor
    rng = np.random.default_rng(0)
    spf = 256
    counts = rng.integers(-(2**20), 2**20, (n, n_channels)).astype(np.int32)
    gauges = rng.uniform(-1, 1, (n, lc_p.N_GAUGES))
    channel = f"dimacq-time-lapse-probe-{id(counts)}"
    tx = SimVirtualBus(channel=channel, fd=True)
    rx = VirtualBus(channel=channel, fd=True)
    rounds = 0
    try:
        w0, c0 = time.perf_counter(), time.process_time()
        while rounds == 0 or time.perf_counter() - w0 < min_wall_s:
            rounds += 1
            for k in range(0, n, spf):
                frame = daq_p.encode_frame(k // spf, k, counts[k : k + spf])
                daq_p.decode_frame(frame)
            for _ in range(n_cells):
                for k in range(0, n, spf):
                    c = np.arange(k, min(n, k + spf))
                    frames, _ = lc_p.encode_data_frames(c, gauges[c])
                    tx.send_frames([(lc_p.data_id(1), f, True) for f in frames])
                    q = rx.queue
                    with q.mutex:
                        got = list(q.queue)
                        q.queue.clear()
                    lc_p.decode_data_frames([m.data for m in got])
        wall, cpu = time.perf_counter() - w0, time.process_time() - c0
    finally:
        rx.shutdown()
        tx.shutdown()
    sim_s = rounds * n / sample_rate_hz
    return HostMeasurement(wall / sim_s, cpu / sim_s, sim_s)


def choose_time_lapse(
    imperfections: Mapping[str, object],
    *,
    n_channels: int,
    n_cells: int,
    sample_rate_hz: float,
    max_scale: float = 40.0,
) -> TimeLapse:
    """The time-lapse of a simulated acquisition: the setting's ``daq_time_scale`` when it
    gives one, else measured now (:func:`measure_host`), ``HEADROOM`` of what the host
    sustains, a whole factor within ``[1, max_scale]``."""
    given = imperfections.get("daq_time_scale")
    if imperfections.get("enabled") is False or imperfections.get("daq_free_running") is False:
        return TimeLapse(1.0, "host-paced")  # the DAQ clocks as the host reads: no time-lapse
    if given is not None:
        if isinstance(given, bool) or not isinstance(given, int | float) or not given > 0:
            raise SetupError(
                f"simulation_imperfections.daq_time_scale = {given!r}: give a positive factor "
                "(1: real time), or leave it out to measure what this host sustains"
            )
        return TimeLapse(float(given), "setting")
    m = measure_host(n_channels, n_cells, sample_rate_hz)
    scale = min(float(max_scale), max(1.0, math.floor(HEADROOM * m.sustainable_scale)))
    return TimeLapse(scale, "measured", m)


#: the logger of :mod:`dimacq.simulators.daq.clock`'s run reports (named, not imported: the
#: simulators are not loaded where no simulated device is used)
_RUN_LOG = "dimacq.simulators.time_lapse"

_LC_LOST = re.compile(r"load cell \d+ samples lost \((\d+)\)")


@dataclass
class HostLag:
    """Whether the host kept up with the time-lapse, from the devices' reports.

    The DAQ reports a FIFO overflow when the host read too late; a load cell gap longer than one
    frame is frames dropped because they could not be taken in time (one frame alone is the
    bus's own rare loss, ``can_frame_loss_rate``). ``kept_up``: neither happened.

    ``daq_runs``: the simulated DAQ's free-running runs in this process while :meth:`recording`
    (simulated and wall seconds, the factors its adaptive time-lapse used, how often it waited
    for the host: :class:`~dimacq.simulators.daq.clock.RunReport`).
    """

    overflow_samples: int = 0
    overflow_events: int = 0
    loadcell_gaps: list[int] = field(default_factory=list)
    daq_runs: list[dict[str, Any]] = field(default_factory=list)

    @contextmanager
    def recording(self) -> Iterator[HostLag]:
        """Collect the simulated DAQ's run reports of this process into :attr:`daq_runs`."""
        log = logging.getLogger(_RUN_LOG)
        runs = self.daq_runs

        class _Collect(logging.Handler):
            def emit(self, record: logging.LogRecord) -> None:
                r = getattr(record, "run_report", None)
                if r is not None:
                    runs.append(
                        {
                            "simulated_s": r.simulated_s,
                            "wall_s": r.wall_s,
                            "factors": list(r.factors),
                            "waits": r.waits,
                            "adaptive": r.adaptive,
                        }
                    )

        handler = _Collect(logging.DEBUG)
        level = log.level
        log.addHandler(handler)
        if log.getEffectiveLevel() > logging.DEBUG:
            log.setLevel(logging.DEBUG)
        try:
            yield self
        finally:
            log.removeHandler(handler)
            log.setLevel(level)

    @property
    def simulated_s(self) -> float:
        """Simulated seconds of the recorded DAQ runs."""
        return float(sum(float(r["simulated_s"]) for r in self.daq_runs))

    @property
    def daq_wall_s(self) -> float:
        """Wall seconds of the recorded DAQ runs."""
        return float(sum(float(r["wall_s"]) for r in self.daq_runs))

    def factors_used(self) -> list[float]:
        """Every time-lapse factor the recorded runs used, lowest first."""
        return sorted({float(f) for r in self.daq_runs for f in r["factors"]})

    def describe_factors(self) -> str:
        """The recorded runs' factors: what the summary says of the adaptive time-lapse."""
        if not self.daq_runs:
            return "no simulated DAQ run recorded"
        waits = sum(int(r["waits"]) for r in self.daq_runs)
        f = self.factors_used()
        sim, wall = self.simulated_s, self.daq_wall_s
        eff = sim / wall if wall > 0 else 0.0
        used = "/".join(f"{x:g}" for x in f)
        how = (
            f"slowed for the host {waits} time(s), factors used {used}x"
            if waits or len(f) > 1
            else f"at {used}x throughout"
        )
        return (
            f"{len(self.daq_runs)} DAQ runs, {sim:.0f} s simulated in {wall:.1f} s wall "
            f"(effective {eff:.1f}x); {how}"
        )

    def observe(self, event: Mapping[str, object]) -> None:
        """One device event of an impact session (``on_event``)."""
        dev, kind = str(event.get("device", "")), event.get("kind")
        n = event.get("n_samples")
        size = int(n) if isinstance(n, int | float) else 0
        if dev == "daq" and kind == "overflow":
            self.overflow_events += 1
            self.overflow_samples += size
        elif dev.startswith("loadcell") and kind == "gap":
            self.loadcell_gaps.append(size)

    def observe_reasons(self, reasons: Iterable[str]) -> None:
        """The rejection reasons of averages and lost strikes (what the HTTP API reports)."""
        for r in reasons:
            if "FIFO overflow" in r:
                self.overflow_events += 1
                m = re.search(r"DAQ samples lost \((\d+)", r)
                self.overflow_samples += int(m.group(1)) if m else 0
            self.loadcell_gaps += [int(g) for g in _LC_LOST.findall(r)]

    def merge(self, other: HostLag) -> None:
        """Add what ``other`` saw (another process's acquisition, e.g. the demo's step 0)."""
        self.overflow_events += other.overflow_events
        self.overflow_samples += other.overflow_samples
        self.loadcell_gaps += other.loadcell_gaps
        self.daq_runs += other.daq_runs

    @property
    def kept_up(self) -> bool:
        return self.overflow_events == 0 and all(g <= 1 for g in self.loadcell_gaps)

    def describe(self) -> str:
        if self.kept_up:
            return "the host kept up (no DAQ FIFO overflow, no load cell frames dropped)"
        long = [g for g in self.loadcell_gaps if g > 1]
        parts = []
        if self.overflow_events:
            parts.append(
                f"{self.overflow_events} DAQ FIFO overflow(s), {self.overflow_samples} samples"
            )
        if long:
            parts.append(f"{len(long)} load cell gap(s) of {sum(long)} samples")
        return (
            f"the host did NOT keep up ({'; '.join(parts)}): lower "
            "simulation_imperfections.daq_time_scale (DIMACQ_SIMULATION_IMPERFECTIONS)"
        )

    def to_json(self) -> dict[str, object]:
        return {
            "kept_up": self.kept_up,
            "daq_overflow_events": self.overflow_events,
            "daq_overflow_samples": self.overflow_samples,
            "loadcell_gap_samples": list(self.loadcell_gaps),
            "daq_runs": len(self.daq_runs),
            "daq_simulated_s": self.simulated_s,
            "daq_wall_s": self.daq_wall_s,
            "factors_used": self.factors_used(),
            "host_waits": sum(int(r["waits"]) for r in self.daq_runs),
        }


def rig_time_lapse(
    imperfections: Mapping[str, object],
    rig_path: str | Path,
    loadcell: str = "simulated",
    daq: str = "simulated",
) -> TimeLapse:
    """:func:`choose_time_lapse` for the rig file at ``rig_path`` (its DAQ channels, its load
    cells on CAN amplifiers and its sample rate) read through the load cell backend
    ``loadcell`` (its frames per sample: :data:`LOADCELL_FRAMES_PER_SAMPLE`; its highest factor:
    :data:`LOADCELL_MAX_SCALE`) on the DAQ backend ``daq`` (its highest factor:
    :data:`DAQ_MAX_SCALE`)."""
    from dimacq.io.rig_file import load_rig_file

    rig = load_rig_file(rig_path)
    n_channels = len(rig.hammers) + len(rig.responses)
    n_channels += sum(len(e.daq_channels) for e in rig.load_cells if e.node_id is None)
    n_cells = sum(1 for e in rig.load_cells if e.node_id is not None)
    n_cells *= LOADCELL_FRAMES_PER_SAMPLE.get(loadcell, 1)
    return choose_time_lapse(
        imperfections,
        n_channels=n_channels,
        n_cells=n_cells,
        sample_rate_hz=rig.daq.sample_rate_hz,
        max_scale=min(LOADCELL_MAX_SCALE.get(loadcell, 40.0), DAQ_MAX_SCALE.get(daq, 40.0)),
    )
