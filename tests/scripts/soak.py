"""Soak with faults: the real service process on the wire-level simulators, every fault at random.

``dimacq serve`` runs as its own process on loopback (``tests/_serve_support.py``), on the
simulated lab with its devices' imperfections turned up (:data:`SOAK_IMPERFECTIONS`, through the
``simulation_imperfections`` setting): USB stalls longer than the rig's USB timeout (timeouts),
a DAQ FIFO small enough to overflow when the host is late, USB re-enumeration, CAN frame loss and
bus-off, serial line noise and port loss. The soak then works the service like a lab for
``--minutes``: rounds of digitized points (``POST /api/digitizer/points``) and impact tests
(``POST /api/acquisitions`` on a setup of the article with ``--inputs`` inputs), while a process
of its own reads ``GET /api/status`` every 0.1 s. It checks and prints:

- **nothing accepted is lost**: every digitized point the service accepted (HTTP 200) is in
  ``GET /api/digitizer/points`` at the end; every average seen accepted while an acquisition ran
  (polled ``GET /api/acquisitions/{id}``) is in its final record, and each acquisition ends
  ``succeeded`` with FRFs, or refused as incomplete with its reason (fewer acceptable averages
  than asked after its strikes: the faults rejected too many; counted apart, nothing lost);
- **every fault is reported**: the simulators log each fault they inject (``simulated fault
  <kind>``), the drivers and the acquisition session log what they detect; per kind, the
  reports found in the service's log against the faults injected;
- **the service keeps answering**: no HTTP 500 on any call, status latency p50/p99/max.

Usage (on demand; the test suite runs a short version, ``tests/cli/test_soak.py``)::

    nice python tests/scripts/soak.py --minutes 30 [--seed 1] [--json soak.json]

The tables go to ``soak_results.md`` beside this script (``--results`` elsewhere) with the
command, date, commit and machine load.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import secrets
import shlex
import shutil
import socket
import subprocess
import sys
import tempfile
import threading
import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from _results import Results, add_results_argument
from _serve_support import Service

#: the imperfections turned up for the soak (see dimacq.simulators.imperfections)
SOAK_IMPERFECTIONS: dict[str, float] = {
    "daq_stall_rate": 0.01,  # per bulk read
    "daq_stall_s": 0.3,  # > the soak rig's USB timeout (0.2 s): each stall is a USB timeout
    "daq_time_scale": 4.0,
    "daq_fifo_bytes": 512 * 1024,  # ~4800 samples of 25 channels: 2.3 s, 0.6 s wall at 4x
    "daq_reenumerate_rate": 0.002,
    "daq_reenumerate_s": 0.5,
    "can_frame_loss_rate": 2e-5,
    "can_bus_off_rate": 0.01,  # per second of streamed pulses
    "can_bus_off_s": 0.1,
    "digitizer_noise_rate": 0.05,
    "digitizer_port_loss_rate": 0.02,
    "digitizer_port_loss_s": 0.3,
}

#: fault kind → what the drivers, the session or the service log when they detect it
REPORTS: dict[str, str] = {
    "usb_timeout": r"USB timeout after sample",
    "fifo_overflow": r"device FIFO overflow",
    "usb_reenumeration": r"run restarted",
    "can_frame_loss + can_bus_off": r"lost on the CAN bus",
    "serial_noise": (
        r"line noise, \d+ garbage|truncated line dropped|bytes were corrupted on the link"
    ),
    # the driver's line for every port it finds gone (also while reconnecting: a port lost
    # again during the reopening is met by the reconnect's retries, not by the session)
    "serial_port_loss": r"\S+ vanished: ",
}
_INJECTED = re.compile(r"simulated fault (\w+):")


@dataclass
class Figures:
    minutes: float = 0.0
    points_accepted: int = 0
    points_lost: int = 0
    acquisitions: int = 0
    acquisitions_failed: list[str] = field(default_factory=list)
    #: ended refused: fewer acceptable averages than asked after the strikes allowed (the
    #: faults' rejections named in the acquisition); nothing accepted lost, no FRFs
    acquisitions_incomplete: list[str] = field(default_factory=list)
    averages_accepted: int = 0
    averages_rejected: int = 0
    averages_lost: int = 0
    http_500: int = 0
    status_calls: int = 0
    status_p50_ms: float = 0.0
    status_p99_ms: float = 0.0
    status_max_ms: float = 0.0
    #: CPU time of the service process (user + system) per second of the run; the load average
    #: of the machine at the end (it is shared: other processes compete for its cores)
    service_cpu_per_s: float = 0.0
    load_average: float = 0.0
    #: p99 of each whole minute of the run ("throughout"), ms
    status_p99_by_minute_ms: list[float] = field(default_factory=list)
    #: the calls slower than 50 ms: (started, s into the run; latency, ms)
    status_slow: list[tuple[float, float]] = field(default_factory=list)
    injected: dict[str, int] = field(default_factory=dict)
    reported: dict[str, int] = field(default_factory=dict)
    errors: list[str] = field(default_factory=list)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _soak_rig(folder: Path) -> Path:
    """The calibration mass's rig file with a short USB timeout (0.2 s), its calibration files
    copied beside it (a rig file names them relative to its folder, inside it)."""
    cfg = Path(__file__).resolve().parents[2] / "config"
    text = (cfg / "rig.toml").read_text(encoding="utf-8")
    text = re.sub(r"(?m)^timeout_s = .*$", "timeout_s = 0.2", text)
    for name in re.findall(r'(?m)^calibration_file = "([^"]+)"', text):
        (folder / name).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy(cfg / name, folder / name)
    out = folder / "soak-rig.toml"
    out.write_text(text, encoding="utf-8")
    return out


class _StatusProbe:
    """``GET /api/status`` every ``period_s`` from a process of its own (:func:`_probe_main`:
    one keep-alive ``http.client`` connection), so that what is measured is the service, not
    the soak's own threads competing for this process's GIL; latencies and status codes."""

    def __init__(self, url: str, token: str, folder: Path, period_s: float = 0.1) -> None:
        self.out = folder / "status-probe.txt"
        self.proc = subprocess.Popen(
            [sys.executable, __file__, "--probe", url, token, str(period_s), str(self.out)],
            stdin=subprocess.PIPE,
        )
        self.latencies_ms: list[float] = []
        self.started_s: list[float] = []  # when each call started, s since the probe started
        self.codes: Counter[int] = Counter()

    def stop(self) -> None:
        """Stop the probe (closing its stdin) and read what it measured."""
        assert self.proc.stdin is not None
        self.proc.stdin.close()
        try:
            self.proc.wait(30)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait(10)
        for line in self.out.read_text().splitlines():
            t, ms, code = line.split()
            self.started_s.append(float(t))
            self.latencies_ms.append(float(ms))
            self.codes[int(code)] += 1


def _probe_main(url: str, token: str, period_s: float, out: str) -> None:
    """The status probe's process: until its stdin closes, ``GET /api/status`` every
    ``period_s``; one line per call: start (s since the first), latency (ms), HTTP code (-1: no
    answer)."""
    import http.client
    from urllib.parse import urlsplit

    u = urlsplit(url)
    stop = threading.Event()
    threading.Thread(target=lambda: (sys.stdin.read(), stop.set()), daemon=True).start()
    conn = http.client.HTTPConnection(u.hostname or "127.0.0.1", u.port, timeout=30)
    headers = {"Authorization": f"Bearer {token}"}
    t_start = time.perf_counter()
    with open(out, "w", encoding="utf-8") as f:
        while not stop.is_set():
            t0 = time.perf_counter()
            try:
                conn.request("GET", "/api/status", headers=headers)
                r = conn.getresponse()
                r.read()
                code = r.status
            except (OSError, http.client.HTTPException):
                conn.close()
                code = -1
            f.write(f"{t0 - t_start:.3f} {1e3 * (time.perf_counter() - t0):.2f} {code}\n")
            stop.wait(period_s)


def _setup(article: dict[str, Any], n_inputs: int) -> dict[str, Any]:
    """The article's setup with its first ``n_inputs`` inputs (load cells kept)."""
    setup = dict(article["setup"])
    key = "excitations" if "excitations" in setup else "inputs"
    setup[key] = list(setup[key])[:n_inputs]
    setup["name"] = "soak"
    return setup


