"""Where the refined solution's error comes from, on the virtual lab.

Run on demand::

    nice python tests/scripts/accuracy_diagnose.py [--case calibration-mass] [--seeds 6]

This script (and only this script) compares with the simulator's truth: per seed

1. the error of the refined solve (selection + output error + geometry refinement, scenario band)
   with the stated geometry, and with one geometry source replaced by the truth at a time (sensor
   positions, sensor orientations, input points, lines of action; the gross errors stay), and with
   the stated geometry's *gauge* component removed (below);
2. the gauge: the similarity (translation ``t``, rotation ``ω`` about P, scale ``s``) of the whole
   instrumentation changes no FRF (a free body: ``ψᵀ M⁻¹ φ`` is invariant under ``ψ → Sψ``,
   ``φ → Sφ``, ``M → SMS``), so only the priors fix it. Its realised value is the prior-weighted
   least-squares fit of the stated-to-true geometry errors (sensor offsets ``≈ t + ω × r + s r``,
   rotations ``≈ ω``, input point offsets and line-of-action turns normal to the line), and
   the error it alone causes in the properties is ``∂x/∂(t, ω, s)`` of
   :func:`~dimacq.pipeline.output_error.gauge_property_jacobian` times it;
3. the Cramér–Rao bound of the gauge: the inverse of that fit's normal matrix (the prior
   information, the data's being zero), mapped to mass / |CG| / principal moments: no estimator
   that uses only these FRFs and these priors does better on average;
4. the refinement's estimated corrections against the true ones (RMS of estimate − truth over the
   items, against the RMS of the truth: below 1 the refinement helps).

It writes its tables to ``accuracy_diagnose_results.md`` beside it (``--results`` elsewhere).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np
from accuracy_must_show import errors, spec_with  # type: ignore[import-not-found]
from scipy.spatial.transform import Rotation

from dimacq.model.properties import RigidBodyProperties, principal_moments, vector_to_inertia
from dimacq.model.setup import TestSetup
from dimacq.pipeline.output_error import gauge_property_jacobian
from dimacq.services.solve.analysis import AnalysisOptions, analyse
from dimacq.simulators.lab.scenarios import build_scenario, gross_errors

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from _results import Results, add_results_argument


def _normals(d: np.ndarray) -> np.ndarray:
    """Two unit vectors normal to ``d`` (the convention of output_error's input basis)."""
    a = np.eye(3)[int(np.argmin(np.abs(d)))]
    e1 = np.cross(d, a)
    e1 /= np.linalg.norm(e1)
    return np.stack([e1, np.cross(d, e1)])


def true_corrections(true: TestSetup, nom: TestSetup, bad_ch, bad_in) -> dict[str, Any]:
    """True − stated geometry per sensor node and input (gross items left out)."""
    p = true.reference_point
    nodes: dict[int, dict[str, list]] = {}
    for k, (ct, cn) in enumerate(zip(true.responses, nom.responses, strict=True)):
        n = nodes.setdefault(int(cn.node), {"dt": [], "dn": [], "pt": [], "pn": [], "bad": []})
        n["dt"].append(np.asarray(ct.direction_gcs))
        n["dn"].append(np.asarray(cn.direction_gcs))
        n["pt"].append(np.asarray(ct.position_m))
        n["pn"].append(np.asarray(cn.position_m))
        n["bad"].append(k in bad_ch)
    sens = {}
    for node, v in nodes.items():
        ok = ~np.asarray(v["bad"])
        rot, _ = Rotation.align_vectors(np.asarray(v["dt"])[ok], np.asarray(v["dn"])[ok])
        sens[node] = {
            "rotation": rot.as_rotvec(),  # stated → true
            "offset": np.mean(np.asarray(v["pt"]) - np.asarray(v["pn"]), axis=0),
            "r": np.mean(np.asarray(v["pn"]), axis=0) - p,
        }
    inps = {}
    for j, (et, en) in enumerate(zip(true.excitations, nom.excitations, strict=True)):
        if j in bad_in:
            continue
        dn, dt = np.asarray(en.direction_gcs), np.asarray(et.direction_gcs)
        e = _normals(dn)
        rv = np.cross(dn, dt)  # small turn stated → true
        inps[(int(en.node), int(en.direction))] = {
            "beta": e @ rv,
            "gamma": e @ (np.asarray(et.position_m) - np.asarray(en.position_m)),
            "e": e,
            "r": np.asarray(en.position_m) - p,
        }
    return {"sensors": sens, "inputs": inps}


def gauge_fit(corr: dict[str, Any], gu) -> tuple[np.ndarray, np.ndarray]:
    """Realised similarity ``c = [t, ω, s]`` (prior-weighted LS of the true corrections) and the
    inverse of its normal matrix (the gauge's prior covariance: its Cramér–Rao bound)."""
    rows, rhs, w = [], [], []
    sp, so = gu.sensor_position_m, np.deg2rad(gu.sensor_orientation_deg)
    ip, il = gu.input_position_m, np.deg2rad(gu.line_of_action_deg)

    def dpos(r: np.ndarray) -> np.ndarray:  # (3, 7): ∂(t + ω × r + s r)/∂c
        out = np.zeros((3, 7))
        out[:, :3] = np.eye(3)
        out[:, 3:6] = -np.array([[0, -r[2], r[1]], [r[2], 0, -r[0]], [-r[1], r[0], 0]])
        out[:, 6] = r
        return out

    for v in corr["sensors"].values():
        if sp > 0:
            rows.append(dpos(v["r"]))
            rhs.append(v["offset"])
            w.append(np.full(3, 1 / sp))
        if so > 0:
            a = np.zeros((3, 7))
            a[:, 3:6] = np.eye(3)
            rows.append(a)
            rhs.append(v["rotation"])
            w.append(np.full(3, 1 / so))
    for v in corr["inputs"].values():
        if ip > 0:
            rows.append(v["e"] @ dpos(v["r"]))
            rhs.append(v["gamma"])
            w.append(np.full(2, 1 / ip))
        if il > 0:
            a = np.zeros((2, 7))
            a[:, 3:6] = v["e"]
            rows.append(a)
            rhs.append(v["beta"])
            w.append(np.full(2, 1 / il))
    A = np.concatenate(rows) * np.concatenate(w)[:, None]
    b = np.concatenate(rhs) * np.concatenate(w)
    N = A.T @ A
    cov = np.linalg.inv(N)
    return cov @ (A.T @ b), cov


def gauge_effect(
    c: np.ndarray, cov: np.ndarray, truth: RigidBodyProperties, p: np.ndarray
) -> dict[str, float]:
    """The property error a solve that keeps the stated gauge makes (first order), and its 1σ."""
    x = truth.parameter_vector(p)
    Jg = gauge_property_jacobian(x)[:, :7]  # t, ω, s (gain not here)
    # the stated geometry is the true one moved by −c: the estimate follows it
    dx = -Jg @ c
    cov_x = Jg @ cov @ Jg.T
    est = x + dx
    e = errors(np.r_[est[0], est[1:4] + p, est[4:]], truth, p)

    # principal moments' σ from the scale and the rest, by finite differences
    def pm(v: np.ndarray) -> np.ndarray:
        pr = RigidBodyProperties.from_about_point(
            float(v[0]), v[1:4] + p, vector_to_inertia(v[4:]), p
        )
        return principal_moments(pr.inertia_cg_kgm2)[0]

    Jp = np.empty((3, 10))
    for i in range(10):
        h = 1e-6 * max(abs(x[i]), 1e-3)
        ei = np.zeros(10)
        ei[i] = h
        Jp[:, i] = (pm(x + ei) - pm(x - ei)) / (2 * h)
    sd_pm = 100 * np.sqrt(np.diag(Jp @ cov_x @ Jp.T)) / pm(x)
    return {
        "predicted_cg_mm": e["cg_mm"],
        "predicted_pm_pct": e["pm_pct"],
        "predicted_mass_pct": e["mass_pct"],
        "scale_pct": float(100 * c[6]),
        "translation_mm": (1e3 * c[:3]).tolist(),
        "sd_scale_pct": float(100 * np.sqrt(cov[6, 6])),
        "sd_translation_mm": (1e3 * np.sqrt(np.diag(cov)[:3])).tolist(),
        "sd_cg_3d_mm": float(1e3 * np.sqrt(np.trace(cov_x[1:4, 1:4]))),
        "sd_pm_pct": sd_pm.tolist(),
    }


def with_true(nom: TestSetup, true: TestSetup, what: str, bad_ch, bad_in) -> TestSetup:
    """The stated setup with one geometry source replaced by the truth (gross items kept)."""
    resp = list(nom.responses)
    exc = list(nom.excitations)
    for k, (ct, cn) in enumerate(zip(true.responses, nom.responses, strict=True)):
        if what == "sensor_positions":
            resp[k] = cn.model_copy(update={"position_m": ct.position_m})
        elif what == "sensor_orientations" and k not in bad_ch:
            resp[k] = cn.model_copy(update={"direction_gcs": ct.direction_gcs})
    for j, (et, en) in enumerate(zip(true.excitations, nom.excitations, strict=True)):
        if j in bad_in:
            continue
        if what == "input_points":
            exc[j] = en.model_copy(update={"position_m": et.position_m})
        elif what == "lines_of_action":
            exc[j] = en.model_copy(update={"direction_gcs": et.direction_gcs})
    return nom.model_copy(update={"responses": tuple(resp), "excitations": tuple(exc)})


def degauged(nom: TestSetup, c: np.ndarray) -> TestSetup:
    """The stated setup moved by the realised similarity ``c``: no gauge error left."""
    p = nom.reference_point
    t, w, s = c[:3], c[3:6], c[6]
    R = Rotation.from_rotvec(w)

    def move(pos):
        r = np.asarray(pos) - p
        return tuple(float(v) for v in np.asarray(pos) + t + np.cross(w, r) + s * r)

    resp = [
        c_.model_copy(
            update={
                "position_m": move(c_.position_m),
                "direction_gcs": tuple(float(v) for v in R.apply(c_.direction_gcs)),
            }
        )
        for c_ in nom.responses
    ]
    exc = [
        e.model_copy(
            update={
                "position_m": move(e.position_m),
                "direction_gcs": tuple(float(v) for v in R.apply(e.direction_gcs)),
            }
        )
        for e in nom.excitations
    ]
    return nom.model_copy(update={"responses": tuple(resp), "excitations": tuple(exc)})


def solve(frf, setup, band, known=None) -> tuple[Any, Any]:
    rep = analyse(
        frf,
        setup,
        AnalysisOptions(band_hz=band, refine_geometry=True, unbiased=True, geometry_samples=0),
    )
    return rep, rep.result.parameters


def correction_quality(rep, corr) -> dict[str, float]:
    """RMS (estimate − truth) / RMS truth per kind of correction (estimated items only)."""
    oe = rep.result.extras.get("output_error", {})
    out: dict[str, float] = {}
    acc: dict[str, list] = {"rot": [[], []], "off": [[], []], "loa": [[], []], "ipt": [[], []]}
    for s in oe.get("sensor_corrections", []):
        v = corr["sensors"].get(int(s["node"]))
        if v is None:
            continue
        if s["rotation_estimated"]:
            acc["rot"][0].append(np.deg2rad(s["rotation_deg"]) - v["rotation"])
            acc["rot"][1].append(v["rotation"])
        if s["offset_estimated"]:
            acc["off"][0].append(1e-3 * np.asarray(s["offset_mm"]) - v["offset"])
            acc["off"][1].append(v["offset"])
    for s in oe.get("input_corrections", []):
        v = corr["inputs"].get((int(s["node"]), int(s["direction"])))
        if v is None:  # gross or sign-flipped label
            v = corr["inputs"].get((int(s["node"]), -int(s["direction"])))
        if v is None:
            continue
        if s["line_of_action_estimated"]:
            acc["loa"][0].append(np.deg2rad(s["line_of_action_components_deg"]) - v["beta"])
            acc["loa"][1].append(v["beta"])
        if s["offset_estimated"]:
            acc["ipt"][0].append(1e-3 * np.asarray(s["offset_components_mm"]) - v["gamma"])
            acc["ipt"][1].append(v["gamma"])
    for k, (d, t) in acc.items():
        if d:
            out[k] = float(np.sqrt(np.mean(np.square(d))) / np.sqrt(np.mean(np.square(t))))
    return out


CASES = {
    "calibration-mass": lambda: spec_with("calibration-mass-realistic"),
    "x38-rigid": lambda: spec_with("x38-realistic", {"flexible": False}),
}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--case", choices=sorted(CASES), default="calibration-mass")
    ap.add_argument("--seeds", type=int, default=6)
    ap.add_argument("--noise", type=float, default=0.01)
    ap.add_argument("--variants", nargs="*", default=None)
    ap.add_argument("--json", type=Path)
    add_results_argument(ap, __file__)
    args = ap.parse_args()
    res = Results(
        __file__, f"Where the refined solution's error comes from: {args.case}", args.results
    )
    gauge_rows: list[list[str]] = []
    variant_rows: list[list[str]] = []
    spec = CASES[args.case]()
    variants = args.variants or [
        "stated",
        "sensor_positions",
        "sensor_orientations",
        "input_points",
        "lines_of_action",
        "gauge_removed",
    ]
    report = []
    for seed in range(args.seeds):
        b = build_scenario(spec, seed)
        frf = b.model_frf(noise=args.noise)
        true, nom = b.model.setup, b.setup
        bad_ch, bad_in = gross_errors(true, spec.errors, seed)
        corr = true_corrections(true, nom, bad_ch, bad_in)
        c, cov = gauge_fit(corr, nom.geometry_uncertainty)
        ge = gauge_effect(c, cov, b.truth, nom.reference_point)
        row: dict[str, Any] = {"seed": seed, "gauge": ge}
        print(
            f"seed {seed}: gauge realised scale {ge['scale_pct']:+.3f} % (sd {ge['sd_scale_pct']:.3f}),"
            f" translation {np.round(ge['translation_mm'], 2)} mm (sd "
            f"{np.round(ge['sd_translation_mm'], 2)}); it alone gives CG {ge['predicted_cg_mm']:.2f}"
            f" mm, principal moments {np.round(ge['predicted_pm_pct'], 3)} %; bound (1σ) |CG| "
            f"{ge['sd_cg_3d_mm']:.2f} mm, principal moments {np.round(ge['sd_pm_pct'], 3)} %",
            flush=True,
        )
        gauge_rows.append(
            [
                str(seed),
                f"{ge['scale_pct']:+.3f} ({ge['sd_scale_pct']:.3f})",
                " ".join(f"{x:+.2f}" for x in ge["translation_mm"]),
                f"{ge['predicted_cg_mm']:.2f}",
                " ".join(f"{x:+.3f}" for x in ge["predicted_pm_pct"]),
                f"{ge['sd_cg_3d_mm']:.2f}",
                " ".join(f"{x:.3f}" for x in ge["sd_pm_pct"]),
            ]
        )
        for v in variants:
            if v == "stated":
                setup = nom
            elif v == "gauge_removed":
                setup = degauged(nom, c)
            else:
                setup = with_true(nom, true, v, bad_ch, bad_in)
            rep, params = solve(frf, setup, b.band_hz)
            e = errors(params, b.truth, nom.reference_point)
            q = correction_quality(rep, corr) if v == "stated" else {}
            row[v] = {**e, "correction_rms_ratio": q}
            print(
                f"   {v:20s} mass {e['mass_pct']:+.3f} %  CG {e['cg_mm']:.2f} mm  PM "
                f"{np.round(e['pm_pct'], 3)} %"
                + (f"  corrections (est−true)/true RMS {q}" if q else ""),
                flush=True,
            )
            variant_rows.append(
                [
                    str(seed),
                    v,
                    f"{e['mass_pct']:+.3f}",
                    f"{e['cg_mm']:.2f}",
                    " ".join(f"{x:+.3f}" for x in e["pm_pct"]),
                    ", ".join(f"{k} {x:.2f}" for k, x in q.items()),
                ]
            )
        report.append(row)
    res.add(
        f"Case `{args.case}`, {args.noise:g} FRF noise, {args.seeds} seeds; the refined solve "
        "(selection + output error + geometry refinement, scenario band) against the simulator's "
        "truth."
    )
    res.table(
        ["seed", "realised scale % (1σ bound)", "translation mm", "\\|CG\\| mm it causes"]
        + ["principal % it causes", "bound 1σ \\|CG\\| mm", "bound 1σ principal %"],
        gauge_rows,
        "The gauge: realised similarity, the error it alone causes, its Cramér–Rao bound",
    )
    res.table(
        ["seed", "geometry", "mass %", "\\|CG\\| mm", "principal moments %"]
        + ["corrections: RMS(estimate − truth) / RMS(truth)"],
        variant_rows,
        "The refined solve with one geometry source replaced by the truth",
    )
    res.write()
    if args.json:
        args.json.write_text(json.dumps(report, indent=1, default=float) + "\n", encoding="utf-8")


if __name__ == "__main__":
    main()
