"""Each simulated device twin's ``dimacq demo``: its errors against the truth, or its refusal.

For each simulated load-cell backend of the table (``DIMACQ_LOADCELL=...-simulated``) and the
simulated USB-1808X (``DIMACQ_DAQ=mcc-usb-simulated``), one at a time, the demo runs as a user
starts it (``dimacq demo --json OUT``, ended after ``--timeout-s``). Written per demo: the exit
status, the wall time, the mass error (%), the CG error (mm), the largest principal-moment error
(%), the solution's verdict and whether the errors are within the limits (0.5 % mass, 1 mm CG,
0.5 % principal moments); a demo that ends without a result has the reason it gave (its last
lines). The figures go to ``twin_demos_results.md`` beside this script (``--results``
elsewhere; rewritten after each demo) with the command, date, commit and load.

    python tests/scripts/twin_demos.py [--only cia404-simulated ...] [--timeout-s 900]
"""

from __future__ import annotations

import argparse
import json
import os
import shlex
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))
from _results import Results, add_results_argument  # noqa: E402

#: name → the environment that selects the twin (as a user sets it)
DEMOS: dict[str, dict[str, str]] = {
    "netft-udp-simulated": {"DIMACQ_LOADCELL": "netft-udp-simulated"},
    "netft-can-simulated": {"DIMACQ_LOADCELL": "netft-can-simulated"},
    "cia404-simulated": {"DIMACQ_LOADCELL": "cia404-simulated"},
    "canopen-simulated": {"DIMACQ_LOADCELL": "canopen-simulated"},
    "mcc-usb-simulated": {"DIMACQ_DAQ": "mcc-usb-simulated"},
}

#: the limits: mass %, CG mm, principal moments %
LIMITS = (0.5, 1.0, 0.5)


def run_demo(name: str, env_extra: dict[str, str], out_dir: Path, timeout_s: float) -> dict:
    """One demo's row: exit, wall s, errors, verdict, or the reason it ended without a result."""
    out = out_dir / f"{name}.json"
    cmd = [str(Path(sys.executable).with_name("dimacq")), "demo", "--json", str(out)]
    t0 = time.monotonic()
    load0 = os.getloadavg()[0]
    p = subprocess.Popen(
        cmd,
        env={**os.environ, **env_extra},
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,  # a demo past its time is ended with its children
    )
    try:
        said, err = p.communicate(timeout=timeout_s)
        rc: int | str = p.returncode
    except subprocess.TimeoutExpired:
        os.killpg(p.pid, signal.SIGTERM)
        said, err = p.communicate()
        rc = "timeout"
    row: dict = {
        "name": name,
        "env": " ".join(f"{k}={v}" for k, v in env_extra.items()),
        "rc": rc,
        "wall_s": time.monotonic() - t0,
        "load_at_start": load0,
    }
    (out_dir / f"{name}.log").write_text(f"{said}\n{err}", encoding="utf-8")
    if out.exists() and rc == 0:
        payload = json.loads(out.read_text(encoding="utf-8"))
        e = payload["demo"]["errors"]
        row.update(
            mass_pct=e["mass_pct"],
            cg_mm=e["cg_mm"],
            principal_pct=max(e["principal_moments_pct"], key=abs),
            verdict=payload.get("verdict", "?"),
            band_hz=payload.get("band_hz"),
            acquisition=payload["demo"].get("acquisition", ""),
        )
        row["within"] = (
            abs(row["mass_pct"]) <= LIMITS[0]
            and row["cg_mm"] <= LIMITS[1]
            and abs(row["principal_pct"]) <= LIMITS[2]
        )
    else:
        lines = [ln for ln in f"{said}\n{err}".splitlines() if ln.strip()]
        row["tail"] = lines[-3:]
    return row


def write_results(rows: list[dict], res: Results) -> None:
    """The results file, rewritten after each demo (a demo cut short keeps the others)."""
    out = [
        "| twin | exit | wall s | load at start | mass % | CG mm | principal % (largest) "
        "| band Hz | verdict | within limits |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        if "mass_pct" in r:
            lo, hi = r["band_hz"] or (0, 0)
            figs = (
                f"{r['mass_pct']:+.3f} | {r['cg_mm']:.3f} | {r['principal_pct']:+.3f} "
                f"| {lo:g}-{hi:g} | {r['verdict']} | {'yes' if r['within'] else 'NO'}"
            )
        else:
            figs = "- | - | - | - | - | refused / no result"
        out.append(
            f"| `{r['env']}` | {r['rc']} | {r['wall_s']:.0f} | {r['load_at_start']:.1f} | {figs} |"
        )
    out.append("")
    for r in rows:
        if r.get("tail"):
            out.append(f"- `{r['env']}` ended without a result: " + " / ".join(r["tail"]))
        elif r.get("acquisition"):
            out.append(f"- `{r['env']}`: {r['acquisition']}")
    res.sections = ["\n".join(out)]
    res.write()


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", nargs="*", default=None, choices=sorted(DEMOS))
    ap.add_argument("--timeout-s", type=float, default=900.0, help="per demo")
    ap.add_argument("--logs", default=None, help="keep each demo's output and JSON here")
    add_results_argument(ap, __file__)
    ap.add_argument("--keep", type=Path, default=None, help="rows of earlier runs (JSON) kept")
    args = ap.parse_args(argv)
    res = Results(__file__, "Each simulated twin's `dimacq demo`", args.results)
    res.command = " ".join(["python", res.shown, *map(shlex.quote, argv)])
    res.note("one demo at a time")
    res.note(f"limits: mass {LIMITS[0]} %, CG {LIMITS[1]} mm, principal moments {LIMITS[2]} %")
    rows: list[dict] = []
    if args.keep and args.keep.exists():
        rows = json.loads(args.keep.read_text(encoding="utf-8"))
    with tempfile.TemporaryDirectory(prefix="dimacq-twins-") as tmp:
        logs = Path(args.logs) if args.logs else Path(tmp)
        logs.mkdir(parents=True, exist_ok=True)
        for name in args.only or list(DEMOS):
            row = run_demo(name, DEMOS[name], logs, args.timeout_s)
            rows = [r for r in rows if r["name"] != name] + [row]
            print(json.dumps(row), flush=True)
            if args.keep:
                args.keep.write_text(json.dumps(rows), encoding="utf-8")
            write_results(rows, res)
    return 0 if all(r.get("within") for r in rows) else 1


if __name__ == "__main__":
    raise SystemExit(main())
