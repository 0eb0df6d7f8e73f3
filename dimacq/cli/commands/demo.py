"""``dimacq demo [--json OUT]``: a complete simulated DIM test, driven through the HTTP API.

The command starts the lab service in-process on a free loopback port (a fresh data directory
unless ``--data-dir``), then acts as the test engineer over HTTP only:

0. calibrates the measurement chain (hammer and accelerometers) on the lab's weighed reference
   block (``config/reference-block/``: its drawing as the setup, its weighing certificate), in a
   service of its own on the same data directory, run in a process of its own while steps 1–3
   digitize (:mod:`dimacq.cli.demo_steps`); the test acquires once step 0 is done, and its
   solve applies the factor (``chain_calibration_id``). ``--no-chain-calibration`` skips it;

Unless ``--full``, both acquisitions take what the demo needs to show the chain and the answer
within its limits (:data:`~dimacq.cli.demo_steps.QUICK`: 3 averages of 2048 samples per input,
the chain check 2), not the rig file's 5 of 4096: about a third of the simulated time;

1. places the simulated digitizer's array in front of the test article and registers it from
   reference nodes with known coordinates;
2. digitizes the 24 indentations of the orientation jig on every triaxial sensor and fits each
   sensor's orientation; digitizes each impact point and three points along the hammer's line of
   action and fits it;
3. builds the test setup from that geometry (the load cell is given);
4. acquires the impacts (``POST /api/acquisitions`` → job followed over server-sent events)
   through the configured DAQ and load cell backends, as ``dimacq acquire`` does. A demo that
   cannot acquire (a device missing, a backend name unknown) fails with the reason (exit 2); it
   never substitutes other data. ``--model-frfs`` asks instead for the virtual lab's FRFs of the
   *true* article (with ``--noise``), imported as UFF through ``POST /api/frfs/import``: a check
   of the solver, not of the measurement chain, and the output says so first;
   The simulated DAQ runs at a time-lapse chosen at start for both acquisitions: the setting
   ``simulation_imperfections.daq_time_scale`` when given, else half of what this host sustains
   now (a timed probe, :mod:`dimacq.backends.time_lapse`); the summary says the factor and
   whether the host kept up (no DAQ FIFO overflow, no load cell frames dropped);
5. solves (``POST /api/solutions`` with the service's defaults: automatic band, response and
   input selection; ``--scenario-band`` imposes the scenario's recommended band) and prints the
   result against the scenario's truth.

The simulated engineer knows where the probe is (the ``sim_probe`` field tells the simulator);
everything the service learns it measures through the digitizer. ``--json OUT`` writes the solution
with the keys of ``dimacq solve --json`` plus ``truth`` (same keys), ``elapsed_s`` and ``demo``
(what was done, how, and the errors).
"""

from __future__ import annotations

import argparse
import json
import secrets
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

import numpy as np

from dimacq.cli.demo_steps import (
    QUICK,
    REFERENCE_SCENARIO,
    ChainCheck,
    acquire,
    acquisition_plan,
    check,
)
from dimacq.cli.progress import add_quiet, plain

if TYPE_CHECKING:
    from dimacq.backends.time_lapse import HostLag


