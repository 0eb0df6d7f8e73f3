"""``dimacq acquire``: an impact test of a virtual-lab scenario through the simulated devices.

Usage::

    dimacq acquire SCENARIO --averages-per-input N --frf OUT.uff [--seed S] [--data-dir DIR]
                   [--resume] [--json OUT] [--record-samples N] [--exp-tau S] [--noise-free]
                   [--quiet]

(``--impacts-per-input`` is the same as ``--averages-per-input``, ``--data`` as ``--data-dir``.)

The virtual lab of SCENARIO (a file of ``config/scenarios/``) is read through the rig the
service and ``dimacq demo`` use (:func:`dimacq.services.acquisition.rig.build_rig`, backends ``simulated``):
the simulated USB DAQ (pyusb backend) and one simulated CAN FD amplifier per load cell (python-can
``virtual``), cabled and calibrated as the scenario's rig file says (``config/rigs/<scenario>.toml``,
else ``config/rig.toml``: certificate sensitivities, load cell calibration files; the simulated
transducers differ from them within their tolerances). An impact session strikes every input N
accepted times (the rig file's ``[acquisition]`` gives the other settings), and
the FRFs (accelerances and the load cells' six loads, as the drivers' calibration matrices give
them) are written as one whole-test UFF file (the geometry the lab states: the scenario's
geometry errors applied, never the simulator's truth; + 58 records, binary) that
``dimacq solve OUT.uff`` reads. ``--data-dir DIR`` keeps the raw blocks in ``DIR/acquisition.h5`` and the FRFs with their
coherence (which UFF 58 cannot carry) in ``DIR/frf.npz``; and, as the service does, every
decided average as its own file (``DIR/averages/avg-NNNNN.h5``, written before the next strike)
with the settings in ``DIR/acquisition.json``. ``--resume`` continues an acquisition of ``DIR``
that was interrupted (killed, a crash, Ctrl-C): the accepted averages kept there are used and
only the missing ones are struck (a partly struck input gets its missing averages), with the
kept settings (seed, record length, window; ``--averages-per-input`` must be the same); the new
raw blocks go to ``DIR/acquisition-resumed-K.h5``.
The simulated DAQ runs at a time-lapse: simulation_imperfections.daq_time_scale
(DIMACQ_SIMULATION_IMPERFECTIONS='{"daq_time_scale": 10}') when given, else measured at start
(half of what this host sustains now, dimacq.backends.time_lapse); the summary says the factor
and whether the host kept up (no DAQ FIFO overflow, no load cell frames dropped).
Progress goes to stderr (one updating line on a terminal, plain lines otherwise, with the time
remaining; ``--quiet``: none); a summary (with the FRFs' agreement with the true model) to stdout.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Iterator
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
    p.add_argument(
        "--resume",
        action="store_true",
        help="continue the interrupted acquisition kept in --data DIR: strike only the missing "
        "averages",
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
    from dimacq.backends.time_lapse import HostLag
    from dimacq.io.uff import check_uff_geometry
    from dimacq.simulators.lab.scenarios import build_scenario

    _check_arguments(args)
    # The truth (``model``), to compare the FRFs with; the rig below builds its own world of the
    # same scenario and seed, and the drivers know only the rig file and its calibration files.
    # The setup the acquisition runs on and the file states is the lab's (the scenario's
    # geometry errors applied: digitized positions, jig orientations, lines of action), never
    # the simulator's true geometry.
    built = build_scenario(args.scenario, args.seed)
    model = built.model
    setup = built.setup
    check_uff_geometry(setup)  # before striking: the FRF file must be able to hold the geometry
    n_in = len(setup.excitations)
    settings, lapse = _lab_settings(args.scenario)
    lag = HostLag()
    cfg = _impact_config(args)
    store, kept, first_number = _average_store(args, cfg, n_in)
    t0 = time.monotonic()
    total = n_in * args.impacts_per_input
    averages: list[tuple[int, bool, list[str]]] = [
        (j, True, []) for j, recs in enumerate(kept or []) for _ in recs
    ]
    line = ProgressLine("acquire", quiet=args.quiet)
    fs_hz = [0.0]
    on_average = _average_recorder(averages, store, first_number, fs_hz, setup, line)

    def on_progress(fraction: float, message: str) -> None:
        line.update(fraction, f"[{round(fraction * total)}/{total}] {message}")

    data_path = _raw_data_path(args)
    frf, used, acq_wall_s, acq_cpu_s = _acquire(
        args, settings, setup, cfg, data_path, kept, lag, line, fs_hz, on_average, on_progress
    )
    complete, incomplete = _write_frf_files(args, setup, frf, averages, used)
    elapsed = time.monotonic() - t0
    rejected = [(j, reasons) for j, ok, reasons in averages if not ok]
    agreement = _model_agreement(args.scenario, setup, frf, model, used, complete)
    min_averages = min(used.min_averages, used.averages_per_input)
    time_lapse = {
        **lapse.to_json(),
        **lag.to_json(),
        "acquisition_wall_s": acq_wall_s,
        "acquisition_cpu_s": acq_cpu_s,
    }
    summary = _summary_json(
        args, setup, settings, frf, averages, used, agreement, incomplete, data_path, elapsed
    )
    summary["time_lapse"] = time_lapse
    _print_summary(args, setup, frf, rejected, incomplete, min_averages, agreement)
    sys.stdout.write(
        f"time-lapse: {lapse.describe()}; {lag.describe_factors()}; {lag.describe()}; "
        f"acquisition {acq_wall_s:.1f} s wall, "
        f"{acq_cpu_s:.1f} s CPU (user + sys)\n"
    )
    sys.stdout.write(f"wrote {args.frf} in {elapsed:.1f} s\n")
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


def _check_arguments(args: argparse.Namespace) -> None:
    """Refuse an average count below 1 or an FRF file that is not UFF, before anything runs."""
    if args.impacts_per_input < 1:
        raise SetupError(f"--averages-per-input {args.impacts_per_input}: give at least 1")
    if args.frf.suffix.lower() not in (".uff", ".unv"):
        raise SetupError(f"--frf {args.frf}: give a .uff (or .unv) file name")


def _lab_settings(scenario: str) -> tuple[Any, Any]:
    """The simulated rig's settings for ``scenario`` and the DAQ time-lapse they run at.

    The time-lapse is the setting's ``daq_time_scale``, else what this host sustains now; the
    settings returned carry it, so the simulated DAQ runs at that factor.
    """
    from dimacq.backends.time_lapse import rig_time_lapse
    from dimacq.config import Settings, scenario_rig_file

    settings = Settings(
        daq="simulated",
        loadcell="simulated",
        scenario=scenario,
        rig_file=scenario_rig_file(scenario),
    )
    lapse = rig_time_lapse(settings.simulation_imperfections, settings.rig_path)
    settings = settings.model_copy(
        update={
            "simulation_imperfections": {
                **settings.simulation_imperfections,
                "daq_time_scale": lapse.scale,
            }
        }
    )
    return settings, lapse


def _impact_config(args: argparse.Namespace) -> dict[str, Any]:
    """The impact session's settings as the command line gives them (the API's names)."""
    return {
        "seed": args.seed,
        "noise_scale": 0.0 if args.noise_free else 1.0,
        "averages_per_input": args.impacts_per_input,
        "record_samples": args.record_samples,
        "exponential_tau_s": args.exp_tau,
    }


def _average_store(
    args: argparse.Namespace, cfg: dict[str, Any], n_in: int
) -> tuple[Any, list[list[dict[str, Any]]] | None, int]:
    """Where each decided average is kept, the averages kept already, and the next number.

    Without ``--data`` nothing is kept; with it, a new acquisition refuses a folder that
    holds one (``--resume`` continues that), and ``--resume`` reads what the folder keeps.
    """
    if args.resume:
        if args.data is None:
            raise SetupError("--resume: give --data DIR, the folder of the interrupted acquisition")
        return _kept_averages(args, cfg, n_in)
    if args.data is None:
        return None, None, 1
    from dimacq.persistence import ArrayStore

    if (args.data / "averages").exists() and any((args.data / "averages").glob("*.h5")):
        raise SetupError(
            f"--data {args.data} holds the averages of an acquisition; continue it with "
            "--resume, or give an empty folder"
        )
    return ArrayStore(args.data), None, 1


def _average_recorder(
    averages: list[tuple[int, bool, list[str]]],
    store: Any,
    first_number: int,
    fs_hz: list[float],
    setup: Any,
    line: ProgressLine,
) -> Any:
    """The session's ``on_average``: note each decided average and keep it before the next strike.

    Each average goes to ``averages`` (input, accepted, reasons) and, with a store, to its own
    file ``averages/avg-NNNNN.h5`` numbered from ``first_number``; a rejection is noted on the
    progress line. ``fs_hz[0]`` is the sample rate, known once the rig is configured.
    """

    def on_average(
        input_index: int, number: int, accepted: bool, reasons: Any, record: Any
    ) -> None:
        averages.append((input_index, accepted, list(reasons)))
        if store is not None and record is not None:  # durable before the next strike
            n = first_number + number
            store.write(
                f"averages/avg-{n:05d}.h5",
                record,
                {
                    "input_index": input_index,
                    "number": n,
                    "accepted": accepted,
                    "reason": "; ".join(reasons),
                    "sample_rate_hz": fs_hz[0],
                },
            )
        if not accepted:
            name = setup.excitations[input_index].name
            line.note(f"input {name} rejected: {'; '.join(reasons)}")

    return on_average


def _raw_data_path(args: argparse.Namespace) -> Path | None:
    """The raw blocks' HDF5 file: ``acquisition.h5``, or the next ``acquisition-resumed-K.h5``."""
    if not args.data:
        return None
    if not args.resume:
        return args.data / "acquisition.h5"
    k = 1
    while (args.data / f"acquisition-resumed-{k}.h5").exists():
        k += 1
    return args.data / f"acquisition-resumed-{k}.h5"


