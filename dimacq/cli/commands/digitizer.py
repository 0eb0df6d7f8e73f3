"""``dimacq digitizer``: sonic digitizer selftest and simulator.

``dimacq digitizer selftest [--port URL] [--shots N] [--echo-rate R] [--json OUT]`` digitizes the
simulator's known points through the wire protocol and prints the accuracy figures (tip RMS error,
echoes injected/accepted, temperature step, jig orientation, line of action, solver throughput),
with the thesis Table 1 style orthogonality check of each jig fit.
``dimacq digitizer sim-pty`` serves a simulated digitizer on a pseudo-terminal.
``dimacq digitizer import-points FILE`` sends labelled points measured by another instrument
(CSV/JSON, ``dimacq/io/measured_points.py``) to the running service as a new patch.
"""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path
from typing import Any, Literal

from dimacq.errors import SetupError

# pass/fail limits of the selftest
LIMITS = {
    "tip_rms_mm": 0.5,
    "echoes_accepted": 0,
    "temperature_step_added_mm": 0.2,
    "jig_orientation_rms_deg": 0.1,
    "jig_two_rod_cross_rms_deg": 0.2,
    "line_of_action_rms_deg": 0.2,
}


def register(subparsers: Any) -> None:
    parser = subparsers.add_parser("digitizer", help="sonic digitizer: selftest, simulator")
    sub = parser.add_subparsers(dest="digitizer_command", metavar="ACTION")
    sub.required = True

    st = sub.add_parser(
        "selftest", help="digitize the simulator's known points and report accuracy"
    )
    st.add_argument("--port", default=None, help="pyserial URL (default: a new simdigitizer://)")
    st.add_argument("--shots", type=int, default=1000, help="shots on known points (default 1000)")
    st.add_argument("--shots-per-point", type=int, default=5)
    st.add_argument("--echo-rate", type=float, default=0.02, help="echo probability per shot")
    st.add_argument("--temperature", type=float, default=20.0, help="air temperature, degC")
    st.add_argument("--temperature-step", type=float, default=10.0, help="change for the 2nd pass")
    st.add_argument("--jigs", type=int, default=4, help="jig placements (24 points each)")
    st.add_argument("--seed", type=int, default=1)
    st.add_argument("--config", type=Path, default=None, help="array.toml")
    st.add_argument("--jig", type=Path, default=None, help="jig.toml")
    st.add_argument("--timeout", type=float, default=2.0, help="reply timeout, s")
    st.add_argument(
        "--json", type=Path, default=None, metavar="OUT", help="write the figures as JSON"
    )
    st.set_defaults(func=selftest)

    imp = sub.add_parser(
        "import-points",
        help="points measured by another instrument (CSV/JSON) into the running service",
    )
    imp.add_argument("file", type=Path, help="labelled points: CSV (label,x_mm,y_mm,z_mm) or JSON")
    imp.add_argument("--format", choices=["csv", "json"], default=None, help="default: suffix")
    imp.add_argument("--name", default=None, help="the patch's name (default: the instrument's)")
    imp.add_argument(
        "--url", default=None, help="the service (default: http://host:port of the settings)"
    )
    imp.add_argument("--token", default=None, help="its API token (default: the settings')")
    imp.set_defaults(func=import_points)

    pty = sub.add_parser("sim-pty", help="serve a simulated digitizer on a pseudo-terminal")
    pty.add_argument("--seed", type=int, default=0)
    pty.add_argument("--echo-rate", type=float, default=0.0)
    pty.add_argument("--temperature", type=float, default=20.0)
    pty.add_argument("--rate", type=float, default=0.0, help="stream rate, shots/s (0: at once)")
    pty.add_argument("--config", type=Path, default=None)
    pty.add_argument("--duration", type=float, default=0.0, help="seconds (0: until Ctrl-C)")
    pty.set_defaults(func=sim_pty)


