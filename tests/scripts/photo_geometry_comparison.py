"""Hand-measured, sonic-digitizer and photographed geometry on the same simulated tests: the
geometry's errors against the truth and the errors of the default solve on it.

    python tests/scripts/photo_geometry_comparison.py [--seeds 0 1] [--photos 40]

For each seed of the calibration mass on its bungee: the model FRFs of the true article (0.5 %
noise, the same for all three) solved by the service's defaults (``analyse``) with three setups:

- hand-measured: the true geometry with draws of 2 mm per coordinate, 0.5° per triax, 1° per
  line of action (``nominal_setup``), stating those values (the default ``GeometryUncertainty``);
- sonic digitizer: draws of the digitizer chain's stated accuracy (0.3 mm per coordinate from
  ``config/digitizer/array.toml``'s ``point_m``, 0.1° per triax and 0.2° per line of action, the
  selftest's jig and line-of-action figures), stating them;
- photographs: the whole chain — rendered photos, ``geometry_from_photos``,
  ``apply_to_setup`` — stating what the adjustment states.

Writes ``photo_geometry_comparison.results.txt`` beside this script.
"""

from __future__ import annotations

import argparse
import datetime
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from dimacq.io.tags_file import dump_tags, load_tags
from dimacq.model.setup import GeometryUncertainty, TestSetup
from dimacq.services.geometry.photo_geometry import apply_to_setup, geometry_from_photos
from dimacq.services.solve.analysis import analyse
from dimacq.simulators.camera.render import photograph_article
from dimacq.simulators.camera.scenario import tagged_scenario
from dimacq.simulators.lab.scenarios import build_scenario, nominal_setup

SCENARIO = "calibration-mass-bungee"


def geometry_errors(true: TestSetup, st: TestSetup) -> dict[str, float]:
    rp = np.asarray(st.response_positions) - np.asarray(true.response_positions)
    rd = [
        np.degrees(np.arccos(np.clip(np.dot(a.direction_gcs, b.direction_gcs), -1, 1)))
        for a, b in zip(st.responses, true.responses, strict=True)
    ]
    ip = np.asarray(st.input_positions) - np.asarray(true.input_positions)
    idr = [
        np.degrees(np.arccos(np.clip(np.dot(a.direction_gcs, b.direction_gcs), -1, 1)))
        for a, b in zip(st.excitations, true.excitations, strict=True)
    ]
    return {
        "sensor_mm": 1e3 * float(np.sqrt(np.mean(np.sum(rp**2, axis=1)))),
        "axis_deg": float(np.sqrt(np.mean(np.square(rd)))),
        "input_mm": 1e3 * float(np.sqrt(np.mean(np.sum(ip**2, axis=1)))),
        "loa_deg": float(np.sqrt(np.mean(np.square(idr)))),
    }


def solve_errors(frf, st: TestSetup, truth: dict) -> dict[str, float]:
    rep = analyse(frf, st)
    est = rep.result.properties.to_json(np.asarray(st.reference_point_m))
    pm, pt = np.asarray(est["principal_moments_kgm2"]), np.asarray(truth["principal_moments_kgm2"])
    return {
        "mass_pct": 100 * (est["mass_kg"] - truth["mass_kg"]) / truth["mass_kg"],
        "cg_mm": 1e3 * float(np.linalg.norm(np.subtract(est["cg_m"], truth["cg_m"]))),
        "pm_pct": float(np.max(np.abs(100 * (pm - pt) / pt))),
        "verdict": rep.verdict,
    }


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, nargs="*", default=[0, 1])
    ap.add_argument("--photos", type=int, default=40)
    args = ap.parse_args()
    rows = []
    for seed in args.seeds:
        built = build_scenario(SCENARIO, seed)
        true = built.model.setup
        frf = built.model_frf(noise=0.005)
        truth = built.truth_json()
        errs = built.spec.errors
        hand = nominal_setup(
            true,
            errs.model_copy(
                update={"position_m": 0.002, "orientation_deg": 0.5, "line_of_action_deg": 1.0}
            ),
            seed,
        ).model_copy(update={"geometry_uncertainty": GeometryUncertainty()})
        digi = nominal_setup(
            true,
            errs.model_copy(
                update={"position_m": 3e-4, "orientation_deg": 0.1, "line_of_action_deg": 0.2}
            ),
            seed,
        ).model_copy(
            update={
                "geometry_uncertainty": GeometryUncertainty(
                    sensor_position_m=3e-4,
                    sensor_orientation_deg=0.1 / np.sqrt(3),
                    input_position_m=3e-4,
                    line_of_action_deg=0.2 / np.sqrt(2),
                    source="digitized",
                )
            }
        )
        plan, world = tagged_scenario(built)
        with tempfile.TemporaryDirectory() as tmp:
            photograph_article(world, Path(tmp) / "photos", args.photos, seed + 3000)
            dump_tags(plan, Path(tmp) / "tags.toml")
            res = geometry_from_photos(Path(tmp) / "photos", load_tags(Path(tmp) / "tags.toml"))
        photo = apply_to_setup(true.model_copy(), res)
        for name, st in (
            ("hand-measured", hand),
            ("sonic digitizer", digi),
            ("photographs", photo),
        ):
            row = {"seed": seed, "geometry": name, **geometry_errors(true, st)}
            row.update(solve_errors(frf, st, truth))
            rows.append(row)
            print(row, flush=True)
    commit = subprocess.run(
        ["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True, check=False
    ).stdout.strip()
    lines = [
        f"command: {' '.join(sys.argv)}",
        f"date: {datetime.datetime.now(datetime.UTC).isoformat(timespec='seconds')}",
        f"commit: {commit}; load average: {os.getloadavg()}",
        f"{'geometry':<17}{'seed':>5}{'sensor mm':>10}{'axis deg':>9}{'input mm':>9}"
        f"{'LoA deg':>8}{'mass %':>8}{'CG mm':>7}{'max |I| %':>10}  verdict",
    ]
    for r_ in rows:
        lines.append(
            f"{r_['geometry']:<17}{r_['seed']:>5}{r_['sensor_mm']:>10.3f}{r_['axis_deg']:>9.3f}"
            f"{r_['input_mm']:>9.3f}{r_['loa_deg']:>8.3f}{r_['mass_pct']:>8.3f}{r_['cg_mm']:>7.3f}"
            f"{r_['pm_pct']:>10.3f}  {r_['verdict']}"
        )
    out = Path(__file__).with_suffix(".results.txt")
    out.write_text("\n".join(lines) + "\n", encoding="utf-8")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
