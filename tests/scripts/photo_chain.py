"""Photographed geometry through the whole chain, as a user runs it: the answer's errors.

    python tests/scripts/photo_chain.py [--seeds 0 1 2] [--photos 60] [--averages 3]

For each seed of the calibration mass on its bungee, two chains, each through the commands a
user types (subprocesses; nothing here hands the solver the simulator's truth):

- **demo**: ``dimacq demo --geometry photos --seed S --photos N --json`` (the service's
  Photograph step on the simulated camera's photos, the acquisition through the simulated DAQ
  and load cell, the default solve);
- **acquire + solve**: photos of the article rendered by the simulated camera
  (:func:`~dimacq.simulators.camera.render.photograph_article`: the lab's camera) and the lab's
  stated setup written to files (hand-measured geometry: the true geometry with draws of 2 mm
  per coordinate, 0.5° per triax and 1° per line of action, stating those values), then
  ``dimacq geometry from-photos`` (→ the photographed setup), ``dimacq acquire`` through the
  simulated devices, ``dimacq solve`` of the acquired UFF with the photographed setup and,
  beside it, with the hand-measured one.

Each row: mass error (%), CG error (mm), largest principal-moment error (%) against the
truth (``dimacq simulate --truth``) and the verdict, against the limits of the photo chain
(0.05 % mass, 0.2 mm CG, 0.1 % principal moments). Written to ``photo_chain_results.md``
beside this script (``--results`` elsewhere) with the command, date, commit and load.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))
from _results import Results, add_results_argument  # noqa: E402

SCENARIO = "calibration-mass-bungee"
#: mass %, CG mm, principal moments %
LIMITS = (0.05, 0.2, 0.1)


def _dimacq(*args: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    exe = str(Path(sys.executable).with_name("dimacq"))
    return subprocess.run([exe, *args], cwd=cwd, capture_output=True, text=True, check=False)


def errors(est: dict, truth: dict) -> dict[str, float]:
    """Mass %, CG mm and the largest principal-moment error % of ``est`` against ``truth``
    (both in ``dimacq solve --json``'s keys)."""
    pm = np.asarray(est["principal_moments_kgm2"], float)
    pt = np.asarray(truth["principal_moments_kgm2"], float)
    return {
        "mass_pct": 100.0 * (est["mass_kg"] - truth["mass_kg"]) / truth["mass_kg"],
        "cg_mm": 1e3 * float(np.linalg.norm(np.subtract(est["cg_m"], truth["cg_m"]))),
        "pm_pct": float(np.max(np.abs(100.0 * (pm - pt) / pt))),
    }


def demo_row(seed: int, photos: int, tmp: Path) -> dict:
    out = tmp / "demo.json"
    t0 = time.monotonic()
    r = _dimacq(
        "demo", "--geometry", "photos", "--seed", str(seed), "--photos", str(photos),
        "--json", str(out), cwd=tmp,
    )  # fmt: skip
    row: dict = {"chain": "demo --geometry photos", "seed": seed, "wall_s": time.monotonic() - t0}
    if r.returncode != 0 or not out.exists():
        row["failed"] = " / ".join((r.stdout + r.stderr).strip().splitlines()[-3:])
        return row
    d = json.loads(out.read_text(encoding="utf-8"))
    row.update(errors(d, d["truth"]))
    row["verdict"] = d["verdict"]
    return row


def acquire_rows(seed: int, photos: int, averages: int, tmp: Path) -> list[dict]:
    from dimacq.io.setup_file import save_setup
    from dimacq.io.tags_file import dump_tags
    from dimacq.model.setup import GeometryUncertainty
    from dimacq.simulators.camera.render import photograph_article
    from dimacq.simulators.camera.scenario import tagged_scenario
    from dimacq.simulators.lab.scenarios import build_scenario, nominal_setup

    built = build_scenario(SCENARIO, seed)
    true = built.model.setup
    plan, world = tagged_scenario(built)
    photograph_article(world, tmp / "photos", photos, seed + 3000)
    dump_tags(plan, tmp / "tags.toml")
    hand = nominal_setup(
        true,
        built.spec.errors.model_copy(
            update={"position_m": 0.002, "orientation_deg": 0.5, "line_of_action_deg": 1.0}
        ),
        seed,
    ).model_copy(update={"geometry_uncertainty": GeometryUncertainty()})
    save_setup(hand, tmp / "stated.json")

    t0 = time.monotonic()
    g = _dimacq(
        "geometry", "from-photos", str(tmp / "photos"), "--setup", str(tmp / "stated.json"),
        "--tags", str(tmp / "tags.toml"), "--out", str(tmp / "geometry.json"), "-q", cwd=tmp,
    )  # fmt: skip
    base = {"seed": seed}
    if not (tmp / "geometry.json").exists():
        return [{**base, "chain": "from-photos", "failed": (g.stdout + g.stderr)[-300:]}]
    geometry = json.loads((tmp / "geometry.json").read_text(encoding="utf-8"))
    (tmp / "photo_setup.json").write_text(json.dumps(geometry["setup"]), encoding="utf-8")
    photo_note = g.stdout.strip().splitlines()[-1] if g.stdout.strip() else ""
    _dimacq("simulate", SCENARIO, "--seed", str(seed), "--truth", str(tmp / "truth.json"), cwd=tmp)
    a = _dimacq(
        "acquire", SCENARIO, "--averages-per-input", str(averages), "--frf", str(tmp / "t.uff"),
        "--seed", str(seed), "--data-dir", str(tmp / "data"), "-q", cwd=tmp,
    )  # fmt: skip
    if a.returncode != 0:
        return [{**base, "chain": "acquire", "failed": (a.stdout + a.stderr)[-300:]}]
    truth = json.loads((tmp / "truth.json").read_text(encoding="utf-8"))
    rows = []
    for name, setup in (("photographed", "photo_setup.json"), ("hand-measured", "stated.json")):
        out = tmp / f"solve-{setup}"
        s = _dimacq("solve", str(tmp / setup), str(tmp / "t.uff"), "--json", str(out), cwd=tmp)
        row = {**base, "chain": f"acquire + solve, {name} setup"}
        if not out.exists():
            row["failed"] = (s.stdout + s.stderr)[-300:]
        else:
            est = json.loads(out.read_text(encoding="utf-8"))
            row.update(errors(est, truth))
            row["verdict"] = est["verdict"]
        if name == "photographed":
            row["note"] = f"from-photos exit {g.returncode}: {photo_note}"
        row["wall_s"] = time.monotonic() - t0
        rows.append(row)
    return rows


def write(rows: list[dict], res: Results, args: argparse.Namespace) -> None:
    lines = [
        "| chain | seed | mass % | CG mm | principal % (largest) | verdict | within limits | wall s |",
        "|---|---|---|---|---|---|---|---|",
    ]
    notes = []
    for r in rows:
        if "failed" in r:
            lines.append(f"| {r['chain']} | {r['seed']} | - | - | - | - | no result | - |")
            notes.append(f"- {r['chain']}, seed {r['seed']}: {r['failed']}")
            continue
        ok = (
            abs(r["mass_pct"]) <= LIMITS[0] and r["cg_mm"] <= LIMITS[1] and r["pm_pct"] <= LIMITS[2]
        )
        lines.append(
            f"| {r['chain']} | {r['seed']} | {r['mass_pct']:+.4f} | {r['cg_mm']:.3f} | "
            f"{r['pm_pct']:.3f} | {r['verdict']} | {'yes' if ok else 'no'} | "
            f"{r.get('wall_s', 0):.0f} |"
        )
        if r.get("note"):
            notes.append(f"- {r['chain']}, seed {r['seed']}: {r['note']}")
    res.sections = ["\n".join(lines + [""] + notes)]
    res.write()


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="*", default=[0, 1, 2])
    ap.add_argument("--photos", type=int, default=60)
    ap.add_argument("--averages", type=int, default=3)
    add_results_argument(ap, __file__)
    args = ap.parse_args(argv)
    res = Results(__file__, "Photographed geometry through the whole chain", args.results)
    res.note(f"scenario: {SCENARIO}; {args.photos} photos, {args.averages} averages per input")
    res.note(f"limits: mass {LIMITS[0]} %, CG {LIMITS[1]} mm, principal moments {LIMITS[2]} %")
    rows: list[dict] = []
    for seed in args.seeds:
        with tempfile.TemporaryDirectory(prefix=f"photo-chain-{seed}-") as t:
            tmp = Path(t)
            for row in [demo_row(seed, args.photos, tmp), *acquire_rows(
                seed, args.photos, args.averages, tmp
            )]:  # fmt: skip
                rows.append(row)
                print(json.dumps(row), flush=True)
                write(rows, res, args)
    print(f"wrote {res.path}  (load average {os.getloadavg()[0]:.1f})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
