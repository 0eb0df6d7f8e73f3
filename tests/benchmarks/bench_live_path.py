"""Benchmark: the live path (DAQ driver → blocks → FRF per record) on one core, from a recorded
stream: how many channels at 51.2 kS/s it sustains in real time, and the margin at 128.

A recorded stream (``SECONDS`` of 24-bit frames of ``n`` channels, ``SPF`` samples each, encoded
once with the DAQ codec: a hammer pulse train on channel 0 and decaying responses) is fed to the
driver by a scripted USB device that answers each bulk read with the next frame, as fast as the
host asks (the device is never the limit). The host does what the acquisition does per record:
the driver reads ``RECORD`` samples (header check, CRC-32, 24-bit unpack, scaling, overload
bookkeeping) into a block, and the record's FRFs are estimated (H1, force and exponential
windows: :func:`dimacq.pipeline.frf_estimation.estimate_frf`, one FFT thread; its sums in numpy
until the process has summed ``NUMPY_SUMS_BUDGET`` products (15 s of stream at 128 channels),
then compiled: a short count measures mostly the slower numpy sums). The process is pinned to
one core; the figures are

    realtime factor = simulated seconds / CPU seconds        (and / wall seconds)

for each channel count; the most channels sustained is the largest count with a factor ≥ 1
(interpolated between the counts measured, the cost being about linear in the channels), and
the margin at 128 channels is its factor. Written to ``bench_live_path_results.md`` beside this
script (``--results`` elsewhere) with the command, date, commit, load and this host's sustainable
time-lapse.

    python tests/benchmarks/bench_live_path.py [--channels 32 64 128 192 256] [--seconds 4]
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np
import usb.core

from dimacq.drivers.daq import protocol as p
from dimacq.drivers.daq.driver import DaqDevice, DaqTask
from dimacq.pipeline.frf_estimation import estimate_frf, exponential_window, force_window

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))
from _results import Results, add_results_argument  # noqa: E402

FS = 51200
SPF = 512
RECORD = 4096


class _Ctx:
    def dispose(self, device: object) -> None:
        return None


class RecordedUsb:
    """A DAQ answering bulk reads with the frames of a recorded stream, in order (encoded
    before the run: the device's work is not the host's)."""

    def __init__(self, counts: np.ndarray, n_ch: int) -> None:
        self.counts = counts
        self.n_ch = n_ch
        self.n_frames = counts.shape[0] // SPF
        self.frames = [
            p.encode_frame(i, i * SPF, counts[i * SPF : (i + 1) * SPF])
            for i in range(self.n_frames)
        ]
        self.i = 0
        self.running = False
        self._ctx = _Ctx()

    def set_configuration(self) -> None:
        return None

    def ctrl_transfer(self, bm, req, value, index, data, timeout):  # type: ignore[no-untyped-def]
        if req == p.Request.IDENTIFY:
            return p.DeviceIdentity(1, self.n_ch, FS, 24, 5, "BENCH", "1").encode()
        if req == p.Request.GET_STATUS:
            return p.DeviceStatus(False, False, float(FS), 0, 0).encode()
        if req in (p.Request.START, p.Request.STOP):
            self.running = req == p.Request.START
        return 0

    def read(self, ep, size, timeout):  # type: ignore[no-untyped-def]
        if not self.running or self.i >= self.n_frames:  # nothing in the FIFO
            raise usb.core.USBTimeoutError("Operation timed out", error_code=-7, errno=110)
        f = self.frames[self.i]
        self.i += 1
        return f


def recorded_stream(n_ch: int, seconds: float) -> np.ndarray:
    """Counts of a hammer pulse every record on channel 0 and decaying responses on the rest."""
    n = int(seconds * FS) // SPF * SPF
    rng = np.random.default_rng(1)
    t = np.arange(n) / FS
    pulse = np.zeros(n)
    pulse[RECORD // 8 :: RECORD] = 1.0
    kernel = np.exp(-np.arange(64) / 8.0)
    hammer = np.convolve(pulse, kernel)[:n]
    resp = np.convolve(pulse, np.exp(-np.arange(2048) / 400.0) * np.sin(np.arange(2048) / 9.0))[:n]
    x = np.empty((n, n_ch))
    x[:, 0] = hammer
    x[:, 1:] = resp[:, None] * rng.uniform(0.2, 1.0, n_ch - 1) + 1e-3 * rng.standard_normal(
        (n, n_ch - 1)
    )
    x += 1e-4 * np.sin(2 * np.pi * 50 * t)[:, None]
    return np.rint(x / np.abs(x).max() * 0.5 * 2**23).astype(np.int32)


def run(n_ch: int, seconds: float) -> tuple[float, float]:
    """Simulated seconds per CPU second and per wall second of the live path on ``n_ch``."""
    usb = RecordedUsb(recorded_stream(n_ch, seconds), n_ch)
    task = DaqTask(DaqDevice(usb))
    task.add_force_channel(0, "hammer", 2.25)
    for k in range(1, n_ch):
        task.add_accel_channel(k, f"a{k}", 100.0)
    task.configure_timing(FS, SPF)
    w_in = force_window(RECORD, RECORD // 8 + 200)
    w_out = exponential_window(RECORD, FS, 0.5 * RECORD / FS)
    n_records = int(seconds * FS) // RECORD
    task.start()
    try:
        c0, t0 = time.process_time(), time.perf_counter()
        for _ in range(n_records):
            block = task.read(RECORD)
            estimate_frf(
                block.data[:1],
                block.data[1:],
                FS,
                input_window=w_in * w_out,
                output_window=w_out,
            )
        cpu, wall = time.process_time() - c0, time.perf_counter() - t0
    finally:
        task.stop()
    sim = n_records * RECORD / FS
    return sim / cpu, sim / wall


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--channels", type=int, nargs="+", default=[32, 64, 128, 192, 256])
    ap.add_argument("--seconds", type=float, default=4.0, help="simulated seconds per count")
    add_results_argument(ap, __file__)
    args = ap.parse_args()
    res = Results(
        __file__, "Live path: DAQ driver → blocks → FRF per record, one core", args.results
    )
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})
    from dimacq.backends.time_lapse import measure_host

    def host() -> str:
        load = os.getloadavg()
        m = measure_host(30, 1, 51200.0)
        return (
            f"load average {load[0]:.2f} / {load[1]:.2f} / {load[2]:.2f} on "
            f"{os.cpu_count()} cores; this host sustains about {m.sustainable_scale:.1f}x "
            "time-lapse now"
        )

    res.note(f"at start: {host()}")
    res.note(
        f"stream: 24-bit frames of {SPF} samples at {FS} S/s, records of {RECORD} samples, "
        "H1 with force and exponential windows per record"
    )
    lines = [
        "| channels | realtime factor (CPU) | realtime factor (wall) |",
        "|---|---|---|",
    ]
    got = []
    run(args.channels[0], 0.5)  # warm-up: first FFT plans, imports
    for n in args.channels:
        cpu_f, wall_f = run(n, args.seconds)
        got.append((n, cpu_f, wall_f))
        lines.append(f"| {n} | {cpu_f:.2f} | {wall_f:.2f} |")
        print(lines[-1], flush=True)
    ch = np.array([g[0] for g in got], float)
    f = np.array([g[1] for g in got])
    # cost per simulated second ~ linear in channels: 1/f = a + b·n; sustained where 1/f = 1
    b, a = np.polyfit(ch, 1 / f, 1)
    most = (1 - a) / b if b > 0 else float("inf")
    at128 = 1 / (a + b * 128)
    lines += [
        "",
        f"- most channels sustained at {FS} S/s in real time on one core (CPU, linear fit of "
        f"cost against channels): about {most:.0f}",
        f"- margin at 128 channels: {at128:.2f}x real time (CPU)",
        f"- at end: {host()}",
    ]
    res.add("\n".join(lines))
    print("\n".join(lines[-3:]))
    res.write()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
