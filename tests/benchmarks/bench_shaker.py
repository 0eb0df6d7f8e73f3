"""Benchmark of shaker excitation in the virtual lab (on demand:
``python tests/benchmarks/bench_shaker.py``).

- raw lab throughput with 2 shakers driving (exact first-order-hold recursion at 4 fs, anti-alias
  filter, every channel) on the calibration mass on bungee and on the X-38;
- a typical shaker test: calibration mass on bungee, 2 shakers, random, 40 Welch averages
  (4096-sample Hann segments, 50 % overlap) at each of 12 shaker positions covering the 24
  inputs, multiple-input H1; and the same with burst random and swept sine.
"""

from __future__ import annotations

import time

import numpy as np

from dimacq.simulators.lab.impact import virtual_lab
from dimacq.simulators.lab.scenarios import build_scenario
from dimacq.simulators.lab.shaker import shaker_test
from dimacq.simulators.lab.timedomain import ShakerSignal


def main() -> None:
    for name in ("calibration-mass-bungee", "x38"):
        b = build_scenario(name)
        lab = virtual_lab(b, n_shakers=2, cache_blocks=64)
        lab.drive(0, 0, ShakerSignal(seed=1, band_limited=True, f_lo_hz=10.0), 0)
        lab.drive(1, 5, ShakerSignal(seed=2, band_limited=True, f_lo_hz=10.0), 0)
        ch = np.arange(len(lab.channel_names))
        n = round(60 * lab.sample_rate_hz)
        t0 = time.perf_counter()
        for start in range(0, n, 8192):
            lab.read(ch, start, 8192)
        dt = time.perf_counter() - t0
        print(
            f"{name}: 60 s of lab time, 2 shakers, {ch.size} channels, {lab._lam.size} poles, "
            f"oversample {lab.oversample}: {dt:.2f} s ({60 / dt:.0f}x real time)"
        )
    b = build_scenario("calibration-mass-bungee")
    for kind in ("random", "burst-random", "swept-sine"):
        t0 = time.perf_counter()
        run = shaker_test(b, excitation=kind, n_shakers=2)
        dt = time.perf_counter() - t0
        print(
            f"shaker test {kind}: 2 shakers x {len(run.groups)} positions, {run.averages} "
            f"averages, {run.samples / b.spec.acquisition.sample_rate_hz:.0f} s of lab time: "
            f"{dt:.2f} s"
        )


if __name__ == "__main__":
    main()
