"""Issue 4 "must show": selection rates over seeded trials on the forward model's calibration mass.

Run: ``python tests/scripts/selection_rates.py [--trials 100]``

Scenarios (FRFs from ``dimacq.simulators.lab.forward.calibration_mass`` with the *true* geometry,
the solver given the nominal one; 1 % noise on every FRF; 20–200 Hz, bungee support with its load
cell):

A. 0.5° random orientation errors on every triax and 2 of 24 channels mis-oriented by ≥ 20°:
   rate of "response selection removes exactly the two bad channels", and of "afterwards mass within
   0.5 %, CG within 1 mm, principal moments within 1 %".
B. 2 of 24 inputs corrupted (30° line of action, 3 cm position) on top of 0.5° triax errors: rate of
   "the jackknife removes both" (and of "exactly both").
C. 3° random orientation errors on every triax: orientation repair; largest remaining
   angle between repaired and true channel directions.
D. Clean data (1 % noise; and 1 % noise + 0.5° triax errors): false removals with both selections.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from _selection_support import forward_case

from dimacq.pipeline.selection._common import response_geometry
from dimacq.pipeline.selection.orientation import estimate_orientation_frf
from dimacq.services.solve.analysis import AnalysisOptions, analyse


def _accuracy(report, truth) -> tuple[bool, float, float, float]:  # type: ignore[no-untyped-def]
    r = report.result
    dm = abs(r.mass_kg - truth.mass_kg) / truth.mass_kg * 100
    dc = float(np.linalg.norm(r.cg_m - truth.cg_m)) * 1000
    w = np.linalg.eigvalsh(r.inertia_cg_kgm2)
    w0 = np.linalg.eigvalsh(truth.inertia_cg_kgm2)
    dp = float(np.max(np.abs(w - w0) / w0)) * 100
    return (dm <= 0.5 and dc <= 1.0 and dp <= 1.0), dm, dc, dp


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trials", type=int, default=100)
    args = ap.parse_args(argv)
    n = args.trials
    t0 = time.perf_counter()

    # A ------------------------------------------------------------------------------------
    exact = acc = 0
    worst = [0.0, 0.0, 0.0]
    for s in range(n):
        c = forward_case(s, triax_error_deg=0.5, bad_channel_deg=20.0, n_bad_channels=2)
        rep = analyse(c.frf, c.nominal, AnalysisOptions(select_responses=True))
        got = {(e["node"], e["direction"]) for e in rep.excluded_responses}
        ok_sel = got == set(c.bad_channels)
        exact += ok_sel
        ok, dm, dc, dp = _accuracy(rep, c.truth)
        acc += ok
        worst = [max(worst[0], dm), max(worst[1], dc), max(worst[2], dp)]
        if not ok_sel:
            print(f"  A seed {s}: removed {sorted(got)}, bad {sorted(c.bad_channels)}")
    print(f"A. bad channels removed exactly: {exact}/{n}")
    print(
        f"   afterwards mass ≤ 0.5 %, CG ≤ 1 mm, principal moments ≤ 1 %: {acc}/{n} "
        f"(worst: mass {worst[0]:.3f} %, CG {worst[1]:.3f} mm, principal {worst[2]:.3f} %)"
    )

    # B ------------------------------------------------------------------------------------
    both = exact_in = 0
    for s in range(n):
        c = forward_case(1000 + s, triax_error_deg=0.5, n_bad_inputs=2)
        rep = analyse(c.frf, c.nominal, AnalysisOptions(select_inputs=True))
        got = {(e["node"], e["direction"]) for e in rep.excluded_inputs}
        both += set(c.bad_inputs) <= got
        exact_in += got == set(c.bad_inputs)
        if got != set(c.bad_inputs):
            print(f"  B seed {1000 + s}: removed {sorted(got)}, bad {sorted(c.bad_inputs)}")
    print(f"B. jackknife removes both corrupted inputs: {both}/{n} (exactly both: {exact_in}/{n})")

    # C ------------------------------------------------------------------------------------
    below = 0
    worst_after, worst_before = 0.0, 0.0
    for s in range(n):
        c = forward_case(2000 + s, triax_error_deg=3.0)
        rep_o, geo = estimate_orientation_frf(c.frf, c.nominal)
        true_geo = response_geometry(c.frf, c.true)
        cosang = np.sum(rep_o.corrected_directions * true_geo.directions, axis=1)
        after = float(np.degrees(np.arccos(np.clip(cosang, -1, 1))).max())
        cos0 = np.sum(geo.directions * true_geo.directions, axis=1)
        before = float(np.degrees(np.arccos(np.clip(cos0, -1, 1))).max())
        below += after < 0.3
        worst_after, worst_before = max(worst_after, after), max(worst_before, before)
    print(
        f"C. orientation repair, 3° errors: largest channel error below 0.3° in {below}/{n} "
        f"(worst before {worst_before:.2f}°, worst after {worst_after:.3f}°)"
    )

    # D ------------------------------------------------------------------------------------
    for label, deg in (("1 % noise", 0.0), ("1 % noise + 0.5° triax errors", 0.5)):
        fr_resp = fr_in = 0
        for s in range(n):
            c = forward_case(3000 + s, triax_error_deg=deg)
            rep = analyse(
                c.frf, c.nominal, AnalysisOptions(select_responses=True, select_inputs=True)
            )
            fr_resp += len(rep.excluded_responses)
            fr_in += len(rep.excluded_inputs)
        print(
            f"D. clean data ({label}): false removals {fr_resp} channels, {fr_in} inputs "
            f"in {n} trials"
        )
    print(f"total time {time.perf_counter() - t0:.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
