"""Inertial calibration against other accelerometer certificates (run on demand, ~2 min for
the acquisition, then ~3 s per draw: ``python tests/scripts/inertial_certificate_draws.py
[--draws 60]``).

The matrix error of the inertial bench comes from the accelerometers' certificates (0.5 % 1σ
each, :data:`CERTIFICATE_ERROR` of ``simulated_rig_files.py``): the shipped rig file is one draw.
This script acquires the bench once per scenario seed through the real service
(:func:`~dimacq.services.calibration.inertial_calibration.run_inertial_calibration` on the simulated lab,
over the devices' wires, with the rig file's certificates), then re-runs the same service code on
that acquisition for ``--draws`` other certificate draws: a channel whose certificate is
``c' = true (1 + ε')`` instead of the rig file's ``c`` reads ``c/c'`` times what it read, so
the FRF rows are rescaled, nothing else changes. Per draw: the matrix error against the
simulated cell's ``pinv(S)`` and the reported expanded uncertainty ``matrix_uncertainty_rel``
(k = 2). Prints the error's median / 95th percentile / maximum and the coverage (share of
draws whose error is within the reported uncertainty; ~95 % expected), with the gains
correction and without it (the certificates as they are: the gains never identified).

The scenario's seed is not varied: it also turns the simulated triaxes (``sensor_skew_deg``), so
another seed's world does not match the bench's setup file; the service refuses that
(``MAX_RIGID_RESIDUAL``: the accelerometers do not move as one rigid body with the setup's
geometry), ``--seeds`` shows it.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

import dimacq.services.calibration.inertial_calibration as ic
from dimacq.config import Settings
from dimacq.io.rig_file import load_rig_file
from dimacq.pipeline import inertial_bench
from dimacq.simulators.lab import transducers as tr
from dimacq.simulators.lab.bridge import strain_gauge_cell

CERTIFICATE_ERROR = 0.005


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--draws", type=int, default=200)
    ap.add_argument(
        "--seeds", type=int, nargs="+", default=[0], help="scenario seeds (others: refused)"
    )
    ap.add_argument("--averages", type=int, default=5)
    args = ap.parse_args()
    S = np.asarray(strain_gauge_cell(501).sensitivity_mvv, float)
    C_true = np.linalg.pinv(S)
    rows: dict[str, list[tuple[float, float]]] = {"gains": [], "certificates": []}
    with tempfile.TemporaryDirectory(prefix="dimacq-draws-") as tmp:
        base = Settings(
            daq="simulated",
            loadcell="simulated",
            scenario="calibration-mass-bungee",
            rig_file="",
            data_dir=Path(tmp) / "data",
        )
        settings = ic.scratch_rig(base, Path(tmp) / "rig")
        rig = load_rig_file(settings.rig_path)
        cert = np.array([r.sensitivity_mv_per_g for r in rig.responses])
        true = np.array(
            [
                tr.true_sensitivity(
                    tr.NOMINAL_ACCEL_MV_PER_G,
                    tr.ACCEL_TOLERANCE,
                    tr.accelerometer_serial(r.physical_channel),
                )
                for r in rig.responses
            ]
        )
        n_acc = len(cert)
        original = ic.run_impact_session
        for seed in args.seeds:
            cached: dict[str, Any] = {}

            def once(*a: Any, cached: dict[str, Any] = cached, **kw: Any) -> Any:
                if "res" not in cached:
                    cached["res"] = original(*a, **kw)
                return cached["scaled"](cached["res"])

            ic.run_impact_session = once
            rng = np.random.default_rng([0xD2A3, seed])
            for draw in range(args.draws + 1):
                # draw 0: the rig file's own certificates
                eps = CERTIFICATE_ERROR * rng.standard_normal(n_acc) if draw else None
                factor = np.ones(n_acc) if eps is None else cert / (true * (1 + eps))

                def scaled(res: Any, factor: np.ndarray = factor) -> Any:
                    H = np.array(res.H, copy=True)
                    H[:, :n_acc] *= factor[None, :, None]
                    return dataclasses.replace(res, H=H)

                cached["scaled"] = scaled
                for mode in ("gains", "certificates"):
                    if mode == "certificates":
                        keep = inertial_bench.MAX_SEPARATION
                        inertial_bench.MAX_SEPARATION = -1.0  # gains never identified
                    try:
                        run, _ = ic.run_inertial_calibration(
                            settings,
                            cfg={"seed": seed, "averages_per_input": args.averages},
                            on_progress=lambda f, m: None,
                        )
                    finally:
                        if mode == "certificates":
                            inertial_bench.MAX_SEPARATION = keep
                    err = float(np.linalg.norm(run.matrix - C_true) / np.linalg.norm(C_true))
                    rows[mode].append((err, run.matrix_uncertainty_rel()))
                if draw == 0:
                    e, u = rows["gains"][-1]
                    print(
                        f"seed {seed} ({run.n_inputs} inputs with FRFs), rig file's "
                        f"certificates: error {100 * e:.3f} %, "
                        f"uncertainty (k=2) {100 * u:.3f} %",
                        flush=True,
                    )
            ic.run_impact_session = original
    for mode, r in rows.items():
        e = np.array([x[0] for x in r])
        u = np.array([x[1] for x in r])
        print(
            f"{mode:>12}: {len(e)} runs, matrix error median {100 * np.median(e):.3f} %, 95th "
            f"percentile {100 * np.percentile(e, 95):.3f} %, max {100 * e.max():.3f} %; "
            f"reported uncertainty (k=2) median {100 * np.median(u):.3f} %; error within it in "
            f"{100 * np.mean(e <= u):.1f} % of runs"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
