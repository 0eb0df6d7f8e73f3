"""Stated vs observed geometry uncertainty of the digitizing chain, on demand.

Repeats, ``--trials`` times, what a digitized setup does: place the simulated array at a random
pose, digitize six reference nodes through the wire (their stated GCS coordinates carry an error
of ``--ref-sigma-mm`` per coordinate, as a surveyed frame does), register with the limit, digitize
the 24 jig indentations of one triax and three points along a line of action, and fit both. The
observed errors against the truth (the probe positions the script placed) are compared with the
1σ the service states (``orientation_uncertainty`` / ``line_of_action_uncertainty``):

- orientation: RMS misorientation observed vs the RMS of the stated ``uncertainty_deg`` (the same
  quantity: ``sqrt(Σ axis variances)``), and the jig and registration parts separately;
- line of action: RMS angle observed vs RMS stated ``angle_std_deg``;
- triax origin: RMS per-coordinate error vs RMS stated ``origin_std_m``.

A ratio observed/stated near 1 means the statement is right, below 1 conservative (the stated
σ uses max(σ̂, prior) per registration), above 1 optimistic (wrong).

    python tests/scripts/geometry_uncertainty_check.py --trials 60 [--ref-sigma-mm 0.5] [--json OUT]

The figures go to ``geometry_uncertainty_check_results.md`` beside this script (``--results``
elsewhere) with the command, date, commit and machine load.
"""

from __future__ import annotations

import argparse
import json
import shlex
import sys
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from _results import Results, add_results_argument

import dimacq.simulators.digitizer as simdig
from dimacq.drivers.digitizer import SerialDigitizer
from dimacq.pipeline.digitizing.lines_of_action import angle_between_deg, line_of_action_svd
from dimacq.pipeline.digitizing.orientation import fit_orientation, rotation_error_deg
from dimacq.pipeline.digitizing.registration import registration_limit_m
from dimacq.services.geometry.digitizer_config import load_array_config, load_jig
from dimacq.services.geometry.digitizing import DigitizingSession
from dimacq.services.geometry.geometry_trust import (
    judge_registration,
    line_of_action_uncertainty,
    orientation_uncertainty,
)

