"""Lab page speed (issue 13): page load and a plot of 30 FRFs × 2048 lines, in headless Chromium.

Starts ``dimacq serve`` on the simulated lab (scenario calibration-mass-bungee), stores the bundled
example (``config/examples/six_triax_setup.toml`` and its FRFs), then in Debian's ``chromium``
(driven by Playwright's Python package, no browser download):

- **page load**: ``/`` until the page says it is ready (every step's first data loaded: status,
  setups, the simulated article, FRF sets, solutions, the rig file), cold (first visit, fresh
  browser context) and warm (reloads); navigation start → ready, milliseconds;
- **plot**: the page's own ``plot.js`` draws 30 series × 2048 lines (log magnitude) on a
  1200 × 400 canvas, repeated; milliseconds per draw;
- **FRF step**: opening the stored FRF set in step 4 (fetch, flatten, magnitude, coherence and
  CMIF plots), milliseconds.

Targets: page load < 1 s; 30 FRFs × 2048 lines drawn < 1 s.

    python tests/benchmarks/bench_lab_page.py [--repeat 10]
"""

from __future__ import annotations

import argparse
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from statistics import median

import httpx

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
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        env=env,
        text=True,
    )
    url = f"http://127.0.0.1:{port}"
    deadline = time.monotonic() + 60
    while True:
        try:
            httpx.get(f"{url}/api/status", timeout=1).raise_for_status()
            return proc, url
        except httpx.TransportError:
            if proc.poll() is not None or time.monotonic() > deadline:
                proc.kill()
                raise SystemExit(f"dimacq serve did not start: {proc.communicate()[1]}") from None
            time.sleep(0.1)


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


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--repeat", type=int, default=10)
    args = ap.parse_args()
    chromium = shutil.which("chromium")
    if chromium is None:
        raise SystemExit("Debian's chromium is not installed (apt-get install -y chromium)")
    from playwright.sync_api import sync_playwright

    with tempfile.TemporaryDirectory() as tmp:
        proc, url = _serve(Path(tmp) / "data")
        try:
            frf_id = _store_example(url)
            with sync_playwright() as pw:
                browser = pw.chromium.launch(executable_path=chromium)
                cold: list[float] = []
                for _ in range(3):  # a fresh context each time: nothing cached
                    ctx = browser.new_context(viewport={"width": 1280, "height": 900})
                    page = ctx.new_page()
                    page.goto(f"{url}/#token={TOKEN}")
                    page.wait_for_selector("body[data-ready='1']", timeout=30_000)
                    cold.append(page.evaluate(READY_MS))
                    ctx.close()
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
                page.wait_for_function(
                    f"() => window.dimacq.frf && window.dimacq.frf.id === {frf_id}"
                )
                info = page.inner_text("#frf-info")
                step = page.evaluate(
                    "() => [window.dimacq.timings.frf_fetch_ms, window.dimacq.timings.frf_draw_ms]"
                )
                version = browser.version
                browser.close()
        finally:
            proc.send_signal(signal.SIGINT)
            try:
                proc.communicate(timeout=20)
            except subprocess.TimeoutExpired:
                proc.kill()
    print(f"chromium {version}, {os.cpu_count()} CPUs, service {url}")
    print(
        f"page load, navigation start -> ready: cold median {median(cold):.0f} ms "
        f"(max {max(cold):.0f}, n={len(cold)}); warm median {median(warm):.0f} ms "
        f"(max {max(warm):.0f}, n={len(warm)})   target < 1000 ms"
    )
    print(
        f"plot 30 FRFs x 2048 lines: median {median(plot):.1f} ms (max {max(plot):.1f}, "
        f"n={len(plot)})   target < 1000 ms"
    )
    print(
        f"FRF step, example set ({info}): fetch {step[0]:.0f} ms, magnitude plot {step[1]:.1f} ms"
    )


if __name__ == "__main__":
    main()
