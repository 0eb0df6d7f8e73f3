"""``dimacq acquire``: an impact test of a virtual-lab scenario through the simulated devices.

Usage::

    dimacq acquire SCENARIO --averages-per-input N --frf OUT.uff [--seed S] [--data-dir DIR]
                   [--json OUT] [--record-samples N] [--exp-tau S] [--noise-free] [--quiet]

(``--impacts-per-input`` is the same as ``--averages-per-input``, ``--data`` as ``--data-dir``.)

The virtual lab of SCENARIO (a file of ``config/scenarios/``) is read through the rig the
service and ``dimacq demo`` use (:func:`dimacq.services.rig.build_rig`, backends ``simulated``):
the simulated USB DAQ (pyusb backend) and one simulated CAN FD amplifier per load cell (python-can
``virtual``), cabled and calibrated as the scenario's rig file says (``config/rigs/<scenario>.toml``,
else ``config/rig.toml``: certificate sensitivities, load cell calibration files; the simulated
transducers differ from them within their tolerances). An impact session strikes every input N
accepted times (the rig file's ``[acquisition]`` gives the other settings), and
the FRFs (accelerances and the load cells' six loads, as the drivers' calibration matrices give
them) are written as one whole-test UFF file (the geometry the lab states: the scenario's
geometry errors applied, never the simulator's truth; + 58 records, binary) that
``dimacq solve OUT.uff`` reads. ``--data-dir DIR`` keeps the raw blocks in ``DIR/acquisition.h5`` and the FRFs with their
coherence (which UFF 58 cannot carry) in ``DIR/frf.npz``.
Progress goes to stderr (one updating line on a terminal, plain lines otherwise, with the time
remaining; ``--quiet``: none); a summary (with the FRFs' agreement with the true model) to stdout.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from dimacq.cli.progress import ProgressLine, add_quiet, plain
from dimacq.errors import DataError, SetupError
from dimacq.model.frf import Channel


def register(subparsers: Any) -> None:
    p = subparsers.add_parser(
        "acquire",
        help="impact test of a virtual-lab scenario through the simulated DAQ and load cells",
        description=plain(__doc__),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("scenario", metavar="SCENARIO", help="virtual-lab scenario name")
    p.add_argument(
        "--averages-per-input",
        "--impacts-per-input",
        dest="impacts_per_input",
        type=int,
        required=True,
        metavar="N",
        help="accepted averages per input (the API's averages_per_input)",
    )
    p.add_argument("--frf", type=Path, required=True, metavar="OUT.uff", help="FRF output (UFF)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument(
        "--data-dir",
        "--data",
        dest="data",
        type=Path,
        metavar="DIR",
        help="keep the raw data (HDF5) and the FRFs with their coherence in DIR",
    )
    p.add_argument("--json", type=Path, metavar="OUT", help="write the summary as JSON")
    p.add_argument("--record-samples", type=int, default=4096, help="samples per average")
    p.add_argument(
        "--exp-tau", type=float, default=None, metavar="S", help="exponential window time constant"
    )
    p.add_argument("--noise-free", action="store_true", help="no transducer noise")
    add_quiet(p)
    p.set_defaults(func=run)


def _scenario_band(name: str) -> tuple[float, float]:
    """The scenario's recommended band (config/scenarios), else the simulated DIM band."""
    from dimacq.cli.simulated_lab import DIM_BAND_HZ
    from dimacq.simulators.lab.scenarios import list_scenarios, load_scenario

    if name in list_scenarios():
        band = load_scenario(name).band
        return (float(band.lo_hz), float(band.hi_hz))
    return DIM_BAND_HZ