REFS = np.array(
    [[0, 0, 0], [0.4, 0, 0], [0, 0.4, 0], [0, 0, 0.3], [0.4, 0.4, 0.3], [0.4, 0, 0.3]], float
)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trials", type=int, default=60)
    ap.add_argument("--ref-sigma-mm", type=float, default=0.5)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--json", default=None)
    add_results_argument(ap, __file__)
    args = ap.parse_args(argv)
    res = Results(
        __file__,
        "Stated against observed geometry uncertainty of the digitizing chain",
        args.results,
    )
    if argv is not None:
        res.command = " ".join(["python", res.shown, *map(shlex.quote, argv)])
    rng = np.random.default_rng(args.seed)
    cfg = load_array_config()
    jig = load_jig()
    sig_r = 1e-3 * args.ref_sigma_mm
    point = cfg.accuracy.point_m
    limit = registration_limit_m(point, sig_r)
    prior = float(np.hypot(point, sig_r))
    name = f"geocheck-{args.seed}"
    url = f"simdigitizer://{name}?seed={args.seed}"
    drv = SerialDigitizer.from_url(url, timeout_s=2.0)
    drv.configure(emitters=2, microphones=len(cfg.array.microphones_m), averaging=1, bar_repeats=4)
    rows: dict[str, list[float]] = {
        k: []
        for k in (
            "ori_err",
            "ori_stated",
            "ori_jig",
            "ori_reg",
            "loa_err",
            "loa_stated",
            "origin_err",
            "origin_stated",
            "reg_rms",
        )
    }
    refused = 0
    try:
        for t in range(args.trials):
            sess = DigitizingSession(drv, cfg.geometry(), cfg.limits())
            rot = Rotation.from_euler("xyz", rng.uniform(-20, 20, 3), degrees=True)
            off = np.array([-0.2, -0.2, 0.9]) + rng.uniform(-0.05, 0.05, 3)

            def dig(label: str, p_gcs: np.ndarray, sess=sess, rot=rot, off=off) -> np.ndarray:
                tip = rot.apply(p_gcs) + off
                vals = ",".join(f"{v:.6f}" for v in (*tip, 0.0, 0.0, 1.0))
                drv.command(f"SIM:PROBE {vals}")
                return sess.digitize(label).position_array_m

            xa = np.array([dig(f"R{i}", p) for i, p in enumerate(REFS)])
            known = REFS + rng.normal(0, sig_r, REFS.shape)
            try:
                reg, body = judge_registration(
                    xa,
                    known,
                    [f"R{i}" for i in range(len(REFS))],
                    limit_m=limit,
                    prior_sigma_m=prior,
                )
            except Exception:
                refused += 1
                continue
            rows["reg_rms"].append(reg.rms_m)
            c_true = Rotation.random(random_state=int(rng.integers(2**31))).as_matrix()
            origin = np.array([0.2, 0.2, 0.1]) + rng.uniform(-0.05, 0.05, 3)
            xg = reg.apply(
                np.array(
                    [
                        dig(f"J{lab}", c_true @ xl + origin)
                        for lab, xl in zip(jig.labels, jig.points_local_m, strict=True)
                    ]
                )
            )
            fit = fit_orientation(jig.points_local_m, xg, jig.rod)
            unc = orientation_uncertainty(
                fit.uncertainty_deg, fit.residual_rms_m, len(xg), fit.origin_m, [body], point
            )
            rows["ori_err"].append(rotation_error_deg(fit.rotation, c_true))
            rows["ori_stated"].append(unc["uncertainty_deg"])
            rows["ori_jig"].append(unc["jig_uncertainty_deg"])
            rows["ori_reg"].append(unc["registration_uncertainty_deg"])
            rows["origin_err"].append(float(np.sqrt(np.mean((fit.origin_m - origin) ** 2))))
            rows["origin_stated"].append(unc["origin_std_m"])
            d = np.array([0.0, 0.6, -0.8])
            p_in = np.array([0.1, 0.05, 0.2])
            pin = reg.apply(dig("in", p_in))
            pts = reg.apply(
                np.array([dig(f"L{k}", p_in - s * d) for k, s in enumerate((0.04, 0.08, 0.12))])
            )
            loa = line_of_action_svd(pts, pin)
            lu = line_of_action_uncertainty(loa.angle_std_deg, pin, [body], point)
            rows["loa_err"].append(angle_between_deg(loa.direction, d))
            rows["loa_stated"].append(lu["angle_std_deg"])
            print(f"trial {t + 1}/{args.trials}", file=sys.stderr, flush=True)
    finally:
        drv.close()
        simdig.unregister_device(name)

    def rms(v: list[float]) -> float:
        return float(np.sqrt(np.mean(np.square(v))))

    out = {
        "trials": args.trials,
        "refused_registrations": refused,
        "ref_sigma_mm": args.ref_sigma_mm,
        "point_accuracy_mm": 1e3 * point,
        "registration_limit_mm": 1e3 * limit,
        "registration_rms_mm_mean": 1e3 * float(np.mean(rows["reg_rms"])),
        "orientation_error_rms_deg": rms(rows["ori_err"]),
        "orientation_stated_rms_deg": rms(rows["ori_stated"]),
        "orientation_stated_jig_rms_deg": rms(rows["ori_jig"]),
        "orientation_stated_registration_rms_deg": rms(rows["ori_reg"]),
        "orientation_observed_over_stated": rms(rows["ori_err"]) / rms(rows["ori_stated"]),
        "line_of_action_error_rms_deg": rms(rows["loa_err"]),
        "line_of_action_stated_rms_deg": rms(rows["loa_stated"]),
        "line_of_action_observed_over_stated": rms(rows["loa_err"]) / rms(rows["loa_stated"]),
        "origin_error_rms_mm": 1e3 * rms(rows["origin_err"]),
        "origin_stated_rms_mm": 1e3 * rms(rows["origin_stated"]),
        "origin_observed_over_stated": rms(rows["origin_err"]) / rms(rows["origin_stated"]),
    }
    for k, v in out.items():
        print(f"{k:45s} {v:.4g}" if isinstance(v, float) else f"{k:45s} {v}")
    res.table(
        ["figure", "value"],
        [(k, f"{v:.4g}" if isinstance(v, float) else v) for k, v in out.items()],
    )
    res.write()
    if args.json:
        with open(args.json, "w", encoding="utf-8") as fh:
            json.dump(out, fh, indent=2)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
