"""Issue 3 "must show" figures of the virtual lab (run on demand:
``python tests/scripts/virtual_lab_must_show.py``).

1. Rigid-only model FRFs of every scenario, written to UFF, read back and solved by the DIM
   solver: largest relative error of the ten properties (mass; CG / structure size; inertia /
   largest principal moment).
2. With the elastic modes (x38) in the recommended band, response selection on: same errors and
   the principal moments.
3. Impact test from simulated time data (calibration mass, scenario noise, 5 averages): FRF
   agreement with the model ``H(iω + 1/τ)`` where the coherence exceeds 0.99 — pointwise relative
   error and error relative to each FRF's RMS level — and the DIM solution in the band: mass and
   principal moments (%), CG (mm).
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np

from dimacq.io.uff import read_uff_test, write_uff_test
from dimacq.pipeline import dim
from dimacq.simulators.lab.impact import impact_test
from dimacq.simulators.lab.scenarios import build_scenario, list_scenarios


def errors(res: dim.DimResult, truth, size: float) -> tuple[float, float, float]:
    p = res.reference_point_m
    it = truth.inertia_about(p)
    return (
        abs(res.mass_kg / truth.mass_kg - 1),
        float(np.abs(res.cg_m - truth.cg_m).max() / size),
        float(np.abs(res.inertia_p_kgm2 - it).max() / np.linalg.eigvalsh(it).max()),
    )


def main() -> None:
    tmp = Path(tempfile.mkdtemp())
    print("1. rigid-only model FRFs -> UFF -> DIM (max rel. error m, CG/size, I/I_max)")
    for name in list_scenarios():
        b = build_scenario(name)
        write_uff_test(tmp / "t.uff", b.setup, b.model_frf(rigid_only=True))
        setup, frf = read_uff_test(tmp / "t.uff")
        size = float(np.ptp(setup.response_positions, axis=0).max())
        e = errors(dim.solve(frf, setup, band_hz=b.band_hz), b.truth, size)
        print(f"   {name:<27} {e[0]:.1e} {e[1]:.1e} {e[2]:.1e}")

    print("2. x38 with its elastic modes, recommended band, chute triaxes left out")
    b = build_scenario("x38")
    frf = b.model_frf()
    keep = np.array(
        [i for i, c in enumerate(frf.outputs) if c.node not in b.spec.analysis.exclude_nodes]
    )
    setup = b.setup.model_copy(
        update={
            "responses": tuple(
                c for c in b.setup.responses if c.node not in b.spec.analysis.exclude_nodes
            )
        }
    )
    res = dim.solve(frf.select(keep), setup, band_hz=b.band_hz)
    e = errors(res, b.truth, 9.0)
    pm = (
        np.linalg.eigvalsh(res.properties.inertia_cg_kgm2)
        / np.linalg.eigvalsh(b.truth.inertia_cg_kgm2)
        - 1
    )
    print(
        f"   band {b.band_hz} Hz: m {100 * e[0]:.3f} %, CG/size {100 * e[1]:.3f} %, "
        f"I/I_max {100 * e[2]:.3f} %, principal moments {np.round(100 * pm, 3)} %"
    )

    print("3. calibration mass, impact test from time data (scenario noise, 5 averages)")
    for name in ("calibration-mass-bungee", "calibration-mass-air-ride", "calibration-mass-ground"):
        b = build_scenario(name)
        run = impact_test(b)
        frf = run.frf
        ref = b.model.transfer(2j * np.pi * frf.frequencies_hz + 1 / run.exponential_tau_s)
        lo, hi = b.band_hz
        band = (frf.frequencies_hz >= lo) & (frf.frequencies_hz <= hi)
        for kind in ("acceleration", "reaction"):
            idx = frf.output_index(kind)
            h, r, c = frf.H[band][:, idx], ref[band][:, idx], frf.coherence[band][:, idx]
            ok = c > 0.99
            if not ok.any():
                print(f"   {name} {kind}: no line with coherence > 0.99 in {lo:g}-{hi:g} Hz")
                continue
            rel = np.abs(h - r) / np.abs(r)
            lev = np.abs(h - r) / np.sqrt(np.mean(np.abs(r) ** 2, axis=0, keepdims=True))
            print(
                f"   {name} {kind:<12} coh>0.99 on {100 * ok.mean():5.1f} % of values in band; there "
                f"pointwise rel. error median {np.median(rel[ok]):.1e}, "
                f"{100 * np.mean(rel[ok] < 0.01):.1f} % within 1 %, max {rel[ok].max():.2e}; "
                f"error / FRF rms level max {lev[ok].max():.1e}"
            )
        res = dim.solve(frf, b.setup, band_hz=b.band_hz)
        t = b.truth
        pm = (
            np.linalg.eigvalsh(res.properties.inertia_cg_kgm2)
            / np.linalg.eigvalsh(t.inertia_cg_kgm2)
            - 1
        )
        print(
            f"   {name} DIM {lo:g}-{hi:g} Hz: mass {100 * (res.mass_kg / t.mass_kg - 1):+.3f} %, "
            f"CG {1e3 * np.abs(res.cg_m - t.cg_m).max():.3f} mm, principal moments "
            f"{np.round(100 * pm, 3)} %"
        )


if __name__ == "__main__":
    main()
