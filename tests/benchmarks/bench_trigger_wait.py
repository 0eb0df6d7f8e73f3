"""Benchmark: host CPU of the acquisition's trigger wait, target < 0.2 s for a 60 s wait at
10 240 S/s × 64 channels.

Run on demand: ``python tests/benchmarks/bench_trigger_wait.py [rate_hz] [wait_s]``. One
impact average through :class:`~dimacq.services.acquisition.session.ImpactSession` on an in-memory DAQ
(``tests/_block_daq.py``: blocks are preallocated zeros, so the DAQ side costs nothing) whose
hammer hit comes ``wait_s`` seconds after arming; reports the process CPU of the whole run
(trigger wait, record and FRF of one short record) and of a run with no wait, and their
difference: the wait itself. Before the sliding buffer the history grew by ``np.concatenate``
per block (quadratic in the wait).
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from _block_daq import BlockDaq

from dimacq.services.acquisition.session import ImpactSession, ImpactSettings

N_CH, BLOCK = 64, 512


def run(rate_hz: float, wait_s: float) -> float:
    daq = BlockDaq(N_CH, rate_hz, BLOCK)
    settings = ImpactSettings(
        record_samples=2048,
        averages_per_input=1,
        trigger_level_n=20.0,
        block_samples=BLOCK,
        trigger_timeout_samples=int((wait_s + 10) * rate_hz),
    )
    delay = int(wait_s * rate_hz)
    session = ImpactSession(
        daq,
        ["0+X force"],
        list(daq.channel_names[1:]),
        settings=settings,
        operator=lambda j, at: daq.strike(at + delay),
    )
    t0 = time.process_time()
    res = session.run()
    cpu = time.process_time() - t0
    assert res.n_accepted == (1,)
    return cpu


def main() -> None:
    rate = float(sys.argv[1]) if len(sys.argv) > 1 else 10240.0
    wait = float(sys.argv[2]) if len(sys.argv) > 2 else 60.0
    run(rate, 0.0)  # warm-up
    base = min(run(rate, 0.0) for _ in range(3))
    full = min(run(rate, wait) for _ in range(3))
    print(
        f"{rate:g} S/s × {N_CH} channels, {wait:g} s trigger wait ({int(rate * wait)} samples, "
        f"blocks of {BLOCK}): run {full:.3f} s CPU, run without wait {base:.3f} s, "
        f"wait {full - base:.3f} s CPU (target < 0.2 s)"
    )


if __name__ == "__main__":
    main()