def _write_acquisition_json(data: Path, scenario: str, cfg: dict[str, Any], used: Any) -> None:
    """Keep the settings asked and applied in ``data/acquisition.json`` (what ``--resume`` reads)."""
    data.mkdir(parents=True, exist_ok=True)
    (data / "acquisition.json").write_text(
        json.dumps(
            {"scenario": scenario, "config": cfg, "applied": used.model_dump()},
            indent=2,
        )
        + "\n",
        encoding="utf-8",
    )


def _strike(
    rig: Any, setup: Any, cfg: dict[str, Any], data_path: Path | None, **session: Any
) -> Any:
    """Run the impact test on ``rig``; with ``data_path``, the raw blocks are written there too."""
    from dimacq.io.acquisition_hdf5 import AcquisitionWriter
    from dimacq.services.acquisition.rig import run_impact_test

    if data_path is None:
        return run_impact_test(rig, setup, cfg, **session)
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
        return run_impact_test(rig, setup, cfg, writer=writer, **session)


def _acquire(
    args: argparse.Namespace,
    settings: Any,
    setup: Any,
    cfg: dict[str, Any],
    data_path: Path | None,
    kept: list[list[dict[str, Any]]] | None,
    lag: Any,
    line: ProgressLine,
    fs_hz: list[float],
    on_average: Any,
    on_progress: Any,
) -> tuple[Any, Any, float, float]:
    """Build the simulated rig and strike; return the FRFs, the settings applied, wall and CPU s.

    The rig, the host-lag recording and the progress line are closed whatever happens; a new
    acquisition under ``--data`` keeps its settings in ``acquisition.json`` before striking.
    """
    from dimacq.services.acquisition.rig import build_rig, impact_settings

    meta = {
        "source": "dimacq acquire (simulated USB DAQ + CAN load cells)",
        "scenario": args.scenario,
    }
    rig = build_rig(settings, setup, cfg)
    t_acq, cpu_acq = time.monotonic(), time.process_time()
    recording = lag.recording()
    recording.__enter__()
    try:
        # min_averages as the service states it: the rig file's [acquisition], else the
        # min_averages setting (capped at --impacts-per-input by the session)
        if cfg.get("min_averages") is None:
            cfg["min_averages"] = rig.defaults.get("min_averages", settings.min_averages)
        used = impact_settings(rig, cfg)
        fs_hz[0] = float(rig.daq.sample_rate_hz or 0.0)
        if args.data is not None and not args.resume:
            _write_acquisition_json(args.data, args.scenario, cfg, used)
        frf = _strike(
            rig,
            setup,
            cfg,
            data_path,
            on_average=on_average,
            on_progress=on_progress,
            meta=meta,
            prior=kept,
            on_event=lag.observe,
        )
    finally:
        rig.close()
        recording.__exit__(None, None, None)
        line.close()
    return frf, used, time.monotonic() - t_acq, time.process_time() - cpu_acq