def register(sub: Any) -> None:
    p = sub.add_parser(
        "demo",
        help="run a complete simulated DIM test through the HTTP API",
        description=plain(__doc__),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--json", type=Path, default=None, metavar="OUT", help="write the solution JSON")
    p.add_argument("--scenario", default="calibration-mass-bungee", help="virtual lab scenario")
    p.add_argument("--seed", type=int, default=None, help="seed (default: the scenario's own)")
    p.add_argument(
        "--averages-per-input",
        "--averages",
        dest="averages",
        type=int,
        default=None,
        metavar="N",
        help=f"accepted averages per input (the API's averages_per_input; default "
        f"{QUICK['averages_per_input']}, with --full the rig file's)",
    )
    p.add_argument(
        "--record-samples",
        type=int,
        default=None,
        metavar="N",
        help=f"samples per average (the API's record_samples; default {QUICK['record_samples']}, "
        "with --full the rig file's)",
    )
    p.add_argument(
        "--full",
        action="store_true",
        help="acquire both tests as the rig file sets them (5 averages of 4096 samples per input "
        "for the calibration mass: about 4 times the demo's simulated time)",
    )
    p.add_argument(
        "--model-frfs",
        action="store_true",
        help="do not acquire: import the virtual lab's FRFs of the TRUE article (a check of the "
        "solver, not of the chain; no chain calibration). Without it a demo that cannot acquire "
        "fails (exit 2)",
    )
    p.add_argument(
        "--noise", type=float, default=0.005, help="relative FRF noise (--model-frfs only)"
    )
    p.add_argument(
        "--data-dir", type=Path, default=None, help="data directory (default: temporary)"
    )
    p.add_argument(
        "--rig-file",
        type=Path,
        default=None,
        help="the simulated rig's channel map and calibrations (default: the scenario's rig, "
        "config/rigs/<scenario>.toml or config/rig.toml)",
    )
    p.add_argument(
        "--scenario-band",
        action="store_true",
        help="solve in the scenario's recommended band (default: the service's defaults, "
        "automatic band and selections, as a user gets them)",
    )
    p.add_argument(
        "--geometry",
        choices=["digitizer", "photos"],
        default="digitizer",
        help="how steps 1-2 measure the geometry: the sonic digitizer and the jig (default), or "
        "photos of fiducial tags from the simulated camera (dimacq geometry from-photos)",
    )
    p.add_argument(
        "--photos", type=int, default=40, metavar="N", help="photos taken (--geometry photos)"
    )
    p.add_argument(
        "--no-chain-calibration",
        action="store_true",
        help="skip step 0 (measuring the chain on the weighed reference block); the rig file's "
        "recorded chain calibration, if any, still applies",
    )
    add_quiet(p)
    p.set_defaults(func=run)


# ------------------------------------------------------------------------------------ scenario
def _scenario(name: str, seed: int | None) -> Any:
    """The scenario made concrete (true article, truth, recommended band)."""
    from dimacq.simulators.lab.scenarios import build_scenario

    return build_scenario(name, seed)


class _Array:
    """Where the simulated engineer put the digitizer array: DACS = R·GCS + t."""

    def __init__(self, rng: np.random.Generator, centre_gcs: np.ndarray) -> None:
        from scipy.spatial.transform import Rotation

        self.rot = Rotation.from_euler("zyx", rng.uniform(-25, 25, 3), degrees=True)
        self.t = np.array([0.0, 0.0, 1.1]) - self.rot.apply(centre_gcs)

    def dacs(self, p_gcs: np.ndarray) -> list[float]:
        return [float(v) for v in self.rot.apply(np.asarray(p_gcs, float)) + self.t]


# ------------------------------------------------------------------------------------ run
def run(args: argparse.Namespace) -> int:
    from dimacq.api import create_app
    from dimacq.api.server import BackgroundServer
    from dimacq.backends.time_lapse import HostLag, rig_time_lapse
    from dimacq.config import load_settings, scenario_rig_file

    t0 = time.perf_counter()
    say: Callable[[str], None] = (
        (lambda _m: None) if args.quiet else (lambda m: print(m, flush=True))
    )
    built = _scenario(args.scenario, args.seed)
    tmp = None
    data_dir = args.data_dir
    if data_dir is None:
        tmp = tempfile.TemporaryDirectory(prefix="dimacq-demo-")
        data_dir = Path(tmp.name)
    token = secrets.token_urlsafe(16)
    settings = load_settings(
        data_dir=data_dir,
        token=token,
        host="127.0.0.1",
        digitizer_url=f"simdigitizer://demo-{secrets.token_hex(4)}?seed={built.seed}",
        scenario=args.scenario,
        rig_file=str(args.rig_file) if args.rig_file else scenario_rig_file(args.scenario),
        database_url="",
    )
    # The simulated DAQ's time-lapse, for step 0 and the test alike: the setting's
    # (simulation_imperfections.daq_time_scale), else what this host sustains now.
    # (--model-frfs acquires nothing: no time-lapse)
    lapse = None
    imperfections = dict(settings.simulation_imperfections)
    if not args.model_frfs:
        lapse = rig_time_lapse(
            settings.simulation_imperfections,
            settings.rig_path,
            str(settings.loadcell),
            str(settings.daq),
        )
        imperfections["daq_time_scale"] = lapse.scale
        settings = settings.model_copy(update={"simulation_imperfections": imperfections})
        say(f"time-lapse: {lapse.describe()}")
    lag = HostLag()
    runs: list[dict[str, Any]] = []  # the acquisitions: wall seconds, averages, settings
    if args.model_frfs:
        say(
            "dimacq demo --model-frfs: NO ACQUISITION. The FRFs are the virtual lab's forward model "
            f"of the true article with {100 * args.noise:g} % noise: this checks the solver, not "
            "the measurement chain"
        )
    chain: ChainCheck | None = None
    try:
        if (
            not args.no_chain_calibration
            and not args.model_frfs
            and args.scenario != REFERENCE_SCENARIO
        ):  # step 0 in a process of its own while this service starts and steps 1-3 digitize
            from dimacq.persistence.db import open_database

            open_database(settings.db_url).close()  # the schema first: two services open it
            chain = ChainCheck(data_dir, token, args, imperfections, say)
        app = create_app(settings)
        backends = {k: str(getattr(settings, k)) for k in ("daq", "loadcell", "digitizer")}
        with BackgroundServer(app) as srv, lag.recording():
            say(f"dimacq demo: service on {srv.url} (data in {data_dir}), scenario {args.scenario}")
            say("backends: " + ", ".join(f"{k} = {v!r}" for k, v in backends.items()))
            payload = run_demo(srv.url, token, built, args, say, chain, backends, lag, runs)
        payload["demo"]["backends"] = backends
        if lapse is not None:
            # simulated seconds: what the DAQ clocked (its time-lapse adapts to the host)
            sim_s = lag.simulated_s or sum(r["wall_s"] for r in runs) * lapse.scale
            payload["demo"]["acquisitions"] = runs
            payload["demo"]["time_lapse"] = {
                **lapse.to_json(),
                **lag.to_json(),
                "acquisitions_wall_s": sum(r["wall_s"] for r in runs),
                "acquisitions_simulated_s": sim_s,
            }
            payload["demo"]["time_lapse_summary"] = (
                f"{lapse.describe()}; {len(runs)} acquisitions, about {sim_s:.0f} s of simulated "
                f"test in {sum(r['wall_s'] for r in runs):.1f} s ({lag.describe_factors()}); "
                f"{lag.describe()}"
            )
    finally:
        if chain is not None:
            chain.close()
        if tmp is not None:
            tmp.cleanup()
    payload["elapsed_s"] = time.perf_counter() - t0
    _print_result(payload, say)
    if args.json is not None:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(payload, indent=2) + "\n", encoding="utf-8")
    return 0


