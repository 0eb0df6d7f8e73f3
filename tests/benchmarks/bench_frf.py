"""Benchmark: H1 FRF estimation of 64 outputs x 10 averages x 8192 samples (target < 0.2 s).

Run on demand: ``python tests/benchmarks/bench_frf.py``. Compares with pyFRF (PyPI ``pyfrf``)
in the same run when it is installed, and checks that both give the same H1.
"""

from __future__ import annotations

import statistics
import time

import numpy as np

from dimacq.pipeline.frf_estimation import estimate_frf, exponential_window, force_window

N_OUT, N_AVG, N_S, FS = 64, 10, 8192, 2048.0


def data() -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(0)
    force = rng.standard_normal((N_AVG, 1, N_S))
    resp = rng.standard_normal((N_AVG, N_OUT, N_S)) + force
    return force, resp


def time_it(fn, repeat: int = 7) -> float:
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def main() -> None:
    force, resp = data()
    w = exponential_window(N_S, FS, 1.0)
    wf = force_window(N_S, 64) * w
    t_ours = time_it(lambda: estimate_frf(force, resp, FS))
    t_win = time_it(lambda: estimate_frf(force, resp, FS, input_window=wf, output_window=w))
    t_hv = time_it(lambda: estimate_frf(force, resp, FS, estimator="Hv"), repeat=3)
    print(f"dimacq H1, {N_OUT} outputs x {N_AVG} averages x {N_S} samples: {t_ours * 1e3:.1f} ms")
    print(f"dimacq H1 with force+exponential windows: {t_win * 1e3:.1f} ms")
    print(f"dimacq Hv: {t_hv * 1e3:.1f} ms")
    print(f"target < 200 ms: {'PASS' if t_ours < 0.2 else 'FAIL'}")
    try:
        import pyFRF  # type: ignore[import-not-found]
    except ImportError:
        print("pyFRF not installed (pip install pyfrf) - comparison skipped")
        return

    def run_pyfrf() -> np.ndarray:
        frf = pyFRF.FRF(
            int(FS),
            exc=force,
            resp=resp,
            exc_type="f",
            resp_type="a",
            frf_estimator="H1",
            fft_len=N_S,
        )
        return np.asarray(frf.get_FRF(frf_estimator="H1", frf_form="accelerance"))

    t_py = time_it(run_pyfrf, repeat=3)
    h_py = run_pyfrf()  # (n_out, n_in, n_lines)
    h_ours = estimate_frf(force, resp, FS).H.transpose(1, 2, 0)
    # pyFRF returns NaN at 0 Hz (its accelerance form divides a receptance by ω²): skip DC.
    rel = np.max(np.abs(h_py[..., 1:] - h_ours[..., 1:])) / np.max(np.abs(h_ours))
    print(
        f"pyFRF {pyFRF.__version__ if hasattr(pyFRF, '__version__') else ''} H1 same data: "
        f"{t_py * 1e3:.1f} ms  (dimacq is {t_py / t_ours:.1f}x faster); "
        f"max |H_pyFRF - H_dimacq| / max|H| = {rel:.2e}"
    )


if __name__ == "__main__":
    main()
