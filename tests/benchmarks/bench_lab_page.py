"""Lab page speed: page load and a plot of 30 FRFs × 2048 lines, in headless Chromium.

Starts ``dimacq serve`` on the simulated lab (scenario calibration-mass-bungee), stores the bundled
example (``config/examples/six_triax_setup.toml`` and its FRFs), then in Debian's ``chromium``
(driven by Playwright's Python package, no browser download):

- **page load**: ``/`` until the page says it is ready (every step's first data loaded: status,
  tests, setups, the simulated article, FRF sets, solutions, the rig file), navigation start →
  ready, milliseconds: cold = the first request after ``dimacq serve`` prints the page's address
  (a new service each time, a fresh browser context), warm = reloads;
- **plot**: the page's own ``plot.js`` draws 30 series × 2048 lines (log magnitude) on a
  1200 × 400 canvas, repeated; milliseconds per draw;
- **FRF step**: opening the stored FRF set in step 4 (fetch, flatten, magnitude, coherence and
  CMIF plots), milliseconds;
- **report**: ``/report?solution=N`` of a solution of the simulated lab's whole FRF set
  (``dimacq simulate calibration-mass-bungee``, imported as one whole-test UFF), navigation
  start → drawn; beside it what fetching that set whole (``/data``, what the report used to do)
  takes in the same page.

Targets: page load < 1 s; 30 FRFs × 2048 lines drawn < 1 s; report ~1 s.

    nice python tests/benchmarks/bench_lab_page.py [--repeat 10] [--cold 3] [--results PATH]

The figures go to ``bench_lab_page_results.md`` beside this script (``--results`` elsewhere)
with the command, date, commit and machine load.
"""

from __future__ import annotations

import argparse
import os
import shutil
import signal
import subprocess
import sys
import tempfile
from pathlib import Path
from statistics import median

import httpx

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from _results import Results, add_results_argument

from dimacq.api.server import free_port
from dimacq.config import default_config_file

TOKEN = "bench-token"
PLOT_JS = """async ([n, k]) => {
  const { linePlot } = await import('/static/plot.js');
  const c = document.createElement('canvas');
  c.style.width = '1200px'; c.style.height = '400px';
  document.body.appendChild(c);
  const x = new Float64Array(n);
  for (let i = 0; i < n; i++) x[i] = i * 0.25;
  const series = [];
  for (let s = 0; s < k; s++) {
    const y = new Float64Array(n);
    for (let i = 0; i < n; i++) y[i] = (1 + s) * (1 + Math.abs(Math.sin(i / 50 + s)));
    series.push({ y });
  }
  const t0 = performance.now();
  linePlot(c, { x, series, logY: true });
  const ms = performance.now() - t0;
  c.remove();
  return ms;
}"""
READY_MS = (
    "() => { const n = performance.getEntriesByType('navigation')[0];"
    " return window.dimacq.timings.ready_ms - n.startTime; }"
)


def _serve(data: Path) -> tuple[subprocess.Popen[str], str]:
    """``dimacq serve`` on a free port; returns once it prints the page's address (ready)."""
    port = free_port()
    env = {
        **os.environ,
        "DIMACQ_TOKEN": TOKEN,
        "DIMACQ_SCENARIO": "calibration-mass-bungee",
        "DIMACQ_DIGITIZER_URL": f"simdigitizer://bench{port}?seed=3",
        "DIMACQ_DATABASE_URL": "",
    }
    proc = subprocess.Popen(
        [sys.executable, "-m", "dimacq.cli.main", "serve", "--port", str(port)]
        + ["--data-dir", str(data), "--log-level", "warning"],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        env=env,
        text=True,
    )
    assert proc.stdout is not None
    seen = []
    for line in proc.stdout:
        seen.append(line)
        if line.startswith("lab page:"):
            return proc, f"http://127.0.0.1:{port}"
    raise SystemExit("dimacq serve did not start:\n" + "".join(seen))


def _stop(proc: subprocess.Popen[str]) -> None:
    proc.send_signal(signal.SIGINT)
    try:
        proc.communicate(timeout=20)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.communicate()


def _store_example(url: str) -> int:
    ex = default_config_file().parent / "examples"
    auth = {"Authorization": f"Bearer {TOKEN}"}
    with httpx.Client(base_url=url, headers=auth, timeout=60) as c:
        setup = c.post(
            "/api/setups/import?format=toml&name=example",
            content=(ex / "six_triax_setup.toml").read_bytes(),
        )
        setup.raise_for_status()
        sid = setup.json().get("setup_id") or setup.json()["id"]
        frf = c.post(
            f"/api/frfs/import?setup_id={sid}&name=example",
            content=(ex / "six_triax_frf.uff").read_bytes(),
        )
        frf.raise_for_status()
        return int(frf.json()["id"])


