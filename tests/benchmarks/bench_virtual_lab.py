"""Benchmark of the virtual lab (run on demand: ``python tests/benchmarks/bench_virtual_lab.py``).

- model FRFs of every bundled scenario (target < 1 s each);
- time data of the calibration-mass scenario: 24 impacts × 5 averages at 2048 S/s, every channel
  (24 accelerometer axes, hammer, 12 gauges, 6 loads), records of 4096 samples plus the
  operator's settling time (target < 10 s); and the whole simulated impact test with the FRF
  estimation.
"""

from __future__ import annotations

import time

import numpy as np

from dimacq.simulators.lab.impact import impact_test, virtual_lab
from dimacq.simulators.lab.scenarios import build_scenario, list_scenarios


def main() -> None:
    print("model FRFs (build scenario + all lines, median of 5):")
    for name in list_scenarios():
        times = []
        for _ in range(5):
            t0 = time.perf_counter()
            frf = build_scenario(name).model_frf()
            times.append(time.perf_counter() - t0)
        print(f"  {name:<27} {frf.H.shape}  {1e3 * np.median(times):7.1f} ms")

    b = build_scenario("calibration-mass-bungee")
    acq = b.spec.acquisition
    for settle_s in (0.0, acq.settle_s):
        lab = virtual_lab(b)
        ch = np.arange(len(lab.channel_names))
        N, settle = acq.record_samples, round(settle_s * lab.sample_rate_hz)
        t0 = time.perf_counter()
        cursor = 0
        for j in range(24):
            for _ in range(5):
                lab.excite(j, cursor + acq.pretrigger_samples)
                lab.read(ch, cursor, N)
                cursor += N + settle
        dt = time.perf_counter() - t0
        print(
            f"time data, 24 impacts x 5 averages at {lab.sample_rate_hz:g} S/s, {ch.size} channels, "
            f"{N}-sample records, settle {settle_s:g} s: {dt:.2f} s "
            f"({cursor / lab.sample_rate_hz:.0f} s of lab time)"
        )
    t0 = time.perf_counter()
    run = impact_test(b)
    print(
        f"whole impact test with FRF estimation (H1, {run.n_strikes} strikes): "
        f"{time.perf_counter() - t0:.2f} s"
    )


if __name__ == "__main__":
    main()