def _sim(kind: Literal["daq", "loadcell"], backend: str) -> str:
    from dimacq.backends import is_simulated

    return "simulated " if is_simulated(kind, backend) else ""


ACQUISITION = (
    "acquisition (the demo acquires as dimacq acquire does; --model-frfs solves model FRFs instead)"
)


def _acquisition_devices_connected(devices: dict[str, Any]) -> None:
    """Step 4 needs the DAQ and the load cell: refuse at once, as the acquisition would (the
    same reason: the service's own, from ``/api/status``), not after steps 1–3's digitizing."""
    from dimacq.errors import DeviceError

    missing = [
        f"{name} is not connected ({devices[name].get('error') or 'closed'})"
        for name in ("daq", "loadcell")
        if name in devices and not devices[name]["connected"]
    ]
    if missing:
        raise DeviceError(
            f"demo: {ACQUISITION} cannot start: {'; '.join(missing)}; connect it first"
        )


def run_demo(
    url: str,
    token: str,
    built: Any,
    args: argparse.Namespace,
    say: Callable[[str], None],
    chain_check: ChainCheck | None = None,
    backends: dict[str, str] | None = None,
    lag: HostLag | None = None,
    runs: list[dict[str, Any]] | None = None,
) -> dict[str, Any]:
    """Play the engineer's part of the demo against the service at ``url`` (bearer ``token``)
    through its HTTP API; the solve's result with the truth and the demo's figures (``"demo"``)."""
    import httpx

    rng = np.random.default_rng(built.seed + 1000)
    model = built.model
    setup_true = model.setup  # the TRUE geometry: what the digitizer measures
    band = [float(b) for b in built.band_hz]
    c = httpx.Client(base_url=url, headers={"Authorization": f"Bearer {token}"}, timeout=120)
    info: dict[str, Any] = {"scenario": built.spec.name, "seed": built.seed}
    chain: dict[str, Any] | None = None
    try:
        st = check(c.get("/api/status"), "status")
        say(
            "devices: "
            + ", ".join(
                f"{k} {'connected' if v['connected'] else 'not connected'}"
                for k, v in st["devices"].items()
            )
        )
        if not args.model_frfs:
            _acquisition_devices_connected(st["devices"])
        nodes = sorted({ch.node for ch in setup_true.responses})
        if args.geometry == "photos":
            photo = _photograph(c, built, args, say)
            rms_mm, ori_err, ori_unc, loa_err = (
                0.0,
                photo.pop("ori_err"),
                photo.pop("ori_unc"),
                photo.pop("loa_err"),
            )
            n_points = [0]
            info["photos"] = photo
        else:
            rms_mm, ori_err, ori_unc, loa_err, n_points = _digitize_geometry(
                c, setup_true, rng, nodes, info, say
            )
        sid = _setup_from_geometry(c, setup_true, nodes, args, info, say)
        # --- 4. acquisition, once step 0 is done: one acquisition at a time, and step 0's solve
        # (its modal fit can take both cores for seconds) not beside it: that starved the test's
        # acquisition into FIFO overflows at 18x on the loaded machine
        if chain_check is not None:
            chain_check.acquired(lag, runs)
            chain = chain_check.result()
            info["chain_calibration"] = chain
        frf_id = _acquire_frfs(c, built, sid, args, say, info, backends, lag, runs)
        sol = _solve_step(c, frf_id, chain, band, args, say)
    finally:
        c.close()
    payload: dict[str, Any] = dict(sol["result"])
    truth = built.truth_json()
    payload["truth"] = truth
    errors = _errors(payload, truth)
    info.update(
        {
            "points_digitized": n_points[0],
            "registration_rms_mm": rms_mm,
            "orientation_error_deg": {str(n): e for n, e in zip(nodes, ori_err, strict=True)},
            "orientation_error_rms_deg": float(np.sqrt(np.mean(np.square(ori_err)))),
            "orientation_uncertainty_deg": {str(n): u for n, u in zip(nodes, ori_unc, strict=True)},
            "line_of_action_error_rms_deg": float(np.sqrt(np.mean(np.square(loa_err)))),
            "setup_id": sid,
            "frf_id": frf_id,
            "solution_id": sol["id"],
            "errors": errors,
        }
    )
    payload["demo"] = info
    return payload


