"""Every backend's ``dimacq demo`` on a busy host: nothing lost, the time-lapse slower instead.

While ``--burners`` other processes keep the cores busy (``while True: pass``, each ended when
the script ends or after ``--burn-s``), each backend's demo runs as a user would start it
(``DIMACQ_LOADCELL=... dimacq demo --json``) under ``/usr/bin/time -v`` (peak memory of the
demo and its children). Written per demo: the exit status, wall seconds, the time-lapse chosen at
start and the factors the adaptive clock used, the simulated seconds, DAQ FIFO overflows and
load cell gaps (nothing lost: both zero), the answer's mass error against the truth. Figures go
to ``busy_host_demos_results.md`` beside this script (``--results`` elsewhere) with the command,
date, commit, load average and this host's sustainable time-lapse
(:func:`dimacq.backends.time_lapse.measure_host`).

    python tests/scripts/busy_host_demos.py [--only canopen-simulated ...] [--burners 2]
"""

from __future__ import annotations

import argparse
import json
import os
import re
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))
from _results import Results, add_results_argument  # noqa: E402

#: name → the environment that selects the backend (as a user sets it)
DEMOS: dict[str, dict[str, str]] = {
    "canopen-simulated": {"DIMACQ_LOADCELL": "canopen-simulated"},
    "default": {},
    "netft-can-simulated": {"DIMACQ_LOADCELL": "netft-can-simulated"},
    "netft-udp-simulated": {"DIMACQ_LOADCELL": "netft-udp-simulated"},
    "cia404-simulated": {"DIMACQ_LOADCELL": "cia404-simulated"},
    "daq-channels": {"DIMACQ_LOADCELL": "daq-channels"},
    "mcc-usb-simulated": {"DIMACQ_DAQ": "mcc-usb-simulated"},
}


def burners(n: int, seconds: float) -> list[subprocess.Popen[bytes]]:
    """``n`` processes spinning a core each, ending by themselves after ``seconds``."""
    code = f"import time\nend = time.monotonic() + {seconds}\nwhile time.monotonic() < end: pass"
    return [subprocess.Popen([sys.executable, "-c", code]) for _ in range(n)]


def host_line() -> str:
    from dimacq.backends.time_lapse import measure_host

    m = measure_host(30, 1, 51200.0)
    load = os.getloadavg()
    return (
        f"load average {load[0]:.2f} / {load[1]:.2f} / {load[2]:.2f} (1/5/15 min) on "
        f"{os.cpu_count()} cores; this host sustains about {m.sustainable_scale:.1f}x "
        "time-lapse now (30 DAQ channels at 51.2 kS/s and one CAN FD load cell)"
    )


def run_demo(name: str, env_extra: dict[str, str], out_dir: Path, timeout_s: float) -> dict:
    out = out_dir / f"{name}.json"
    env = {**os.environ, **env_extra}
    cmd = ["/usr/bin/time", "-v", "dimacq", "demo", "--json", str(out)]
    t0 = time.monotonic()
    load0 = os.getloadavg()[0]
    # a session of its own: a demo past its time is ended with its children (the step-0 process)
    p = subprocess.Popen(
        cmd,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
    )
    try:
        said_out, err = p.communicate(timeout=timeout_s)
        rc: int | str = p.returncode
    except subprocess.TimeoutExpired:
        os.killpg(p.pid, signal.SIGTERM)
        said_out, err = p.communicate()
        rc = "timeout"
    wall = time.monotonic() - t0
    (out_dir / f"{name}.log").write_text(f"{said_out}\n{err}", encoding="utf-8")
    rss = re.search(r"Maximum resident set size \(kbytes\): (\d+)", err or "")
    row: dict = {
        "name": name,
        "env": " ".join(f"{k}={v}" for k, v in env_extra.items()) or "(defaults)",
        "rc": rc,
        "wall_s": wall,
        "load_at_start": load0,
        "peak_rss_mb": int(rss.group(1)) / 1024 if rss else None,
    }
    if out.exists():
        payload = json.loads(out.read_text())
        tl = payload.get("demo", {}).get("time_lapse", {})
        row.update(
            start_scale=tl.get("daq_time_scale"),
            factors=tl.get("factors_used"),
            waits=tl.get("host_waits"),
            simulated_s=tl.get("acquisitions_simulated_s"),
            overflows=tl.get("daq_overflow_events"),
            gaps=[g for g in tl.get("loadcell_gap_samples", []) if g > 1],
            kept_up=tl.get("kept_up"),
            summary=payload.get("demo", {}).get("time_lapse_summary"),
        )
        truth, mass = payload.get("truth", {}).get("mass_kg"), payload.get("mass_kg")
        if truth and mass:
            row["mass_error_pct"] = 100 * (mass - truth) / truth
    text = f"{said_out}\n{err}"
    # what the log says whatever the end: the DAQ's overflows and each acquisition's averages
    row["log_fifo_overflows"] = text.count("simulated fault fifo_overflow")
    row["log_acquisitions"] = [
        ln.strip() for ln in text.splitlines() if "averages accepted" in ln and "/5]" in ln
    ]
    if rc != 0 or not out.exists():
        said = [ln for ln in (said_out + "\n" + (err or "")).splitlines() if ln.strip()]
        cut = next((i for i, ln in enumerate(said) if "Command being timed" in ln), len(said))
        row["tail"] = said[max(0, cut - 3) : cut]
    return row