def run(args: argparse.Namespace) -> int:
    from dimacq.cli.simulated_lab import frf_agreement
    from dimacq.config import Settings, scenario_rig_file
    from dimacq.io.acquisition_hdf5 import AcquisitionWriter
    from dimacq.io.uff import check_uff_geometry, write_uff_test
    from dimacq.services.rig import build_rig, impact_settings, run_impact_test
    from dimacq.simulators.lab.scenarios import build_scenario

    if args.impacts_per_input < 1:
        raise SetupError(f"--averages-per-input {args.impacts_per_input}: give at least 1")
    if args.frf.suffix.lower() not in (".uff", ".unv"):
        raise SetupError(f"--frf {args.frf}: give a .uff (or .unv) file name")
    # The truth (``model``), to compare the FRFs with; the rig below builds its own world of the
    # same scenario and seed, and the drivers know only the rig file and its calibration files.
    # The setup the acquisition runs on and the file states is the lab's (the scenario's
    # geometry errors applied: digitized positions, jig orientations, lines of action), never
    # the simulator's true geometry (issue 22).
    built = build_scenario(args.scenario, args.seed)
    model = built.model
    setup = built.setup
    check_uff_geometry(setup)  # before striking: the FRF file must be able to hold the geometry
    n_in = len(setup.excitations)
    settings = Settings(
        daq="simulated",
        loadcell="simulated",
        scenario=args.scenario,
        rig_file=scenario_rig_file(args.scenario),
    )
    cfg: dict[str, Any] = {
        "seed": args.seed,
        "noise_scale": 0.0 if args.noise_free else 1.0,
        "averages_per_input": args.impacts_per_input,
        "record_samples": args.record_samples,
        "exponential_tau_s": args.exp_tau,
    }
    t0 = time.monotonic()
    total = n_in * args.impacts_per_input
    averages: list[tuple[int, bool, list[str]]] = []
    line = ProgressLine("acquire", quiet=args.quiet)

    def on_average(
        input_index: int, _number: int, accepted: bool, reasons: Any, _record: Any
    ) -> None:
        averages.append((input_index, accepted, list(reasons)))
        if not accepted:
            name = setup.excitations[input_index].name
            line.note(f"input {name} rejected: {'; '.join(reasons)}")

    def on_progress(fraction: float, message: str) -> None:
        line.update(fraction, f"[{round(fraction * total)}/{total}] {message}")

    data_path = args.data / "acquisition.h5" if args.data else None
    meta = {
        "source": "dimacq acquire (simulated USB DAQ + CAN load cells)",
        "scenario": args.scenario,
    }
    rig = build_rig(settings, setup, cfg)
    try:
        # min_averages as the service states it: the rig file's [acquisition], else the
        # min_averages setting (capped at --impacts-per-input by the session)
        cfg["min_averages"] = rig.defaults.get("min_averages", settings.min_averages)
        used = impact_settings(rig, cfg)
        if data_path is None:
            frf = run_impact_test(
                rig, setup, cfg, on_average=on_average, on_progress=on_progress, meta=meta
            )
        else:
            data_path.parent.mkdir(parents=True, exist_ok=True)
            sample_rate_hz = rig.daq.sample_rate_hz
            assert sample_rate_hz is not None  # configured by build_rig
            with AcquisitionWriter(
                data_path,
                sample_rate_hz=sample_rate_hz,
                daq_channels=rig.daq.channel_names,
                daq_units=rig.daq_units,
                n_loadcells=len(rig.loadcells),
            ) as writer:
                frf = run_impact_test(
                    rig,
                    setup,
                    cfg,
                    on_average=on_average,
                    on_progress=on_progress,
                    writer=writer,
                    meta=meta,
                )
    finally:
        rig.close()
        line.close()
    # Inputs with too few accepted averages have no FRF: the file holds the complete ones (what
    # was acquired is kept) and the command ends with the reason, not with a mismatch of inputs.
    accepted = [sum(ok for j, ok, _ in averages if j == i) for i in range(n_in)]
    have = set(frf.inputs)
    complete = [e for e in setup.excitations if Channel(e.node, e.direction) in have]
    incomplete = [e.name for e in setup.excitations if Channel(e.node, e.direction) not in have]
    if not complete:
        raise DataError(
            f"acquisition incomplete: no input has {min(used.min_averages, used.averages_per_input)}"
            f" accepted averages ({_rejections(setup, averages)}); nothing written to {args.frf}; "
            "find the fault and acquire again"
        )
    written = setup if not incomplete else setup.model_copy(update={"excitations": complete})
    args.frf.parent.mkdir(parents=True, exist_ok=True)
    write_uff_test(args.frf, written, frf, binary=True)
    if args.data:
        # UFF 58 holds no coherence: keep it (with the FRFs) next to the raw data.
        np.savez(
            args.data / "frf.npz",
            frequencies_hz=frf.frequencies_hz,
            H=frf.H,
            coherence=np.asarray(frf.coherence if frf.coherence is not None else []),
        )
    elapsed = time.monotonic() - t0
    rejected = [(j, reasons) for j, ok, reasons in averages if not ok]
    # one average per input has no coherence (NaN): compare every value then
    coherent = frf.coherence is not None and bool(np.isfinite(frf.coherence).any())
    agreement = frf_agreement(
        frf,
        model,
        exponential_tau_s=used.exponential_tau_s,
        band_hz=_scenario_band(args.scenario),
        coherence_threshold=0.99 if coherent else None,
        inputs=[j for j, e in enumerate(setup.excitations) if e in complete],
    )
    min_averages = min(used.min_averages, used.averages_per_input)
    summary: dict[str, Any] = {
        "scenario": args.scenario,
        "setup": setup.name,
        "seed": args.seed,
        "frf_file": str(args.frf),
        "raw_data": str(data_path) if data_path else None,
        "record_samples": args.record_samples,
        "exponential_tau_s": used.exponential_tau_s,
        "rig_file": str(settings.rig_path),
        "n_inputs": n_in,
        "n_responses": len(frf.outputs),
        "n_lines": frf.n_lines,
        "averages_accepted": accepted,
        "min_averages": min_averages,
        "incomplete_inputs": incomplete,
        "averages_rejected": [
            {"input": setup.excitations[j].name, "reasons": reasons} for j, reasons in rejected
        ],
        "frf_vs_model": agreement.to_json(),
        "elapsed_s": elapsed,
    }
    out = sys.stdout
    out.write(
        f"{setup.name}: {n_in} inputs × {args.impacts_per_input} averages, "
        f"{len(frf.outputs)} outputs ({len(setup.load_cells)} load cells), "
        f"{frf.n_lines} lines {frf.frequencies_hz[0]:g}–{frf.frequencies_hz[-1]:g} Hz\n"
    )
    out.write(f"rejected averages: {len(rejected)}\n")
    for j, reasons in rejected:
        out.write(f"  input {setup.excitations[j].name}: {'; '.join(reasons)}\n")
    if incomplete:
        out.write(
            f"incomplete inputs (fewer than {min_averages} accepted averages, no FRF): "
            f"{', '.join(incomplete)}\n"
        )
    where = (
        f"where coherence > {agreement.coherence_threshold}"
        if agreement.coherence_threshold is not None
        else "(one average: no coherence, every value)"
    )
    out.write(
        f"FRFs vs model {where}: "
        f"{100 * agreement.fraction_kept:.1f} % of values, median error "
        f"{100 * agreement.median_rel_error:.3f} %, 99th percentile "
        f"{100 * agreement.p99_rel_error:.2f} %, max {100 * agreement.max_rel_error:.2f} %\n"
    )
    out.write(f"wrote {args.frf} in {elapsed:.1f} s\n")
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(summary, indent=2) + "\n", encoding="utf-8")
    if incomplete:
        raise DataError(
            f"acquisition incomplete: {len(incomplete)} of {n_in} inputs have fewer than "
            f"{min_averages} accepted averages ({_rejections(setup, averages, incomplete)}); "
            f"{args.frf} holds the FRFs of the {len(complete)} complete inputs only"
        )
    return 0


def _rejections(
    setup: Any, averages: list[tuple[int, bool, list[str]]], names: list[str] | None = None
) -> str:
    """Per input named (all, or ``names``): accepted count and the rejection reasons seen."""
    parts = []
    for j, e in enumerate(setup.excitations):
        if names is not None and e.name not in names:
            continue
        ok = sum(a for i, a, _ in averages if i == j)
        why = sorted({r for i, a, rs in averages if i == j and not a for r in rs})
        parts.append(
            f"{e.name}: {ok} accepted" + (f", rejected for {'; '.join(why)}" if why else "")
        )
    return "; ".join(parts[:6]) + ("; …" if len(parts) > 6 else "")