def _digitize_geometry(
    c: Any,
    setup_true: Any,
    rng: np.random.Generator,
    nodes: list[int],
    info: dict[str, Any],
    say: Callable[[str], None],
) -> tuple[float, list[float], list[float], list[float], list[int]]:
    """Steps 1–2 with the simulated digitizer: register the array, orient the triaxes, fit the
    lines of action. Returns the registration RMS (mm), the orientation errors and
    uncertainties (deg), the line-of-action errors (deg) and the count of points digitized."""
    n_points = [0]
    digitize, rms_mm = _register_array(c, setup_true, rng, n_points, info, say)
    ori_err, ori_unc = _orient_triaxes(c, setup_true, nodes, digitize, say)
    loa_err = _fit_lines_of_action(c, setup_true, digitize)
    say(
        f"[2/5] {len(loa_err)} lines of action: RMS error {np.sqrt(np.mean(np.square(loa_err))):.3f} deg; "
        f"{n_points[0]} points digitized"
    )
    return rms_mm, ori_err, ori_unc, loa_err, n_points


def _register_array(
    c: Any,
    setup_true: Any,
    rng: np.random.Generator,
    n_points: list[int],
    info: dict[str, Any],
    say: Callable[[str], None],
) -> tuple[Callable[[str, np.ndarray], None], float]:
    """Step 1: place the array before the article and register it on six reference nodes.

    Returns the function that digitizes a point (a true GCS position, probed through the
    array; ``n_points[0]`` counts them) and the registration's RMS residual in mm.
    """
    pos = np.vstack([setup_true.response_positions, setup_true.input_positions])
    lo, hi = pos.min(axis=0) - 0.02, pos.max(axis=0) + 0.02
    arr = _Array(rng, 0.5 * (lo + hi))
    refs = {
        f"REF{i}": [float(x), float(y), float(z)]
        for i, (x, y, z) in enumerate(
            [
                (lo[0], lo[1], lo[2]),
                (hi[0], lo[1], lo[2]),
                (lo[0], hi[1], lo[2]),
                (lo[0], lo[1], hi[2]),
                (hi[0], hi[1], hi[2]),
                (hi[0], lo[1], hi[2]),
            ]
        )
    }
    check(c.put("/api/digitizer/reference-nodes", json={"nodes": refs}), "reference nodes")

    def digitize(label: str, p_gcs: np.ndarray) -> None:
        body = {
            "label": label,
            "shots": 5,
            "sim_probe": {"tip_m": arr.dacs(p_gcs), "axis": [0.0, 0.0, 1.0]},
        }
        check(c.post("/api/digitizer/points", json=body), f"digitizing {label}")
        n_points[0] += 1

    for lab, ref in refs.items():
        digitize(lab, np.array(ref))
    reg = check(c.post("/api/digitizer/registrations", json={"method": "rigid"}), "registration")
    rms_mm = 1e3 * reg["registration"]["rms_m"]
    info["registration"] = {
        k: reg["registration"][k]
        for k in (
            "verdict",
            "reasons",
            "limit_m",
            "rms_m",
            "worst_node",
            "worst_residual_m",
        )
    }
    say(f"[1/5] array registered from {len(refs)} reference nodes: RMS residual {rms_mm:.3f} mm")
    return digitize, rms_mm