def run_soak(
    minutes: float,
    *,
    seed: int = 1,
    n_inputs: int = 2,
    averages: int = 3,
    workdir: Path | None = None,
    say: Any = print,
    min_succeeded: int = 0,
) -> Figures:
    """Run the soak for ``minutes``; return its figures (see the module docstring).

    ``min_succeeded``: go on past ``minutes`` (up to 5 times as long) until that many
    acquisitions have succeeded: a short run on a starved machine still shows one whole test.
    """
    rng = np.random.default_rng(seed)
    fig = Figures()
    with tempfile.TemporaryDirectory(prefix="dimacq-soak-") as tmp:
        base = Path(workdir or tmp)
        data = base / "data"
        data.mkdir(parents=True, exist_ok=True)
        token = secrets.token_urlsafe(16)
        env = {
            "DIMACQ_RIG_FILE": str(_soak_rig(base)),
            "DIMACQ_SIMULATION_IMPERFECTIONS": json.dumps(SOAK_IMPERFECTIONS),
            "DIMACQ_DIGITIZER_URL": f"simdigitizer://soak?seed={seed}",
            "DIMACQ_DATABASE_URL": "",
        }
        svc = Service(data, _free_port(), token, env)
        probe = _StatusProbe(svc.url, token, base)
        c = svc.client
        codes: Counter[int] = Counter()

        def call(method: str, path: str, **kw: Any) -> Any:
            r = c.request(method, path, **kw)
            codes[r.status_code] += 1
            if r.status_code >= 500:
                fig.errors.append(f"{method} {path}: HTTP {r.status_code} {r.text[:200]}")
            return r

        t_end = time.monotonic() + 60 * minutes
        t_last = time.monotonic() + 5 * 60 * minutes

        def more() -> bool:
            now = time.monotonic()
            done = fig.acquisitions - len(fig.acquisitions_failed + fig.acquisitions_incomplete)
            return now < t_end or (done < min_succeeded and now < t_last)

        t0 = time.monotonic()
        try:
            article = call("GET", "/api/simulation/article").json()
            pos = np.array(
                [r["position_m"] for r in article["setup"]["responses"]], dtype=float
            ).reshape(-1, 3)
            lo, hi = pos.min(axis=0), pos.max(axis=0)
            refs = {
                f"REF{i}": [float(v) for v in p]
                for i, p in enumerate(
                    [lo, [hi[0], lo[1], lo[2]], [lo[0], hi[1], lo[2]], [lo[0], lo[1], hi[2]], hi]
                )
            }
            call("PUT", "/api/digitizer/reference-nodes", json={"nodes": refs})
            r = call("POST", "/api/setups", json=_setup(article, n_inputs))
            if r.status_code >= 400:
                raise RuntimeError(f"soak: setup refused: HTTP {r.status_code} {r.text[:300]}")
            setup_id = r.json()["id"]
            k = 0
            while more():
                # a few digitized points: the probe somewhere around the article
                for _ in range(4):
                    # array coordinates: the array 1.1 m above the article (as dimacq demo)
                    tip = np.array([0.0, 0.0, 1.1]) + rng.uniform(-0.1, 0.1, 3)
                    body = {
                        "label": f"p{k}",
                        "shots": 3,
                        "sim_probe": {"tip_m": [float(v) for v in tip], "axis": [0, 0, 1.0]},
                    }
                    r = call("POST", "/api/digitizer/points", json=body)
                    if r.status_code in (200, 201):
                        fig.points_accepted += 1
                    elif r.status_code not in (409, 422, 503):
                        fig.errors.append(f"point p{k}: HTTP {r.status_code} {r.text[:200]}")
                    k += 1
                if not more():
                    break
                _acquire(call, setup_id, averages, int(rng.integers(2**31 - 1)), fig, say)
                say(
                    f"soak {(time.monotonic() - t0) / 60:5.1f} min: {fig.points_accepted} points, "
                    f"{fig.acquisitions} acquisitions, {fig.averages_accepted} averages accepted"
                )
            stored = call("GET", "/api/digitizer/points").json()
            fig.points_lost = max(0, fig.points_accepted - len(stored))
        finally:
            probe.stop()
            fig.minutes = (time.monotonic() - t0) / 60
            fig.service_cpu_per_s = _cpu_s(svc.proc.pid) / max(1e-9, 60 * fig.minutes)
            fig.load_average = _load_average()
            svc.stop()
            log_text = Path(svc.log.name).read_text(errors="replace")
        lat = np.array(probe.latencies_ms or [0.0])
        fig.status_calls = len(probe.latencies_ms)
        fig.status_p50_ms = float(np.percentile(lat, 50))
        fig.status_p99_ms = float(np.percentile(lat, 99))
        fig.status_max_ms = float(lat.max())
        started = np.array(probe.started_s[: lat.size] or [0.0])
        minute = (started // 60).astype(int)
        fig.status_p99_by_minute_ms = [
            round(float(np.percentile(lat[minute == m], 99)), 1)
            for m in range(int(minute.max()) + 1)
            if (minute == m).sum() >= 300  # a whole minute (600 calls at 0.1 s)
        ]
        fig.status_slow = [
            (round(float(t), 2), round(float(v), 1))
            for t, v in zip(started, lat, strict=True)
            if v > 50
        ]
        fig.http_500 = sum(n for code, n in (codes + probe.codes).items() if code >= 500)
        if probe.codes.get(-1):
            fig.errors.append(f"{probe.codes[-1]} status calls got no answer")
        fig.injected, fig.reported = count_faults(log_text)
        if "Traceback" in log_text:
            fig.errors.append("the service log has a traceback: " + _first_traceback(log_text))
    return fig


def _cpu_s(pid: int) -> float:
    """User + system CPU time of process ``pid`` so far, s (Linux ``/proc``; 0 elsewhere)."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return 0.0
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def _load_average() -> float:
    try:
        return os.getloadavg()[1]
    except OSError:
        return float("nan")


_GAP = re.compile(r"load cell (\d+): load cell samples (\d+)\.\.(\d+) lost on the CAN bus")
_UNSEEN = re.compile(r"simulated fault note: (\d+) fifo_overflow")


def count_faults(log_text: str) -> tuple[dict[str, int], dict[str, int]]:
    """Faults injected and reported, by kind, from the service log. CAN: one gap of the load
    cell stream (reported block by block, merged when contiguous) per frame lost, bus-off or
    overload (the amplifier simulator starved of CPU drops the frames it is behind with);
    FIFO overflows the DAQ's reset discarded unread are not counted as injected."""
    injected = Counter(_INJECTED.findall(log_text))
    injected.pop("note", None)
    injected["fifo_overflow"] -= sum(int(n) for n in _UNSEEN.findall(log_text))
    reported = {k: len(re.findall(v, log_text)) for k, v in REPORTS.items() if "CAN" not in v}
    gaps = 0
    last: dict[str, int] = {}
    for node, a, b in _GAP.findall(log_text):
        if last.get(node) != int(a):
            gaps += 1
        last[node] = int(b) + 1
    reported["can_frame_loss + can_bus_off"] = gaps
    can = sum(injected.pop(k, 0) for k in ("can_frame_loss", "can_bus_off", "can_overload"))
    injected["can_frame_loss + can_bus_off"] = can
    return {k: v for k, v in injected.items() if v or k in reported}, reported


def _first_traceback(text: str) -> str:
    i = text.index("Traceback")
    return text[i : i + 1500]


def _acquire(call: Any, setup_id: int, averages: int, seed: int, fig: Figures, say: Any) -> None:
    body = {
        "setup_id": setup_id,
        "averages_per_input": averages,
        "min_averages": averages,
        "seed": seed,
    }
    r = call("POST", "/api/acquisitions", json=body)
    if r.status_code >= 400:
        fig.acquisitions_failed.append(f"start: HTTP {r.status_code} {r.text[:300]}")
        return
    acq_id = r.json()["id"]
    seen: set[int] = set()
    deadline = time.monotonic() + 600
    while True:
        a = call("GET", f"/api/acquisitions/{acq_id}").json()
        seen |= {int(v["number"]) for v in a.get("averages", []) if v.get("accepted")}
        if a["state"] not in ("pending", "running") or time.monotonic() > deadline:
            break
        time.sleep(0.2)
    final = {int(v["number"]) for v in a.get("averages", []) if v.get("accepted")}
    fig.acquisitions += 1
    fig.averages_accepted += len(final)
    fig.averages_rejected += sum(1 for v in a.get("averages", []) if not v.get("accepted"))
    fig.averages_lost += len(seen - final)
    if a["state"] != "succeeded" or a.get("frf_id") is None:
        what = f"acquisition {acq_id}: {a['state']}: {a.get('message')}"
        if a["state"] == "incomplete" or (
            a["state"] == "failed" and "acceptable averages" in str(a.get("message"))
        ):
            fig.acquisitions_incomplete.append(what)
        else:
            fig.acquisitions_failed.append(what)
        say(f"acquisition {acq_id} ended {a['state']}: {a.get('message')}")


def table(fig: Figures) -> str:
    """The README table of a run."""
    rows = [
        "| fault (injected at random) | injected | reported by drivers / session |",
        "| --- | ---: | ---: |",
    ]
    for kind in sorted(set(fig.injected) | set(REPORTS)):
        rows.append(f"| {kind} | {fig.injected.get(kind, 0)} | {fig.reported.get(kind, 0)} |")
    rows += [
        "",
        "| figure | value |",
        "| --- | ---: |",
        f"| run length | {fig.minutes:.1f} min |",
        f"| digitized points accepted / lost | {fig.points_accepted} / {fig.points_lost} |",
        f"| acquisitions: succeeded with FRFs / refused incomplete / failed | "
        f"{fig.acquisitions - len(fig.acquisitions_failed) - len(fig.acquisitions_incomplete)}"
        f" / {len(fig.acquisitions_incomplete)} / {len(fig.acquisitions_failed)} |",
        f"| averages accepted / rejected / lost | {fig.averages_accepted} / "
        f"{fig.averages_rejected} / {fig.averages_lost} |",
        f"| HTTP 500 | {fig.http_500} |",
        f"| status calls; latency p50 / p99 / max | {fig.status_calls}; {fig.status_p50_ms:.1f} /"
        f" {fig.status_p99_ms:.1f} / {fig.status_max_ms:.1f} ms |",
        f"| status p99 of the worst whole minute | "
        f"{max(fig.status_p99_by_minute_ms, default=float('nan')):.1f} ms |",
        f"| status calls over 50 ms | {len(fig.status_slow)} |",
        f"| service CPU per second of run; machine load average (5 min) | "
        f"{fig.service_cpu_per_s:.2f} s; {fig.load_average:.1f} |",
    ]
    return "\n".join(rows)


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] == ["--probe"]:  # the status probe's own process (_StatusProbe)
        _probe_main(argv[1], argv[2], float(argv[3]), argv[4])
        return 0
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--minutes", type=float, default=30.0)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--inputs", type=int, default=2, help="inputs of the soak's setup")
    ap.add_argument("--averages", type=int, default=3, help="averages per input")
    ap.add_argument("--json", type=Path, default=None)
    ap.add_argument("--keep", type=Path, default=None, help="keep the data and service log here")
    add_results_argument(ap, __file__)
    args = ap.parse_args(argv)
    res = Results(__file__, "Soak with faults", args.results)
    res.command = " ".join(["python", res.shown, *map(shlex.quote, argv)])
    fig = run_soak(
        args.minutes,
        seed=args.seed,
        n_inputs=args.inputs,
        averages=args.averages,
        workdir=args.keep,
    )
    print(table(fig))
    said = []
    for e in fig.errors + fig.acquisitions_failed:
        print("problem:", e)
        said.append(f"- problem: {e}")
    for e in fig.acquisitions_incomplete:
        print("incomplete (refused, nothing lost):", e)
        said.append(f"- incomplete (refused, nothing lost): {e}")
    res.add(table(fig))
    if said:
        res.add("\n".join(said))
    res.write()
    if args.json:
        args.json.write_text(json.dumps(fig.__dict__, indent=2) + "\n", encoding="utf-8")
    ok = (
        not fig.errors
        and not fig.acquisitions_failed
        and fig.points_lost == 0
        and fig.averages_lost == 0
        and fig.http_500 == 0
        and fig.status_p99_ms < 50
    )
    return 0 if ok else 1


if __name__ == "__main__":
    raise SystemExit(main())
