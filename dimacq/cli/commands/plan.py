"""``dimacq plan``: pre-test planning — which triaxes and inputs to use, and what they will give.

    dimacq plan SETUP --properties PROPS.json --triaxes K --inputs M [--trials N] [--seed S]
                [--scheduler local|none|tcp://HOST:PORT] [--workers W] [--noise L] [--lines N]
                [--noise-model channel|relative] [--json OUT] [--quiet]

SETUP lists the candidate responses (each response node is a candidate triax) and inputs, in the
setup-file format (``dimacq/io/setup_file.py``); its ``[geometry_uncertainty]`` and
``[transducer_uncertainty]`` are the error model (defaults when absent). PROPS.json holds the
expected properties (the keys of a truth file: ``mass_kg``, ``cg_m``, ``inertia_cg_kgm2`` or
``inertia_p_kgm2``). The plan chooses K triaxes and M inputs by greedy selection and exchange on the
Fisher information of the ten inertia parameters (nuisances marginalised,
``dimacq/pipeline/planning.py``) and prints the predicted 95 % bounds (mass %, largest CG component
mm, largest principal moment %) against the median of random layouts of the same size, the
observability, the error budget per source and what one more triax or input buys.

FRF noise (``--noise L``, default 0.01, on each of ``--lines N`` lines, default 41): with
``--noise-model channel`` (default) L times the RMS of a strike's FRFs over every candidate
channel, the same on every channel (an accelerometer's noise floor); with ``relative`` L times
each FRF's own magnitude (``dimacq simulate --noise``), which rates a triax near the CG as high
as a far one.

``--trials N`` (default 0) checks the prediction with N simulated tests of the chosen layout, each
solved by the default ``dimacq solve``: trials run on a Dask LocalCluster of ``--workers W``
(default 2) processes (``--scheduler local``, the default), on a running scheduler
(``--scheduler tcp://host:8786``), or in this process (``--scheduler none`` or ``--workers 0``).
Trial i draws from ``SeedSequence(S).spawn(N)[i]``: the same seed gives the same JSON wherever
the trials run. Progress (solves done, time left) goes to stderr.

The JSON (``--json OUT``) has ``layout`` (``responses``: triax nodes, ``inputs``: input nodes),
``predicted`` and ``random_median`` (``mass_pct``, ``cg_mm``, ``principal_pct``),
``factor_over_random``, ``observability``, ``error_budget``, ``one_more``, ``error_model`` and,
with trials, ``monte_carlo`` (``bounds``, ``coverage`` of the solves' 95 % intervals, verdicts).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from dimacq.cli.progress import ProgressLine, add_quiet, plain
from dimacq.errors import SetupError


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser(
        "plan",
        help="choose the triaxes and inputs of a test and predict its 95 %% bounds",
        description=plain(__doc__),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("setup", type=Path, metavar="SETUP", help="candidate setup (.toml/.json)")
    p.add_argument(
        "--properties",
        type=Path,
        required=True,
        metavar="PROPS.json",
        help="expected properties (mass_kg, cg_m, inertia_cg_kgm2)",
    )
    p.add_argument("--triaxes", type=int, required=True, metavar="K", help="triaxes to use")
    p.add_argument("--inputs", type=int, required=True, metavar="M", help="inputs to strike")
    p.add_argument(
        "--trials", type=int, default=0, metavar="N", help="Monte Carlo solves (default 0)"
    )
    p.add_argument("--seed", type=int, default=0, metavar="S", help="seed (default 0)")
    p.add_argument(
        "--scheduler",
        default="local",
        metavar="local|none|tcp://HOST:PORT",
        help="where the trials run (default local: a LocalCluster of --workers processes)",
    )
    p.add_argument(
        "--workers", type=int, default=2, metavar="W", help="local workers (0: in-process)"
    )
    p.add_argument(
        "--noise",
        type=float,
        default=None,
        metavar="L",
        help="FRF noise relative to each FRF's RMS (default 0.01)",
    )
    p.add_argument(
        "--lines", type=int, default=None, metavar="N", help="frequency lines (default 41)"
    )
    p.add_argument(
        "--noise-model",
        choices=("channel", "relative"),
        default="channel",
        help="noise scale: per strike over the channels (default) or per FRF",
    )
    p.add_argument("--json", type=Path, metavar="OUT", help="write the plan as JSON")
    add_quiet(p)
    p.set_defaults(func=run)


def read_properties(path: Path) -> Any:
    """The expected properties of ``--properties PATH`` (a JSON object with ``mass_kg``,
    ``cg_m`` and the inertia), as :class:`RigidBodyProperties`; a :class:`SetupError` naming the
    file otherwise."""
    from dimacq.model.properties import RigidBodyProperties

    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError as err:
        raise SetupError(f"--properties {path} does not exist") from err
    except (OSError, ValueError) as err:
        raise SetupError(f"--properties {path}: not readable JSON ({err})") from err
    if not isinstance(data, dict):
        raise SetupError(f"--properties {path}: give a JSON object with mass_kg, cg_m, inertia")
    return RigidBodyProperties.from_json(data)


def _fmt(b: dict[str, Any]) -> str:
    return (
        f"mass {b['mass_pct']:.3g} %, CG {b['cg_mm']:.3g} mm, "
        f"principal moments {b['principal_pct']:.3g} %"
    )


def run(args: argparse.Namespace) -> int:
    from dimacq.io.setup_file import load_setup
    from dimacq.services.solve.planning import DEFAULT_LINES, DEFAULT_NOISE, make_plan

    if args.trials < 0:
        raise SetupError(f"--trials {args.trials}: give 0 or more")
    if args.workers < 0:
        raise SetupError(f"--workers {args.workers}: give 0 (in-process) or more")
    setup = load_setup(args.setup)
    props = read_properties(args.properties)
    bar = ProgressLine("plan", quiet=args.quiet)

    def progress(done: int, total: int, left: float) -> None:
        bar.update(done / total, f"{done}/{total} solves")

    try:
        plan = make_plan(
            setup,
            props,
            args.triaxes,
            args.inputs,
            noise=DEFAULT_NOISE if args.noise is None else args.noise,
            n_lines=DEFAULT_LINES if args.lines is None else args.lines,
            noise_model=args.noise_model,
            trials=args.trials,
            seed=args.seed,
            scheduler=args.scheduler,
            workers=args.workers,
            progress=progress,
        )
    finally:
        bar.close()
    lay = plan["layout"]
    out = sys.stdout
    out.write(
        f"plan: {len(lay['responses'])} of {plan['candidates']['triaxes']} triaxes, "
        f"{len(lay['inputs'])} of {plan['candidates']['inputs']} inputs\n"
    )
    out.write(f"  triax nodes: {', '.join(map(str, lay['responses']))}\n")
    out.write(
        "  inputs: "
        + ", ".join(f"{c['node']}{c['direction']:+d}" for c in lay["input_channels"])
        + "\n"
    )
    out.write(f"  predicted 95 % bounds: {_fmt(plan['predicted'])}\n")
    out.write(f"  random layouts (median): {_fmt(plan['random_median'])}\n")
    lp = plan["layout_controlled"]
    out.write(
        f"  without the hammer's common scale: {_fmt(lp['predicted'])} (random median "
        f"{_fmt(lp['random_median'])})\n"
    )
    obs = plan["observability"]
    out.write(
        f"  observability: condition number {obs['condition_number']:.3g}, weakest "
        f"{', '.join(obs['weak_parameters']) or '-'}\n"
    )
    top = sorted(
        plan["error_budget"].items(),
        key=lambda kv: -max(v or 0 for v in kv[1]["share_pct"].values()),
    )
    out.write(
        "  error budget (share of the variance, mass / CG / principal): "
        + "; ".join(
            f"{k} {v['share_pct']['mass_pct']:.0f}/{v['share_pct']['cg_mm']:.0f}/"
            f"{v['share_pct']['principal_pct']:.0f} %"
            for k, v in top
        )
        + "\n"
    )
    for kind, v in plan["one_more"].items():
        if v:
            out.write(f"  one more {kind} (node {v['node']}): {_fmt(v['predicted'])}\n")
    mc = plan.get("monte_carlo")
    if mc:
        out.write(
            f"  Monte Carlo, {mc['n_solved']}/{mc['n_trials']} solves: 95 % bounds "
            f"{_fmt(mc['bounds'])}; coverage of the solves' intervals mass "
            f"{mc['coverage']['mass']}, CG {mc['coverage']['cg']}, principal "
            f"{mc['coverage']['principal']}; share within the predicted bounds "
            f"{mc['within_predicted']['mass_pct']} / {mc['within_predicted']['cg_mm']} / "
            f"{mc['within_predicted']['principal_pct']}\n"
        )
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(plan, indent=2) + "\n", encoding="utf-8")
        out.write(f"  plan → {args.json}\n")
    return 0