def _orient_triaxes(
    c: Any,
    setup_true: Any,
    nodes: list[int],
    digitize: Callable[[str, np.ndarray], None],
    say: Callable[[str], None],
) -> tuple[list[float], list[float]]:
    """Step 2a: digitize the jig on every triax and fit its orientation; return each fit's
    error against the true orientation and its stated uncertainty (deg)."""
    from dimacq.services.geometry.digitizer_config import load_jig

    jig = load_jig()
    ori_err = []
    ori_unc = []
    for k, n in enumerate(nodes):
        chans = sorted(
            (ch for ch in setup_true.responses if ch.node == n), key=lambda ch: ch.direction
        )
        C = np.array([ch.direction_gcs for ch in chans]).T
        origin = np.asarray(chans[0].position_m)
        for lab, xl in zip(jig.labels, jig.points_local_m, strict=True):
            digitize(f"jig{n}/{lab}", C @ xl + origin)
        o = check(c.post("/api/digitizer/orientations", json={"node": n}), f"orientation {n}")
        ori_err.append(_angle_deg(np.array(o["rotation"]), C))
        ori_unc.append(float(o["uncertainty_deg"]))
        say(
            f"[2/5] triax {n} oriented ({k + 1}/{len(nodes)}): error {ori_err[-1]:.3f} deg, "
            f"uncertainty {o['uncertainty_deg']:.3f} deg"
        )
    return ori_err, ori_unc


