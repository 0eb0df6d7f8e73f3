"""CPU of an impact acquisition through each simulated load cell backend (same world, DAQ and
strikes): ``python tests/benchmarks/bench_loadcell_cpu.py [backend ...] [--results PATH]``.

Four inputs × two averages × 4096 samples of the calibration mass; prints wall time and the
process's user + sys CPU per backend (the machine is shared: compare CPU, not wall time), and
writes them to ``bench_loadcell_cpu_results.md`` beside this script (``--results`` elsewhere)
with the command, date, commit and machine load.
"""

from __future__ import annotations

import argparse
import logging
import resource
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from _results import Results, add_results_argument

from dimacq.config import load_settings
from dimacq.services.acquisition import rig as rig_builder
from dimacq.simulators.lab.scenarios import build_scenario


def cpu_s() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def run(backend: str, data: Path) -> tuple[float, float]:
    settings = load_settings(data_dir=data / backend, token="t", loadcell=backend)
    setup = build_scenario(settings.scenario).model.setup
    setup = setup.model_copy(update={"excitations": setup.excitations[:4]})
    cfg = {"averages_per_input": 2, "record_samples": 4096, "seed": 4}
    rig = rig_builder.build_rig(settings, setup, cfg)
    c0, t0 = cpu_s(), time.perf_counter()
    try:
        rig_builder.run_impact_test(
            rig, setup, cfg, on_average=lambda *a: None, on_progress=lambda f, m: None
        )
    finally:
        rig.close()
    return time.perf_counter() - t0, cpu_s() - c0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "backends",
        nargs="*",
        default=["simulated", "cia404-simulated", "canopen-simulated"],
        help="load cell backends (default: simulated, cia404-simulated, canopen-simulated)",
    )
    add_results_argument(ap, __file__)
    args = ap.parse_args()
    res = Results(__file__, "CPU of an acquisition through each simulated load cell", args.results)
    res.note("four inputs × two averages × 4096 samples of the calibration mass, one process")
    logging.basicConfig(level=logging.ERROR)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for b in args.backends:
            wall, cpu = run(b, Path(tmp))
            print(f"{b:20s} wall {wall:5.1f} s  cpu (user+sys) {cpu:5.1f} s")
            rows.append((f"`{b}`", f"{wall:.1f}", f"{cpu:.1f}"))
    res.table(["load cell backend", "wall s", "CPU s (user + sys)"], rows)
    res.write()


if __name__ == "__main__":
    main()