def _write_frf_files(
    args: argparse.Namespace,
    setup: Any,
    frf: Any,
    averages: list[tuple[int, bool, list[str]]],
    used: Any,
) -> tuple[list[Any], list[str]]:
    """Write the FRFs of the complete inputs; return those inputs and the incomplete names.

    Inputs with too few accepted averages have no FRF: the file holds the complete ones (what
    was acquired is kept) and the command ends with the reason, not with a mismatch of inputs.
    Under ``--data``, ``frf.npz`` keeps the FRFs with their coherence (UFF 58 holds none).
    """
    from dimacq.io.uff import write_uff_test

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
        np.savez(
            args.data / "frf.npz",
            frequencies_hz=frf.frequencies_hz,
            H=frf.H,
            coherence=np.asarray(frf.coherence if frf.coherence is not None else []),
        )
    return complete, incomplete


def _model_agreement(
    scenario: str, setup: Any, frf: Any, model: Any, used: Any, complete: list[Any]
) -> Any:
    """The measured FRFs of the complete inputs against the true model, in the scenario's band.

    Where coherence is known, only values above 0.99 are compared; one average per input has
    no coherence (NaN), and every value is compared then.
    """
    from dimacq.cli.simulated_lab import frf_agreement

    coherent = frf.coherence is not None and bool(np.isfinite(frf.coherence).any())
    return frf_agreement(
        frf,
        model,
        exponential_tau_s=used.exponential_tau_s,
        band_hz=_scenario_band(scenario),
        coherence_threshold=0.99 if coherent else None,
        inputs=[j for j, e in enumerate(setup.excitations) if e in complete],
    )


