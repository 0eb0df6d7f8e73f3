"""Benchmark: the CAN FD load cell stream at a time-lapse, simulator and driver in one process.

Run on demand: ``python tests/benchmarks/bench_loadcell_stream.py [SCALE ...]``. The amplifier
simulator counts a free-running SYNC clock (2048 S/s × SCALE) and sends its frames on python-can's
``virtual`` bus (one CAN FD frame per sample, a heartbeat every 256); the real driver reads them
back in 512-sample blocks, as an impact session does, for ``SECONDS`` of wall time. Printed per
time-lapse: the process CPU per simulated second and per frame (simulator and driver together,
user + sys), the wall time, the samples the driver got and the samples it reported lost (a
counter gap: the simulator fell behind and dropped its backlog, or the driver fell behind).
The time-lapse is sustained when nothing is lost and the CPU per wall second stays well under
one core (the simulator and the driver share the GIL with the DAQ path and the service).
"""

from __future__ import annotations

import logging
import os
import sys
import time

import can
import numpy as np
from numpy.typing import NDArray

from dimacq.drivers.loadcell.driver import LoadCellAmplifier
from dimacq.simulators.daq.clock import SampleClock
from dimacq.simulators.loadcell.amplifier import LoadCellAmplifierSim

FS = 2048.0
BLOCK = 512
SECONDS = 3.0


class _Gauges:
    """12 gauge channels of small noise (volts), the same samples for the same counters."""

    sample_rate_hz = FS
    channel_names = tuple(f"g{k:02d}" for k in range(12))
    channel_units = ("V",) * 12

    def read(self, channels: NDArray[np.intp], start: int, n: int) -> NDArray[np.float64]:
        t = np.arange(start, start + n) / FS
        return 1e-3 * np.sin(2 * np.pi * 7.0 * t)[None, :] * (1 + channels[:, None])

    def excite(self, input_index: int, at_sample: int) -> None:
        return None


def run(scale: float, seconds: float = SECONDS) -> dict[str, float]:
    clock = SampleClock()
    name = f"bench-lc-{os.getpid()}-{scale:g}"
    sim = LoadCellAmplifierSim(name, _Gauges(), list(range(12)), clock=clock)
    bus = can.Bus(interface="virtual", channel=name, fd=True)
    try:
        amp = LoadCellAmplifier(bus, timeout_s=5.0)
        amp.set_rate(int(FS))
        amp.start(external_clock=True)
        c0, t0 = time.process_time(), time.perf_counter()
        clock.start(0, FS, wall_scale=scale)
        end, got, lost = BLOCK, 0, 0
        while time.perf_counter() - t0 < seconds:
            # the session's pace: a block once the DAQ has clocked it
            while clock.count() < end:
                time.sleep(0.001)
            blk = amp.read_until(end, timeout_s=5.0)
            got += blk.gauges_v.shape[1]
            lost += int((~blk.valid).sum())
            end += BLOCK
        wall = time.perf_counter() - t0
        cpu = time.process_time() - c0
        clock.stop()
        amp.stop()
    finally:
        sim.close()
        bus.shutdown()
    sim_s = got / FS
    return {
        "scale": scale,
        "wall_s": wall,
        "achieved": sim_s / wall,
        "cpu_per_sim_s_ms": 1e3 * cpu / sim_s,
        "cpu_per_frame_us": 1e6 * cpu / got,
        "cpu_per_wall_s": cpu / wall,
        "got": got,
        "lost": lost,
    }


def main(argv: list[str]) -> None:
    logging.basicConfig(level=logging.ERROR)
    scales = [float(a) for a in argv] or [4.0, 20.0, 40.0, 80.0]
    print(
        f"{'time-lapse':>10} {'achieved':>9} {'CPU ms/sim s':>13} {'CPU µs/frame':>13} "
        f"{'CPU/wall':>9} {'samples':>8} {'lost':>6}"
    )
    for s in scales:
        r = run(s)
        print(
            f"{r['scale']:>9g}x {r['achieved']:>8.1f}x {r['cpu_per_sim_s_ms']:>13.1f} "
            f"{r['cpu_per_frame_us']:>13.2f} {r['cpu_per_wall_s']:>9.2f} {r['got']:>8d} "
            f"{r['lost']:>6d}"
        )


if __name__ == "__main__":
    main(sys.argv[1:])
