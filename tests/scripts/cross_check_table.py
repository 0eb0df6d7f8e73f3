"""DIM and the mass-line cross-check against the truth, through the command line (``dimacq
simulate`` files, ``dimacq solve --json``), as a user would run them.

Cases: the simulator's model FRFs of ``calibration-mass-bungee`` and ``x38`` (noise-free and with
``--noise``), of ``calibration-mass-realistic`` and ``x38-realistic`` (their geometry errors), and
the shared bracket samples written by another tool (``../shared/samples``,
``bracket_truth.json``). Per case and estimator: mass error (%), largest CG error (mm), largest
principal-moment error (%), and the cross-check's verdict (all items agree / which disagree).

Run on demand (a few seconds per solve)::

    python tests/scripts/cross_check_table.py [--noise 0.01] [--seed 0] [--out DIR]

It writes the table to ``cross_check_table_results.md`` beside it (``--results`` elsewhere).
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import sys
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "tests"))

from _results import Results, add_results_argument  # noqa: E402
from _samples import samples_dir  # noqa: E402

from dimacq.cli.main import main  # noqa: E402


def _quiet(args: list[str]) -> int:
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        return main(args)


def _errors(mass: float, cg: Any, pm: Any, truth: dict[str, Any]) -> tuple[float, float, float]:
    pm_t = np.asarray(truth["principal_moments_kgm2"], float)
    return (
        100 * (mass / truth["mass_kg"] - 1),
        1000 * float(np.max(np.abs(np.subtract(cg, truth["cg_m"])))),
        100 * float(np.max(np.abs(np.asarray(pm, float) / pm_t - 1))),
    )


def _row(name: str, uff: Path, truth_path: Path, work: Path) -> str:
    out = work / (uff.stem + ".json")
    rc = _quiet(["solve", str(uff), "--json", str(out)])
    data = json.loads(out.read_text())
    truth = json.loads(truth_path.read_text())
    if "principal_moments_kgm2" not in truth:
        truth["principal_moments_kgm2"] = np.linalg.eigvalsh(
            np.asarray(truth["inertia_cg_kgm2"], float)
        ).tolist()
    cc = data["cross_check"]
    d = _errors(data["mass_kg"], data["cg_m"], data["principal_moments_kgm2"], truth)
    c = _errors(cc["mass_kg"], cc["cg_m"], cc["principal_moments_kgm2"], truth)
    z = cc["z"]
    zs = [z["mass"], *z["cg"], *z["inertia"].values(), *z["principal"]]
    agree = "all agree" if cc["agrees"]["all"] else "DISAGREE"
    return (
        f"| {name} | {d[0]:+.4f} % / {d[1]:.3f} mm / {d[2]:.3f} % | "
        f"{c[0]:+.4f} % / {c[1]:.3f} mm / {c[2]:.3f} % | {agree} (max abs z "
        f"{max(abs(x) for x in zs):.2f}) | {data['verdict']} (rc {rc}) |"
    )


def main_(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--noise", type=float, default=0.01)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", type=Path, default=None)
    add_results_argument(ap, __file__)
    a = ap.parse_args(argv)
    res = Results(__file__, "DIM and the mass-line cross-check against the truth", a.results)
    work = a.out or Path(tempfile.mkdtemp(prefix="cross_check_"))
    work.mkdir(parents=True, exist_ok=True)
    table: list[str] = []

    def say(line: str) -> None:
        print(line, flush=True)
        table.append(line)

    say(
        "| case | DIM: mass / CG / principal moments | mass line: mass / CG / principal moments "
        "| cross-check | verdict |"
    )
    say("| --- | --- | --- | --- | --- |")
    cases = [
        ("calibration-mass-bungee", 0.0),
        ("calibration-mass-bungee", a.noise),
        ("x38", 0.0),
        ("x38", a.noise),
        ("calibration-mass-realistic", a.noise),
        ("x38-realistic", a.noise),
    ]
    for scn, noise in cases:
        uff = work / f"{scn}-{noise:g}.uff"
        truth = work / f"{scn}-{noise:g}_truth.json"
        args = ["simulate", scn, "--frf", str(uff), "--truth", str(truth), "--seed", str(a.seed)]
        if noise:
            args += ["--noise", f"{noise:g}"]
        if _quiet(args) != 0:
            say(f"| {scn} | simulate failed | | | |")
            continue
        label = f"`{scn}` model FRFs, " + (f"{100 * noise:g} % noise" if noise else "noise-free")
        say(_row(label, uff, truth, work))
    samples = samples_dir()
    if samples.is_dir():
        for f in ("bracket_clean_binary.uff", "bracket_clean_ascii.uff", "bracket_noisy_ascii.uff"):
            say(_row(f"`{f}` (shared sample)", samples / f, samples / "bracket_truth.json", work))
    res.add(
        f"Seed {a.seed}; `dimacq simulate SCENARIO --frf F.uff --truth T.json [--noise N]` then "
        "`dimacq solve F.uff --json OUT.json` (defaults). Errors against the truth: mass (%), "
        "largest CG coordinate (mm), largest principal moment (%); the cross-check's agreement "
        "and largest |z|; the solve's verdict and exit status."
    )
    res.add("\n".join(table))
    res.write()
    return 0


if __name__ == "__main__":
    raise SystemExit(main_())
