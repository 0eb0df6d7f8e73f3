"""``dimacq simulate``: a virtual-lab scenario's FRFs as one UFF file and its truth as JSON.

    dimacq simulate SCENARIO --frf OUT.uff --truth TRUTH.json [--time-domain] [--rigid-only]
                    [--excitation {impact,random,burst-random,swept-sine}] [--shakers N]
                    [--seed S] [--noise LEVEL] [--ascii]
    dimacq simulate --list [--nodes]
    dimacq simulate SCENARIO --nodes

SCENARIO is a name from ``config/scenarios/`` (``dimacq simulate --list`` lists every one) or
the path of a scenario file. ``--nodes`` prints the node numbers an acquisition and a setup use:
each response channel (node, UFF direction, position and measured direction in the GCS), each
input (node, where to strike and along which direction) and each load cell (node, position), as
the nominal setup states them. The UFF file holds the whole test as ``dimacq solve OUT.uff`` reads it (units,
node coordinate systems, nodes, 58 records, binary double precision unless ``--ascii``), with the
NOMINAL geometry (the scenario's geometry errors applied). TRUTH.json holds the true properties
with the keys of ``dimacq solve --json`` plus the scenario's recommended band and the response
nodes its recommended solution leaves out.

Model FRFs are exact unless ``--noise LEVEL`` adds complex Gaussian noise of LEVEL times each
FRF's RMS magnitude. With ``--time-domain`` the FRFs are estimated (H1, force and exponential
windows) from simulated impact records; ``--noise`` then scales the scenario's transducer noise
(default 1; 0 = noise-free time data). ``--rigid-only`` drops the elastic modes.

``--excitation random|burst-random|swept-sine`` (with ``--time-domain``) runs a shaker test
instead of the impact test (default ``impact``): ``--shakers N`` shakers (default: the scenario's
``[shaker]`` section, 2) drive N inputs at once with independent signals, the multiple-input H1
gives their FRF columns, and the shakers move on until every input has been driven; the
coherence written is the multiple coherence of each output.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from dimacq.cli.progress import plain
from dimacq.errors import SetupError


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser(
        "simulate",
        help="write a virtual-lab scenario's FRFs (UFF) and true properties (JSON)",
        description=plain(__doc__),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("scenario", nargs="?", metavar="SCENARIO", help="scenario name or file")
    p.add_argument("--list", action="store_true", help="list the bundled scenarios and exit")
    p.add_argument(
        "--nodes",
        action="store_true",
        help="print the scenario's response, input and load cell nodes (with --list: of every "
        "scenario) and exit",
    )
    p.add_argument("--frf", type=Path, metavar="OUT.uff", help="write the FRFs here (UFF)")
    p.add_argument("--truth", type=Path, metavar="TRUTH.json", help="write the true properties")
    p.add_argument(
        "--time-domain", action="store_true", help="estimate the FRFs from simulated impacts"
    )
    p.add_argument(
        "--excitation",
        choices=("impact", "random", "burst-random", "swept-sine"),
        default="impact",
        help="time domain: impact hammer (default) or shakers with this signal",
    )
    p.add_argument(
        "--shakers",
        type=int,
        metavar="N",
        help="shakers driving at once (default: the scenario's shaker.shakers)",
    )
    p.add_argument("--rigid-only", action="store_true", help="drop the elastic modes")
    p.add_argument("--seed", type=int, metavar="S", help="seed (default: the scenario's)")
    p.add_argument(
        "--noise",
        type=float,
        metavar="LEVEL",
        help="model FRFs: relative FRF noise (default 0); time domain: factor on the "
        "scenario's transducer noise (default 1)",
    )
    p.add_argument("--ascii", action="store_true", help="write ASCII 58 records, not binary")
    p.set_defaults(func=run)


def _list(nodes: bool = False) -> int:
    from dimacq.simulators.lab.scenarios import list_scenarios, load_scenario

    rows = []
    for name in list_scenarios():
        scn = load_scenario(name)
        rows.append((name, f"{scn.band.lo_hz:g}–{scn.band.hi_hz:g} Hz", scn.description))
    width = max((len(r[0]) for r in rows), default=8)
    print(f"{'scenario':<{width}}  {'band':<14}  description")
    for name, band, desc in rows:
        print(f"{name:<{width}}  {band:<14}  {desc}")
    if nodes:
        for name, _band, _desc in rows:
            print()
            _nodes(name, None)
    return 0


def _vec(v: object) -> str:
    return "(" + ", ".join(f"{float(x):+.4f}" for x in v) + ")"  # type: ignore[attr-defined]


def _axis_word(d: object) -> str:
    """``+X`` … ``−Z`` for a direction within 10° of a GCS axis, else ``oblique``."""
    v = [float(x) for x in d]  # type: ignore[attr-defined]
    k = max(range(3), key=lambda i: abs(v[i]))
    if abs(v[k]) < 0.985:
        return "oblique"
    return ("+" if v[k] > 0 else "−") + "XYZ"[k]


def _nodes(scenario: str, seed: int | None) -> int:
    """The scenario's nodes as its nominal setup states them (what the UFF file holds)."""
    from dimacq.model.channels import axis_name
    from dimacq.simulators.lab.scenarios import build_scenario

    setup = build_scenario(scenario, seed=seed).setup
    print(
        f"{scenario}: {len(setup.responses)} responses, {len(setup.excitations)} inputs, "
        f"{len(setup.load_cells)} load cell(s); positions in the GCS, m"
    )
    print("  responses: node  direction  position_m                    measures along (GCS)")
    for c in setup.responses:
        print(
            f"    {c.node:>6}  {c.direction:+d} ({axis_name(c.node, c.direction)})"
            f"  {_vec(c.position_m)}  {_vec(c.direction_gcs)}"
        )
    print("  inputs: node  position_m                    strike along (GCS)")
    for e in setup.excitations:
        print(
            f"    {e.node:>6}  {_vec(e.position_m)}  {_vec(e.direction_gcs)} "
            f"({_axis_word(e.direction_gcs)})"
        )
    if setup.load_cells:
        print("  load cells: node  position_m")
        for lc in setup.load_cells:
            print(f"    {lc.node:>6}  {_vec(lc.position_m)}")
    return 0