def _fit_lines_of_action(
    c: Any, setup_true: Any, digitize: Callable[[str, np.ndarray], None]
) -> list[float]:
    """Step 2b: digitize each impact point and three points along the hammer's line; return
    the angle (deg) between each fitted line of action and the true direction."""
    loa_err = []
    for e in setup_true.excitations:
        p_in, d = np.asarray(e.position_m), np.asarray(e.direction_gcs)
        digitize(f"in{e.node}", p_in)
        labels = []
        for j, s in enumerate((0.04, 0.08, 0.12)):
            digitize(f"loa{e.node}/{j}", p_in - s * d)
            labels.append(f"loa{e.node}/{j}")
        la = check(
            c.post(
                "/api/digitizer/lines-of-action",
                json={"node": e.node, "input_label": f"in{e.node}", "labels": labels},
            ),
            f"line of action {e.node}",
        )
        loa_err.append(float(np.degrees(np.arccos(np.clip(np.dot(la["direction"], d), -1, 1)))))
    return loa_err


def _setup_from_geometry(
    c: Any,
    setup_true: Any,
    nodes: list[int],
    args: argparse.Namespace,
    info: dict[str, Any],
    say: Callable[[str], None],
) -> int:
    """Step 3: the setup built by the service from the digitized geometry; return its id."""
    from dimacq.io.setup_file import dump_setup_dict

    geo = {
        "name": f"demo {args.scenario}",
        "reference_point_m": list(setup_true.reference_point_m),
        "triaxes": nodes,
        "inputs": [e.node for e in setup_true.excitations],
        "load_cells": [
            dump_setup_dict(setup_true)["load_cells"][i] for i in range(len(setup_true.load_cells))
        ],
    }
    setup_out = check(c.post("/api/setups/from-geometry", json=geo), "setup from geometry")
    sid: int = setup_out["id"]
    info["geometry_uncertainty"] = setup_out["setup"].get("geometry_uncertainty")
    say(
        f"[3/5] setup {sid}: {setup_out['n_responses']} responses, {setup_out['n_inputs']} inputs, "
        f"{setup_out['n_load_cells']} load cell(s)"
    )
    return sid


def _acquire_frfs(
    c: Any,
    built: Any,
    sid: int,
    args: argparse.Namespace,
    say: Callable[[str], None],
    info: dict[str, Any],
    backends: dict[str, str] | None,
    lag: HostLag | None,
    runs: list[dict[str, Any]] | None,
) -> int:
    """Step 4: acquire the impacts through the service (or, with ``--model-frfs``, import the
    model's FRFs); ``info["acquisition"]`` says which and through what. Returns the FRF set id."""
    if args.model_frfs:
        say(
            "[4/5] no acquisition (--model-frfs): importing the virtual lab's FRFs of the true "
            f"article (UFF, {100 * args.noise:.2g} % noise)"
        )
        frf_id = _import_model_frfs(c, built, sid, args)
        info["acquisition"] = (
            "not run (--model-frfs): FRFs of the virtual lab's forward model (true geometry) "
            f"with {100 * args.noise:g} % noise imported as UFF"
        )
        return frf_id
    frf_id = acquire(
        c,
        {"setup_id": sid, **acquisition_plan(args), "seed": built.seed},
        ACQUISITION,
        say,
        quiet=args.quiet,
        lag=lag,
        runs=runs,
    )
    b = backends or {}
    cell = {
        "daq-channels": "its bridges on inputs of the DAQ",
        "canopen-simulated": "load cell (CANopen)",
        "netft-can-simulated": "ATI Net F/T (CAN)",
        "netft-udp-simulated": "ATI Net F/T (RDT over UDP)",
        "cia404-simulated": "CiA 404 amplifier (CANopen)",
    }.get(b.get("loadcell", ""), "load cell (CAN)")
    daq = b.get("daq", "?")
    usb = "Measurement Computing USB-1808X units (USB)"
    dev = {"mcc-usb-simulated": usb, "mcc-usb": usb}.get(daq, "DAQ (USB)")
    info["acquisition"] = (
        f"impact test through the {_sim('daq', daq)}{dev} and {cell} "
        f"(daq = {daq!r}, loadcell = {b.get('loadcell', '?')!r})"
    )
    say(f"[4/5] acquired: {info['acquisition']}")
    return frf_id