def _summary_json(
    args: argparse.Namespace,
    setup: Any,
    settings: Any,
    frf: Any,
    averages: list[tuple[int, bool, list[str]]],
    used: Any,
    agreement: Any,
    incomplete: list[str],
    data_path: Path | None,
    elapsed: float,
) -> dict[str, Any]:
    """The ``--json`` summary without its ``time_lapse`` entry (which the caller appends last)."""
    n_in = len(setup.excitations)
    return {
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
        "averages_accepted": [sum(ok for j, ok, _ in averages if j == i) for i in range(n_in)],
        "min_averages": min(used.min_averages, used.averages_per_input),
        "incomplete_inputs": incomplete,
        "averages_rejected": [
            {"input": setup.excitations[j].name, "reasons": reasons}
            for j, ok, reasons in averages
            if not ok
        ],
        "frf_vs_model": agreement.to_json(),
        "elapsed_s": elapsed,
    }


def _print_summary(
    args: argparse.Namespace,
    setup: Any,
    frf: Any,
    rejected: list[tuple[int, list[str]]],
    incomplete: list[str],
    min_averages: int,
    agreement: Any,
) -> None:
    """Write the test's shape, the rejections, the incomplete inputs and the model agreement."""
    out = sys.stdout
    n_in = len(setup.excitations)
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


#: The settings a resumed acquisition takes from the interrupted one (records and FRFs alike).
_KEPT_SETTINGS = (
    "seed",
    "noise_scale",
    "record_samples",
    "pretrigger_samples",
    "trigger_level_n",
    "min_averages",
    "force_window_samples",
    "exponential_tau_s",
    "estimator",
)


def _kept_averages(
    args: argparse.Namespace, cfg: dict[str, Any], n_in: int
) -> tuple[Any, list[list[dict[str, Any]]], int]:
    """For ``--resume``: the folder's array store, its accepted averages per input (oldest
    first) and the number of the next average; ``cfg`` takes the interrupted run's settings."""
    from dimacq.persistence import ArrayStore
    from dimacq.services.acquisition.resume import kept_averages

    info_path = args.data / "acquisition.json"
    try:
        info = json.loads(info_path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as err:
        raise SetupError(
            f"--resume: {info_path} is missing or unreadable ({err}); give the --data folder "
            "of an acquisition made with --data"
        ) from err
    if info.get("scenario") != args.scenario:
        raise SetupError(
            f"--resume: {args.data} holds an acquisition of scenario {info.get('scenario')!r}; "
            f"give that scenario, not {args.scenario!r}"
        )
    old = info.get("config", {})
    if int(old.get("averages_per_input", 0)) != args.impacts_per_input:
        raise SetupError(
            f"--resume: --averages-per-input {args.impacts_per_input} differs from the "
            f"interrupted acquisition's {old.get('averages_per_input')}; give that"
        )
    applied = info.get("applied", {})
    cfg.update({k: old.get(k, applied.get(k)) for k in _KEPT_SETTINGS if k in old or k in applied})
    store = ArrayStore(args.data)
    numbers: list[int] = []

    def averages() -> Iterator[tuple[int, bool, dict[str, Any]]]:
        for path in sorted((args.data / "averages").glob("avg-*.h5")):
            arrays, attrs = store.read(path.relative_to(args.data).as_posix())
            numbers.append(int(attrs["number"]))
            yield int(attrs["input_index"]), bool(attrs["accepted"]), arrays

    kept = kept_averages(averages(), range(n_in), lambda arrays: arrays)
    if kept.nothing_to_strike(args.impacts_per_input):
        raise SetupError(
            f"--resume: every input in {args.data} has its {args.impacts_per_input} accepted "
            "averages; nothing to strike (run without --resume into a new folder)"
        )
    return store, kept.per_input, max([0, *numbers]) + 1


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