def run(args: argparse.Namespace) -> int:
    if args.list:
        return _list(args.nodes)
    if args.nodes:
        if not args.scenario:
            raise SetupError("--nodes: give a SCENARIO, or --list --nodes for every one")
        return _nodes(args.scenario, args.seed)
    if not args.scenario:
        raise SetupError("give a SCENARIO (dimacq simulate --list shows them)")
    if args.frf is None and args.truth is None:
        raise SetupError("nothing to write; give --frf OUT.uff and/or --truth TRUTH.json")
    from dimacq.io.uff import write_uff_test
    from dimacq.simulators.lab.scenarios import build_scenario

    t0 = time.perf_counter()
    built = build_scenario(args.scenario, seed=args.seed)
    if args.noise is not None and args.noise < 0:
        raise SetupError(f"--noise {args.noise}: give a level ≥ 0")
    summary = ""
    if not args.time_domain and (args.excitation != "impact" or args.shakers is not None):
        raise SetupError("--excitation and --shakers simulate time data; add --time-domain")
    if args.time_domain and args.excitation != "impact":
        from dimacq.simulators.lab.shaker import shaker_test

        srun = shaker_test(
            built,
            excitation=args.excitation,
            n_shakers=args.shakers,
            rigid_only=args.rigid_only,
            noise_scale=1.0 if args.noise is None else args.noise,
        )
        frf = srun.frf
        summary = (
            f"time domain: {args.excitation} excitation, {srun.n_shakers} shakers × "
            f"{len(srun.groups)} positions, {srun.averages} averages each, multiple-input H1 "
            f"(max cond G_ff {float(srun.input_condition.max()):.3g}), {srun.samples} samples at "
            f"{built.spec.acquisition.sample_rate_hz:g} S/s"
        )
    elif args.time_domain:
        if args.shakers is not None:
            raise SetupError("--shakers needs a shaker --excitation (random, burst-random, ...)")
        from dimacq.simulators.lab.impact import impact_test

        res = impact_test(
            built,
            rigid_only=args.rigid_only,
            noise_scale=1.0 if args.noise is None else args.noise,
        )
        frf = res.frf
        summary = (
            f"time domain: {res.n_strikes} strikes ({res.n_rejected} double hits rejected), "
            f"{res.samples} samples at {built.spec.acquisition.sample_rate_hz:g} S/s; "
            f"exponential window τ = {res.exponential_tau_s} s (FRFs → H(iω + 1/τ))"
        )
    else:
        frf = built.model_frf(rigid_only=args.rigid_only, noise=args.noise or 0.0)
        summary = "model FRFs" + (f", noise {args.noise:g}" if args.noise else ", exact")
    if args.frf is not None:
        write_uff_test(args.frf, built.setup, frf, binary=not args.ascii)
    if args.truth is not None:
        truth = built.truth_json()
        truth["rigid_only"] = bool(args.rigid_only)
        truth["time_domain"] = bool(args.time_domain)
        truth["excitation"] = args.excitation if args.time_domain else "model"
        args.truth.write_text(json.dumps(truth, indent=2) + "\n", encoding="utf-8")
    dt = time.perf_counter() - t0
    lo, hi = built.band_hz
    print(f"scenario {built.spec.name} (seed {built.seed}): {built.spec.description}")
    print(
        f"  {len(built.setup.responses)} responses, {len(built.setup.excitations)} inputs, "
        f"{len(built.setup.load_cells)} load cells; {frf.n_lines} lines "
        f"{frf.frequencies_hz[0]:g}–{frf.frequencies_hz[-1]:g} Hz; {summary}"
    )
    modes = [] if args.rigid_only else list(built.model.modes)
    if modes:
        print("  elastic modes: " + ", ".join(f"{m.name} {m.frequency_hz:g} Hz" for m in modes))
    exclude = built.spec.analysis.exclude_nodes
    print(
        f"  recommended band {lo:g}–{hi:g} Hz"
        + (f", leave out response nodes {', '.join(map(str, exclude))}" if exclude else "")
    )
    t = built.truth
    print(f"  truth: m = {t.mass_kg:.6g} kg, CG = ({', '.join(f'{x:.6g}' for x in t.cg_m)}) m")
    for what, path in (("FRFs", args.frf), ("truth", args.truth)):
        if path is not None:
            print(f"  {what} → {path}")
    print(f"  {dt:.2f} s")
    return 0