def write_results(rows: list[dict], args: argparse.Namespace, res: Results, before: str) -> None:
    """The results file, rewritten after each demo (a demo cut short keeps the others)."""
    res.notes = []
    res.note(
        f"beside each demo: {args.burners} processes spinning a core each (`while True: pass`)"
    )
    res.note(f"before: {before}")
    res.note(f"after: {host_line()}")
    lines = [
        "| demo | exit | wall s | load at start | time-lapse at start | factors used | waits "
        "| simulated s | DAQ FIFO overflows | load cell gaps > 1 | mass error % | peak RSS MB |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        fac = "/".join(f"{f:g}" for f in r.get("factors") or []) or "-"
        err = r.get("mass_error_pct")
        lines.append(
            f"| `{r['env']}` | {r['rc']} | {r['wall_s']:.0f} | {r['load_at_start']:.1f} "
            f"| {r.get('start_scale', '-')} | {fac} | {r.get('waits', '-')} "
            f"| {r.get('simulated_s') or 0:.0f} | {r.get('overflows', '-')} "
            f"| {len(r.get('gaps', []) or [])} | {'-' if err is None else f'{err:+.3f}'} "
            f"| {r['peak_rss_mb'] or 0:.0f} |"
        )
    lines.append("")
    for r in rows:
        if r.get("summary"):
            lines.append(f"- `{r['env']}`: {r['summary']}")
        if r.get("log_acquisitions") is not None:
            lines.append(
                f"- `{r['env']}` log: {r['log_fifo_overflows']} simulated DAQ FIFO overflow(s); "
                + ("; ".join(r["log_acquisitions"]) or "no acquisition ended")
            )
        if r.get("tail"):
            lines.append(f"- `{r['env']}` ended without a result: {' / '.join(r['tail'])}")
    res.sections = ["\n".join(lines)]
    res.write()


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", nargs="*", default=None, choices=sorted(DEMOS))
    ap.add_argument("--burners", type=int, default=2, help="busy processes beside each demo")
    ap.add_argument("--burn-s", type=float, default=3600.0, help="each burner ends after this")
    ap.add_argument("--timeout-s", type=float, default=1200.0, help="per demo")
    ap.add_argument("--logs", default=None, help="keep each demo's output and JSON here")
    add_results_argument(ap, __file__)
    args = ap.parse_args()
    names = args.only or list(DEMOS)
    res = Results(__file__, "Every backend's demo on a busy host", args.results)
    before = host_line()
    rows = []
    with tempfile.TemporaryDirectory(prefix="dimacq-busy-") as tmp:
        logs = Path(args.logs) if args.logs else Path(tmp)
        logs.mkdir(parents=True, exist_ok=True)
        for name in names:
            burn = burners(args.burners, args.burn_s)
            try:
                time.sleep(2.0)  # the burners are running before the demo measures the host
                row = run_demo(name, DEMOS[name], logs, args.timeout_s)
            finally:
                for b in burn:
                    b.terminate()
                for b in burn:
                    b.wait()
            rows.append(row)
            print(json.dumps(row), flush=True)
            write_results(rows, args, res, before)
    lost = [r for r in rows if r["rc"] != 0 or not r.get("kept_up")]
    return 1 if lost else 0


if __name__ == "__main__":
    raise SystemExit(main())
