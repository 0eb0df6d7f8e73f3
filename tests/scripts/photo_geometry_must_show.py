"""Photographed geometry against the simulator's truth: rendered photo sets of the calibration
mass and the X-38 (several seeds), triax position and orientation errors and how often the
stated uncertainties cover them.

    python tests/scripts/photo_geometry_must_show.py [--photos N] [--seeds 0 1 2] [--x38-seeds 0]
        [--x38-photos N]

Each set is photographed by the simulated photographer's plan
(:func:`dimacq.simulators.camera.render.photograph_article`) with the camera it gives the article
(:func:`~dimacq.simulators.camera.render.camera_for`).

``--exact-tags`` renders the same worlds with every tag placed exactly on its body (the tags file
still states its placement 1σ): the difference to a run without it is what the tags' placement
adds to the errors.

Coverage: each triax's error per coordinate against ``1.96 σ`` (``origin_std_m``) and its
rotation error per sensor axis against ``1.96 σ`` (``angle_std_deg``); the fraction inside.
"named": tags the run names as glued off their stated place (none is, in these worlds: each
tag is placed within its stated 1σ). The last line pools the coverage over every set (each set
has only 48 errors, so one set's share scatters by about ±3 % around the pooled one).
Appends to ``photo_geometry_must_show.results.txt`` beside this script (command, date, commit,
load) one block per run.
"""

from __future__ import annotations

import argparse
import datetime
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from dimacq.io.tags_file import dump_tags, load_tags
from dimacq.services.geometry.photo_geometry import geometry_from_photos
from dimacq.simulators.camera.render import photograph_article
from dimacq.simulators.camera.scenario import tagged_scenario
from dimacq.simulators.lab.scenarios import build_scenario


def one(scenario: str, seed: int, n_photos: int, exact_tags: bool = False) -> dict[str, float]:
    plan, world = tagged_scenario(build_scenario(scenario, seed), exact_tags=exact_tags)
    with tempfile.TemporaryDirectory() as tmp:
        photograph_article(world, Path(tmp) / "photos", n_photos, seed + 3000)
        dump_tags(plan, Path(tmp) / "tags.toml")
        t0 = time.perf_counter()
        res = geometry_from_photos(Path(tmp) / "photos", load_tags(Path(tmp) / "tags.toml"))
        solve_s = time.perf_counter() - t0
    pos, ang, axes, inside = [], [], [], []
    for o in res.orientations:
        r_true, p_true = world.truth[f"triax {o.node}"]
        e = np.array(o.origin_m) - p_true
        pos.append(float(np.linalg.norm(e)))
        rot = Rotation.from_matrix(np.array(o.rotation) @ r_true.T)
        ang.append(float(np.degrees(rot.magnitude())))
        per_axis = np.degrees(np.array(o.rotation).T @ rot.as_rotvec())
        axes.extend(per_axis)
        inside.extend(np.abs(e) <= 1.96 * o.origin_std_m)
        inside.extend(np.abs(per_axis) <= 1.96 * np.asarray(o.angle_std_deg))
    return {
        "inside": float(np.sum(inside)),
        "n_errors": float(len(inside)),
        "named": float(sum("off its stated place" in i.problem for i in res.issues)),
        "triaxes": len(res.orientations),
        "unfixed": len(res.unfixed),
        "sigma_px": res.bundle.sigma_px,
        "pos_rms_mm": 1e3 * float(np.sqrt(np.mean(np.square(pos)))) if pos else float("nan"),
        "ori_rms_deg": float(np.sqrt(np.mean(np.square(ang)))) if ang else float("nan"),
        "axis_rms_deg": float(np.sqrt(np.mean(np.square(axes)))) if axes else float("nan"),
        "coverage": float(np.mean(inside)) if inside else float("nan"),
        "solve_s": solve_s,
    }


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--photos", type=int, default=40)
    ap.add_argument("--seeds", type=int, nargs="*", default=[0, 1, 2])
    ap.add_argument("--x38-seeds", type=int, nargs="*", default=[0])
    ap.add_argument("--x38-photos", type=int, default=60)
    ap.add_argument(
        "--exact-tags",
        action="store_true",
        help="place the simulated tags exactly on their bodies (the same draws otherwise), to "
        "show what the tags' placement adds to the errors",
    )
    args = ap.parse_args()
    rows = []
    for s in args.seeds:
        rows.append(
            (
                "calibration-mass-bungee",
                s,
                args.photos,
                one("calibration-mass-bungee", s, args.photos, args.exact_tags),
            )
        )
        print(rows[-1], flush=True)
    for s in args.x38_seeds:
        rows.append(("x38", s, args.x38_photos, one("x38", s, args.x38_photos, args.exact_tags)))
        print(rows[-1], flush=True)
    commit = subprocess.run(
        ["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True, check=False
    ).stdout.strip()
    lines = [
        f"command: {' '.join(sys.argv)}",
        f"date: {datetime.datetime.now(datetime.UTC).isoformat(timespec='seconds')}",
        f"commit: {commit}; load average: {os.getloadavg()}",
        "limits: triax position <= 0.2 mm RMS, orientation <= 0.1 deg RMS, coverage >= 0.90",
        "ori deg: RMS of the rotation errors' angles; per axis: RMS over the sensor axes",
        *(["tags placed exactly in the simulated world (--exact-tags)"] if args.exact_tags else []),
        f"{'scenario':<26}{'seed':>5}{'photos':>7}{'triax':>6}{'unfixed':>8}{'σ px':>7}"
        f"{'pos mm':>8}{'ori deg':>9}{'per axis':>9}{'cover':>7}{'named':>6}{'solve s':>8}",
    ]
    for name, s, n, r in rows:
        lines.append(
            f"{name:<26}{s:>5}{n:>7}{r['triaxes']:>6}{r['unfixed']:>8}{r['sigma_px']:>7.3f}"
            f"{r['pos_rms_mm']:>8.3f}{r['ori_rms_deg']:>9.3f}{r['axis_rms_deg']:>9.3f}"
            f"{r['coverage']:>7.2f}{int(r['named']):>6}{r['solve_s']:>8.1f}"
        )
    inside = sum(r["inside"] for *_, r in rows)
    total = sum(r["n_errors"] for *_, r in rows)
    if total:
        lines.append(
            f"coverage pooled over the {len(rows)} sets: {inside / total:.3f} of {total:.0f}"
        )
    out = Path(__file__).with_suffix(".results.txt")
    with out.open("a", encoding="utf-8") as fh:  # one block per run, the newest last
        fh.write("\n" + "\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