def _solve_step(
    c: Any,
    frf_id: int,
    chain: dict[str, Any] | None,
    band: list[float],
    args: argparse.Namespace,
    say: Callable[[str], None],
) -> dict[str, Any]:
    """Step 5: solve the FRF set (with step 0's chain calibration when it gave one)."""
    body: dict[str, Any] = {"frf_id": frf_id}
    if chain is not None and "solution_id" in chain:
        body["chain_calibration_id"] = chain["solution_id"]
    if args.scenario_band:
        body["band_hz"] = band
    sol: dict[str, Any] = check(c.post("/api/solutions", json=body), "solve")
    lo, hi = sol["result"]["band_hz"]
    how = "the scenario's recommended band" if args.scenario_band else "chosen by the service"
    say(
        f"[5/5] solution {sol['id']} on FRF set {frf_id}, band {lo:g}-{hi:g} Hz ({how}), "
        f"verdict {sol['result'].get('verdict', '?')}"
    )
    return sol


def _photograph(
    c: Any, built: Any, args: argparse.Namespace, say: Callable[[str], None]
) -> dict[str, Any]:
    """Steps 1–2 with the simulated camera: the lab's standard tags plan on the true article,
    ``args.photos`` photos written as JPEG files, ``dimacq geometry from-photos`` on them, and
    the result sent to the service (``POST /api/digitizer/photo-geometry``)."""
    from dimacq.io.tags_file import dump_tags, load_tags
    from dimacq.services.geometry.photo_geometry import geometry_from_photos
    from dimacq.simulators.camera.render import photograph_article
    from dimacq.simulators.camera.scenario import tagged_scenario

    plan, world = tagged_scenario(built)
    with tempfile.TemporaryDirectory(prefix="dimacq-photos-") as tmp:
        folder = Path(tmp) / "photos"
        photograph_article(world, folder, args.photos, built.seed + 3000)
        dump_tags(plan, Path(tmp) / "tags.toml")
        say(f"[1/5] {args.photos} photos of {len(plan.bodies)} tagged bodies taken")
        res = geometry_from_photos(
            folder, load_tags(Path(tmp) / "tags.toml"), progress=lambda m: None
        )
        doc = res.to_json()
    check(
        c.post("/api/digitizer/photo-geometry", content=json.dumps(doc).encode()), "photo geometry"
    )
    ori_err, ori_unc, pos_err = [], [], []
    for o in res.orientations:
        r_true, p_true = world.truth[f"triax {o.node}"]
        ori_err.append(_angle_deg(np.array(o.rotation), r_true))
        ori_unc.append(o.uncertainty_deg)
        pos_err.append(float(np.linalg.norm(np.array(o.origin_m) - p_true)))
    loa_err = []
    for a in res.lines_of_action:
        d_true = -world.truth[f"input {a.node}"][0][:, 2]
        loa_err.append(float(np.degrees(np.arccos(np.clip(np.dot(a.direction, d_true), -1, 1)))))
    say(
        f"[2/5] photographed geometry: reprojection σ {res.bundle.sigma_px:.3f} px, triax position "
        f"RMS error {1e3 * np.sqrt(np.mean(np.square(pos_err))):.3f} mm, orientation RMS error "
        f"{np.sqrt(np.mean(np.square(ori_err))):.3f} deg; {len(res.issues)} photo issues"
    )
    for u in res.unfixed:
        say(f"      not fixed: {u}")
    return {
        "photos": len(res.photos),
        "used": len(res.used),
        "sigma_px": res.bundle.sigma_px,
        "verdict": res.verdict,
        "issues": [str(i) for i in res.issues],
        "triax_position_error_rms_mm": 1e3 * float(np.sqrt(np.mean(np.square(pos_err)))),
        "ori_err": ori_err,
        "ori_unc": ori_unc,
        "loa_err": loa_err,
    }


