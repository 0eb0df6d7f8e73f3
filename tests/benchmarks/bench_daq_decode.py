"""Benchmark: DAQ frame decoding, target ≥ 20x the data rate of 64 channels at 51.2 kS/s, 24-bit.

Run on demand: ``python tests/benchmarks/bench_daq_decode.py``. Measures the driver's own path
(header check, CRC-32, 24-bit unpack, scaling to engineering units, overload bookkeeping) on
frames of 64 channels x 512 samples, fed by a scripted USB device that returns prepared frames.
"""

from __future__ import annotations

import time

import numpy as np

from dimacq.drivers.daq import protocol as p
from dimacq.drivers.daq.driver import DaqDevice, DaqTask

N_CH, SPF, FS, SECONDS = 64, 512, 51200, 2.0


class _Ctx:
    def dispose(self, device: object) -> None:
        return None


class PreparedUsb:
    """Answers control requests like an idle device and bulk reads with prepared frames."""

    def __init__(self, frames: list[bytes]) -> None:
        self.frames = frames
        self.i = 0
        self._ctx = _Ctx()

    def set_configuration(self) -> None:
        return None

    def ctrl_transfer(self, bm, req, value, index, data, timeout):  # type: ignore[no-untyped-def]
        if req == p.Request.IDENTIFY:
            return p.DeviceIdentity(1, N_CH, FS, 24, 5, "BENCH", "1").encode()
        if req == p.Request.GET_STATUS:
            return p.DeviceStatus(False, False, float(FS), 0, 0).encode()
        return 0

    def read(self, ep, size, timeout):  # type: ignore[no-untyped-def]
        f = self.frames[self.i % len(self.frames)]
        self.i += 1
        return f


def main() -> None:
    rng = np.random.default_rng(0)
    n_frames = int(SECONDS * FS / SPF)
    frames = [
        p.encode_frame(
            i, i * SPF, rng.integers(-(2**23) + 1, 2**23 - 1, (SPF, N_CH)).astype(np.int32)
        )
        for i in range(n_frames)
    ]
    best = np.inf
    for _ in range(5):
        task = DaqTask(DaqDevice(PreparedUsb(frames)))
        for k in range(N_CH):
            task.add_accel_channel(k, f"ch{k}", 100.0)
        task.configure_timing(FS, SPF)
        task.start()
        t0 = time.perf_counter()
        block = task.read(n_frames * SPF)
        best = min(best, time.perf_counter() - t0)
    assert block.data.shape == (N_CH, n_frames * SPF)
    realtime = SECONDS / best
    mb = n_frames * p.frame_size(SPF, N_CH) / best / 1e6
    print(
        f"decode {SECONDS:g} s of {N_CH} ch @ {FS} S/s (24-bit, {SPF} samples/frame) "
        f"in {best * 1e3:.1f} ms: {realtime:.0f}x realtime, {mb:.0f} MB/s of frames"
    )
    print(f"target >= 20x realtime: {'PASS' if realtime >= 20 else 'FAIL'}")


if __name__ == "__main__":
    main()