def _store_simulated_test(url: str, tmp: Path) -> tuple[int, str]:
    """The simulated lab's whole FRF set as one whole-test UFF, imported and solved in its band
    (equation error: the report, not the solve, is measured); returns the solution id and the
    set's size."""
    from dimacq.simulators.lab.scenarios import build_scenario

    uff, truth = tmp / "sim.uff", tmp / "sim_truth.json"
    subprocess.run(
        [sys.executable, "-m", "dimacq.cli.main", "simulate", "calibration-mass-bungee"]
        + ["--frf", str(uff), "--truth", str(truth)],
        check=True,
        capture_output=True,
    )
    band = [float(b) for b in build_scenario("calibration-mass-bungee", None).band_hz]
    auth = {"Authorization": f"Bearer {TOKEN}"}
    with httpx.Client(base_url=url, headers=auth, timeout=300) as c:
        imp = c.post("/api/setups/import?format=uff&name=simulated", content=uff.read_bytes())
        imp.raise_for_status()
        frf = c.get(f"/api/frfs/{imp.json()['frf_id']}").json()
        sol = c.post(
            "/api/solutions",
            json={"frf_id": frf["id"], "band_hz": band, "unbiased": False},
        )
        sol.raise_for_status()
    size = f"{frf['n_responses']} responses x {frf['n_inputs']} inputs x {frf['n_lines']} lines"
    return int(sol.json()["id"]), size


WHOLE_SET_MS = """async (id) => {
  const t0 = performance.now();
  const r = await fetch(`/api/frfs/${id}/data`);
  const d = await r.json();
  return [performance.now() - t0, d.frequencies_hz.length];
}"""


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--repeat", type=int, default=10)
    ap.add_argument("--cold", type=int, default=3, help="service starts for the cold load")
    add_results_argument(ap, __file__)
    args = ap.parse_args()
    res = Results(__file__, "Lab page speed in headless Chromium", args.results)
    chromium = shutil.which("chromium")
    if chromium is None:
        raise SystemExit("Debian's chromium is not installed (apt-get install -y chromium)")
    from playwright.sync_api import sync_playwright

    with tempfile.TemporaryDirectory() as tmp, sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=chromium)
        version = browser.version
        cold: list[float] = []
        for k in range(args.cold):  # a new service each time: its first request, a fresh context
            proc, url = _serve(Path(tmp) / f"cold{k}")
            try:
                ctx = browser.new_context(viewport={"width": 1280, "height": 900})
                page = ctx.new_page()
                page.goto(f"{url}/#token={TOKEN}")
                page.wait_for_selector("body[data-ready='1']", timeout=60_000)
                cold.append(page.evaluate(READY_MS))
                ctx.close()
            finally:
                _stop(proc)
        proc, url = _serve(Path(tmp) / "data")
        try:
            frf_id = _store_example(url)
            ctx = browser.new_context(viewport={"width": 1280, "height": 900})
            page = ctx.new_page()
            page.goto(f"{url}/#token={TOKEN}")
            page.wait_for_selector("body[data-ready='1']", timeout=30_000)
            warm: list[float] = []
            for _ in range(args.repeat):
                page.reload()
                page.wait_for_selector("body[data-ready='1']", timeout=30_000)
                warm.append(page.evaluate(READY_MS))
            plot = [page.evaluate(PLOT_JS, [2048, 30]) for _ in range(args.repeat)]
            page.select_option("#frf-set", str(frf_id))
            page.wait_for_function(f"() => window.dimacq.frf && window.dimacq.frf.id === {frf_id}")
            info = page.inner_text("#frf-info")
            step = page.evaluate(
                "() => [window.dimacq.timings.frf_fetch_ms, window.dimacq.timings.frf_draw_ms]"
            )
            # the report of a solution of the simulated lab's whole set
            sol_id, size = _store_simulated_test(url, Path(tmp))
            report: list[float] = []
            for _ in range(3):
                rp = ctx.new_page()
                rp.goto(f"{url}/report?solution={sol_id}")
                rp.wait_for_selector("body[data-ready='1']", timeout=120_000)
                report.append(
                    rp.evaluate(
                        "() => performance.now()"
                        " - performance.getEntriesByType('navigation')[0].startTime"
                    )
                )
                whole = rp.evaluate(WHOLE_SET_MS, sol_frf(url, sol_id))
                rp.close()
            browser.close()
        finally:
            _stop(proc)
    print(f"chromium {version}, {os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.1f}")
    res.note(f"chromium {version}")
    said = [
        f"page load, navigation start -> ready: cold (first request after the service printed "
        f"its address) median {median(cold):.0f} ms (max {max(cold):.0f}, n={len(cold)}); warm "
        f"median {median(warm):.0f} ms (max {max(warm):.0f}, n={len(warm)}); target < 1000 ms",
        f"plot 30 FRFs x 2048 lines: median {median(plot):.1f} ms (max {max(plot):.1f}, "
        f"n={len(plot)}); target < 1000 ms",
        f"FRF step, example set ({info}): fetch {step[0]:.0f} ms, magnitude plot {step[1]:.1f} ms",
        f"report, simulated set ({size}): navigation -> drawn median {median(report):.0f} ms "
        f"(max {max(report):.0f}, n={len(report)}); the whole set fetched and parsed as the "
        f"report did before: {whole[0]:.0f} ms",
    ]
    print("\n".join(said))
    res.add("\n".join(f"- {x}" for x in said))
    res.write()


def sol_frf(url: str, solution_id: int) -> int:
    return int(httpx.get(f"{url}/api/solutions/{solution_id}", timeout=60).json()["frf_id"])


if __name__ == "__main__":
    main()