def _angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    from scipy.spatial.transform import Rotation

    return float(np.degrees(Rotation.from_matrix(a @ b.T).magnitude()))


def _import_model_frfs(c: Any, built: Any, sid: int, args: argparse.Namespace) -> int:
    from dimacq.io.uff import write_frf_uff

    frf = built.model_frf(noise=args.noise)
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "model.uff"
        write_frf_uff(path, frf)
        out = check(
            c.post(
                "/api/frfs/import",
                params={"setup_id": sid, "name": "virtual lab model FRFs"},
                content=path.read_bytes(),
            ),
            "FRF import",
        )
    return int(out["id"])


def _errors(est: dict[str, Any], truth: dict[str, Any]) -> dict[str, Any]:
    m_err = 100 * (est["mass_kg"] - truth["mass_kg"]) / truth["mass_kg"]
    cg_err_mm = 1e3 * np.linalg.norm(np.subtract(est["cg_m"], truth["cg_m"]))
    pm = np.asarray(est["principal_moments_kgm2"])
    pt = np.asarray(truth["principal_moments_kgm2"])
    return {
        "mass_pct": float(m_err),
        "cg_mm": float(cg_err_mm),
        "principal_moments_pct": (100 * (pm - pt) / pt).tolist(),
    }


def _print_result(p: dict[str, Any], say: Callable[[str], None]) -> None:
    t = p["truth"]
    e = p["demo"]["errors"]
    print(f"\nDIM result vs truth ({p['demo']['scenario']}), {p['elapsed_s']:.1f} s")
    print(f"{'':<22}{'estimate':>14}{'truth':>14}{'error':>12}")
    print(f"{'mass, kg':<22}{p['mass_kg']:>14.5f}{t['mass_kg']:>14.5f}{e['mass_pct']:>11.3f}%")
    for k, ax in enumerate("xyz"):
        d = 1e3 * (p["cg_m"][k] - t["cg_m"][k])
        print(f"{'CG ' + ax + ', m':<22}{p['cg_m'][k]:>14.5f}{t['cg_m'][k]:>14.5f}{d:>10.3f}mm")
    for k in range(3):
        pe, pt_ = p["principal_moments_kgm2"][k], t["principal_moments_kgm2"][k]
        print(
            f"{'I' + str(k + 1) + ' (principal), kg m2':<22}{pe:>14.6f}{pt_:>14.6f}{e['principal_moments_pct'][k]:>11.3f}%"
        )
    print(f"CG error {e['cg_mm']:.3f} mm; acquisition: {p['demo']['acquisition']}")
    b = p["demo"].get("backends")
    if b:
        print("backends: " + ", ".join(f"{k} = {v!r}" for k, v in b.items()))
    if p["demo"].get("time_lapse_summary"):
        print(f"time-lapse: {p['demo']['time_lapse_summary']}")
    lo, hi = p["band_hz"]
    reasons = "; ".join(
        str(r.get("message", r)) if isinstance(r, dict) else str(r)
        for r in p.get("verdict_reasons") or []
        if not (isinstance(r, dict) and r.get("severity") == "ok")
    )
    print(
        f"band {lo:g}-{hi:g} Hz; verdict {p.get('verdict', '?')}"
        + (f": {reasons}" if reasons else "")
    )
