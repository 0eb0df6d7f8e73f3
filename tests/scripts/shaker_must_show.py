"""Issue 3 "must show" figures for shaker excitation (on demand:
``python tests/scripts/shaker_must_show.py``).

Calibration mass on bungee, scenario noise, 2 shakers, random, 40 Welch averages per shaker
position (12 positions, 24 inputs), multiple-input H1, through the command line:
``dimacq simulate calibration-mass-bungee --time-domain --excitation random --shakers 2`` then
``dimacq solve`` in the scenario's band.

1. FRF agreement with the model ``H(iω)`` in the band where the multiple coherence exceeds 0.99:
   pointwise relative error ``|Ĥ − H| / |H|`` (median, 95th, 99th percentile, max), and the error
   relative to the output's level over the run's inputs ``sqrt(Σ_j |H_oj|²)`` (the scale of the
   multiple-input H1's error, which does not shrink with a small element).
2. DIM solution: mass and principal moments (%), CG (mm).
3. The same for burst random and swept sine (FRF agreement only, figures for information).
"""

from __future__ import annotations

import contextlib
import io
import json
import tempfile
import time
from pathlib import Path

import numpy as np

from dimacq.cli.main import main as cli
from dimacq.simulators.lab.scenarios import build_scenario
from dimacq.simulators.lab.shaker import shaker_test

NAME = "calibration-mass-bungee"


def agreement(kind: str) -> str:
    """FRF agreement of the same (deterministic) shaker test the command line ran."""
    b = build_scenario(NAME)
    frf = shaker_test(b, excitation=kind, n_shakers=2).frf
    ref = b.model.frf(frf.frequencies_hz).H
    lo, hi = b.band_hz
    band = (frf.frequencies_hz >= lo) & (frf.frequencies_hz <= hi)
    h, r = frf.H[band], ref[band]
    assert frf.coherence is not None
    coh = frf.coherence[band] > 0.99
    rel = (np.abs(h - r) / np.abs(r))[coh]
    row = np.sqrt(np.sum(np.abs(r) ** 2, axis=2, keepdims=True))
    per_row = (np.abs(h - r) / row)[coh]
    n_acc = len(b.setup.responses)
    acc = (np.abs(h - r) / np.abs(r))[:, :n_acc][coh[:, :n_acc]]
    return (
        f"coherence > 0.99 on {coh.mean():.1%} of FRF points in {lo:g}–{hi:g} Hz; "
        f"|dH|/|H| median {np.median(rel):.2e}, 95% {np.percentile(rel, 95):.2e}, "
        f"99% {np.percentile(rel, 99):.2e}, max {rel.max():.2e}; within 1 %: "
        f"{np.mean(rel < 0.01):.2%} (accelerometers {np.mean(acc < 0.01):.2%}); "
        f"|dH|/output level max {per_row.max():.2e}"
    )


def main() -> None:
    tmp = Path(tempfile.mkdtemp())
    for kind in ("random", "burst-random", "swept-sine"):
        uff, truth, sol = tmp / f"{kind}.uff", tmp / "truth.json", tmp / f"{kind}.json"
        t0 = time.perf_counter()
        args = ["simulate", NAME, "--time-domain", "--excitation", kind, "--shakers", "2"]
        with contextlib.redirect_stdout(io.StringIO()):
            assert cli([*args, "--frf", str(uff), "--truth", str(truth)]) == 0
        dt = time.perf_counter() - t0
        t = json.loads(truth.read_text())
        lo, hi = t["recommended"]["band_hz"]
        with contextlib.redirect_stdout(io.StringIO()):
            assert cli(["solve", str(uff), "--band", str(lo), str(hi), "--json", str(sol)]) == 0
        s = json.loads(sol.read_text())
        pm = np.array(s["principal_moments_kgm2"]) / np.array(t["principal_moments_kgm2"]) - 1
        print(f"\n=== {kind}: simulate {dt:.1f} s")
        print("  FRFs: " + agreement(kind))
        print(
            f"  DIM {lo:g}–{hi:g} Hz: mass {100 * (s['mass_kg'] / t['mass_kg'] - 1):+.4f} %, "
            f"CG error {1e3 * np.abs(np.array(s['cg_m']) - t['cg_m']).max():.4f} mm, principal "
            f"moments {', '.join(f'{100 * x:+.4f}' for x in pm)} %"
        )


if __name__ == "__main__":
    main()