def selftest(args: argparse.Namespace) -> int:
    from dimacq.drivers.digitizer import SerialDigitizer
    from dimacq.pipeline.digitizing.orientation import orthogonality_table
    from dimacq.services.geometry.digitizer_config import load_array_config, load_jig
    from dimacq.services.geometry.digitizer_selftest import run_selftest

    if args.shots < 1 or not 0.0 <= args.echo_rate <= 1.0:
        raise SetupError("selftest: --shots must be >= 1 and --echo-rate within 0..1")
    url = args.port
    owned_name = None
    if url is None:
        owned_name = f"selftest-{os.getpid()}"
        url = f"simdigitizer://{owned_name}?seed={args.seed}"
    if url.startswith("simdigitizer://"):
        import dimacq.simulators.digitizer  # noqa: F401  (registers the URL scheme)
    cfg = load_array_config(args.config)
    jig = load_jig(args.jig)
    driver = SerialDigitizer.from_url(url, timeout_s=args.timeout)
    try:
        ident = driver.identify()
        if not ident.model.endswith("SIM"):
            raise SetupError(
                f"selftest on {url}: {ident.vendor} {ident.model} is a real array; the selftest needs "
                "the simulator's known points (use simdigitizer:// or a pty from 'dimacq digitizer sim-pty')"
            )
        report = run_selftest(
            driver,
            cfg,
            jig,
            shots=args.shots,
            shots_per_point=args.shots_per_point,
            echo_rate=args.echo_rate,
            temperature_c=args.temperature,
            temperature_step_c=args.temperature_step,
            n_jigs=args.jigs,
            seed=args.seed,
        )
    finally:
        driver.close()
        if owned_name is not None:
            from dimacq.simulators.digitizer import unregister_device

            unregister_device(owned_name)
    values = report.as_dict()
    values["port"] = url
    values["device"] = f"{ident.vendor} {ident.model} {ident.serial}"
    print(f"digitizer selftest on {url} ({values['device']})")
    failed = []
    for key, value in values.items():
        mark = ""
        if key in LIMITS:
            ok = value <= LIMITS[key]
            mark = f"  {'PASS' if ok else 'FAIL'} (limit {LIMITS[key]})"
            if not ok:
                failed.append(key)
        text = f"{value:.4g}" if isinstance(value, float) else str(value)
        print(f"  {key:<42} {text:>14}{mark}")
    if report.orthogonality_checks:
        print("\nDirection cosine orthogonality check C'^T C' (thesis Eq. 12, Table 1 layout):")
        print(orthogonality_table(report.jig_names, report.orthogonality_checks))
    if args.json is not None:
        args.json.write_text(json.dumps(values, indent=2) + "\n")
    return 1 if failed else 0


def sim_pty(args: argparse.Namespace) -> int:
    from dimacq.simulators.digitizer.__main__ import main as sim_main

    argv = ["--pty", "--seed", str(args.seed), "--echo-rate", str(args.echo_rate)]
    argv += ["--temperature", str(args.temperature), "--rate", str(args.rate)]
    argv += ["--duration", str(args.duration)]
    if args.config is not None:
        argv += ["--config", str(args.config)]
    return sim_main(argv)


def import_points(args: argparse.Namespace) -> int:
    """POST the file to ``/api/digitizer/points/import`` of the running service (``dimacq
    serve``): a new patch of labelled points, to register from reference nodes and orient as
    digitized points (``POST /api/digitizer/registrations``, ``/orientations``, ...)."""
    import httpx

    from dimacq.config import load_settings
    from dimacq.io.measured_points import read_measured_points

    path: Path = args.file
    given = args.format or path.suffix.lstrip(".").lower()
    if given not in ("csv", "json"):
        raise SetupError(f"{path}: format {given!r}; give --format csv or json")
    fmt: Literal["csv", "json"] = "csv" if given == "csv" else "json"
    data = path.read_bytes()
    read_measured_points(data, fmt, what=str(path))  # a bad file: named here, nothing sent
    settings = load_settings()
    url = args.url or f"http://{settings.host}:{settings.port}"
    token = args.token or settings.token
    try:
        r = httpx.post(
            f"{url}/api/digitizer/points/import",
            params={"format": fmt, **({"name": args.name} if args.name else {})},
            content=data,
            headers={"Authorization": f"Bearer {token}"},
            timeout=60,
        )
    except httpx.HTTPError as err:
        raise SetupError(f"{url}: {err}; start the service (dimacq serve) or give --url") from err
    if r.status_code != 201:
        raise SetupError(f"{url}: import refused ({r.status_code}): {r.text[:300]}")
    pts = r.json()
    patch = pts[0]["patch"] if pts else None
    print(
        f"{len(pts)} points imported from {path} as patch {patch}; register it from reference "
        "nodes (POST /api/digitizer/registrations)"
    )
    return 0
