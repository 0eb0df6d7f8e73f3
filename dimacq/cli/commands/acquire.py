"""``dimacq acquire``: an impact test of a virtual-lab scenario through the simulated devices.

Usage::

    dimacq acquire SCENARIO --averages-per-input N --frf OUT.uff [--seed S] [--data-dir DIR]
                   [--resume] [--json OUT] [--record-samples N] [--exp-tau S] [--noise-free]
                   [--quiet]

(``--impacts-per-input`` is the same as ``--averages-per-input``, ``--data`` as ``--data-dir``.)

The test runs through the lab's acquisition service, the one the API drives
(:class:`dimacq.services.lab.acquisitions.AcquisitionService`: the plan of inputs, the impact
session per input, the averages, the FRF estimation, the recovery and resume), on the simulated
rig of SCENARIO (a file of ``config/scenarios/``; :func:`dimacq.services.acquisition.rig.build_rig`,
backends ``simulated``): the simulated USB DAQ (pyusb backend) and one simulated CAN FD amplifier
per load cell (python-can ``virtual``), cabled and calibrated as the scenario's rig file says
(``config/rigs/<scenario>.toml``, else ``config/rig.toml``: certificate sensitivities, load cell
calibration files; the simulated transducers differ from them within their tolerances). Every
input is struck until N averages are accepted (the rig file's ``[acquisition]`` gives the other
settings), and the FRFs (accelerances and the load cells' six loads, as the drivers' calibration
matrices give them) are written as one whole-test UFF file (the geometry the lab states: the
scenario's geometry errors applied, never the simulator's truth; + 58 records, binary) that
``dimacq solve OUT.uff`` reads.

``--data-dir DIR`` is the service's data folder: its database (``DIR/dimacq.sqlite``) and every
decided average as its own file (``DIR/arrays/acquisitions/NNNNNN/avg-NNNNN.h5``, stored before
the next strike), as ``dimacq serve`` keeps them; the raw blocks in ``DIR/acquisition.h5``, the
FRFs with their coherence (which UFF 58 cannot carry) in ``DIR/frf.npz`` and the settings asked
and applied in ``DIR/acquisition.json``. Without it the service works in a temporary folder,
removed at the end. ``--resume`` continues the last acquisition of ``DIR`` when it was
interrupted (killed, a crash, Ctrl-C) or ended short, through the service's resume: the accepted
averages kept there are used and only the missing ones are struck (a partly struck input gets
its missing averages), with the kept settings (seed, record length, window;
``--averages-per-input`` must be the same); the new raw blocks go to
``DIR/acquisition-resumed-K.h5``. Ctrl-C stops the acquisition as the API's stop does.
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
import os
import sys
import tempfile
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from dimacq.cli.progress import ProgressLine, add_quiet, plain
from dimacq.errors import DataError, SetupError
from dimacq.model.frf import Channel

if TYPE_CHECKING:
    from dimacq.model.frf import FrfData
    from dimacq.model.impact import ImpactSettings
    from dimacq.services.lab.acquisitions import AcquisitionInfo


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


@dataclass
class _Run:
    """What the acquisition service did for the command: the acquisition as stored, its FRFs,
    the settings applied, every average of this run (input, accepted, reasons; decision order),
    the accepted averages per setup input (with those a resumed run kept), and its wall and CPU
    seconds."""

    info: AcquisitionInfo
    frf: FrfData
    used: ImpactSettings
    averages: list[tuple[int, bool, list[str]]]
    accepted: list[int]
    wall_s: float
    cpu_s: float


def run(args: argparse.Namespace) -> int:
    from dimacq.backends.time_lapse import HostLag
    from dimacq.io.uff import check_uff_geometry
    from dimacq.simulators.lab.scenarios import build_scenario

    _check_arguments(args)
    # The truth (``model``), to compare the FRFs with; the rig the service builds makes its own
    # world of the same scenario and seed, and the drivers know only the rig file and its
    # calibration files. The setup the acquisition runs on and the file states is the lab's
    # (the scenario's geometry errors applied), never the simulator's true geometry.
    built = build_scenario(args.scenario, args.seed)
    model = built.model
    setup = built.setup
    check_uff_geometry(setup)  # before striking: the FRF file must be able to hold the geometry
    n_in = len(setup.excitations)
    lag = HostLag()
    t0 = time.monotonic()
    data_path = _raw_data_path(args)
    with _service_lab(args, data_path) as (lab, settings, lapse):
        done = _acquire(args, lab, setup, lag)
    complete, incomplete = _write_frf_files(args, setup, done)
    elapsed = time.monotonic() - t0
    agreement = _model_agreement(args.scenario, setup, done.frf, model, done.used, complete)
    used = done.used
    min_averages = min(used.min_averages, used.averages_per_input)
    time_lapse = {
        **lapse.to_json(),
        **lag.to_json(),
        "acquisition_wall_s": done.wall_s,
        "acquisition_cpu_s": done.cpu_s,
    }
    summary = _summary_json(args, setup, settings, done, agreement, incomplete, data_path, elapsed)
    summary["time_lapse"] = time_lapse
    _print_summary(args, setup, done, incomplete, min_averages, agreement)
    sys.stdout.write(
        f"time-lapse: {lapse.describe()}; {lag.describe_factors()}; {lag.describe()}; "
        f"acquisition {done.wall_s:.1f} s wall, "
        f"{done.cpu_s:.1f} s CPU (user + sys)\n"
    )
    sys.stdout.write(f"wrote {args.frf} in {elapsed:.1f} s\n")
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(summary, indent=2) + "\n", encoding="utf-8")
    if incomplete:
        raise DataError(
            f"acquisition incomplete: {len(incomplete)} of {n_in} inputs have fewer than "
            f"{min_averages} accepted averages ({_rejections(setup, done, incomplete)}); "
            f"{args.frf} holds the FRFs of the {len(complete)} complete inputs only"
        )
    return 0


def _check_arguments(args: argparse.Namespace) -> None:
    """Refuse an average count below 1, an FRF file that is not UFF, or ``--resume`` without
    ``--data``, before anything runs."""
    if args.impacts_per_input < 1:
        raise SetupError(f"--averages-per-input {args.impacts_per_input}: give at least 1")
    if args.frf.suffix.lower() not in (".uff", ".unv"):
        raise SetupError(f"--frf {args.frf}: give a .uff (or .unv) file name")
    if args.resume and args.data is None:
        raise SetupError("--resume: give --data DIR, the folder of the interrupted acquisition")


def _lab_settings(scenario: str, data_dir: Path) -> tuple[Any, Any]:
    """The settings of the service the command drives (data in ``data_dir``, its SQLite
    database there; the simulated rig of ``scenario``) and the DAQ time-lapse they run at.

    The time-lapse is the setting's ``daq_time_scale``, else what this host sustains now; the
    settings returned carry it, so the simulated DAQ runs at that factor.
    """
    from dimacq.backends.time_lapse import rig_time_lapse
    from dimacq.config import load_settings, scenario_rig_file

    settings = load_settings(
        data_dir=data_dir,
        database_url="",
        daq="simulated",
        loadcell="simulated",
        scenario=scenario,
        rig_file=scenario_rig_file(scenario),
    )
    lapse = rig_time_lapse(
        settings.simulation_imperfections,
        settings.rig_path,
        str(settings.loadcell),
        str(settings.daq),
    )
    imperfections = {**settings.simulation_imperfections, "daq_time_scale": lapse.scale}
    return settings.model_copy(update={"simulation_imperfections": imperfections}), lapse


def _impact_config(args: argparse.Namespace) -> dict[str, Any]:
    """The impact session's settings as the command line gives them (the API's names)."""
    return {
        "seed": args.seed,
        "noise_scale": 0.0 if args.noise_free else 1.0,
        "averages_per_input": args.impacts_per_input,
        "record_samples": args.record_samples,
        "exponential_tau_s": args.exp_tau,
    }


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


@contextmanager
def _service_lab(args: argparse.Namespace, raw: Path | None) -> Iterator[tuple[Any, Any, Any]]:
    """The lab service on ``--data DIR`` (a temporary folder without it), its settings and
    time-lapse; closed (and the temporary folder removed) on leaving.

    The acquisitions' rig is the simulated one of the settings (:func:`build_rig`; no device is
    opened before an acquisition asks for it); each acquisition keeps its raw blocks in ``raw``.
    """
    from dimacq.services.acquisition.rig import build_rig
    from dimacq.services.lab.lab import Lab

    tmp = None
    data_dir = args.data
    if data_dir is None:
        tmp = tempfile.TemporaryDirectory(prefix="dimacq-acquire-")
        data_dir = Path(tmp.name)
    mpl = os.environ.get("MPLCONFIGDIR")  # the lab points matplotlib into its data folder
    try:
        settings, lapse = _lab_settings(args.scenario, data_dir)
        lab = Lab(settings, open_devices=False, rig_factory=build_rig, raw_blocks=lambda _id: raw)
        try:
            yield lab, settings, lapse
        finally:
            lab.close()
    finally:
        if mpl is None:
            os.environ.pop("MPLCONFIGDIR", None)
        else:
            os.environ["MPLCONFIGDIR"] = mpl
        if tmp is not None:
            tmp.cleanup()


def _acquire(args: argparse.Namespace, lab: Any, setup: Any, lag: Any) -> _Run:
    """Start the acquisition (or, with ``--resume``, resume the folder's last one) through the
    lab's acquisition service, follow it to its end and read its FRFs.

    Raises
    ------
    DataError
        The acquisition failed (its averages are kept in the folder: ``--resume`` goes on).
    """
    from dimacq.model.impact import ImpactSettings

    total = len(setup.excitations) * args.impacts_per_input
    t_acq, cpu_acq = time.monotonic(), time.process_time()
    with lag.recording():
        info = _start_or_resume(args, lab, setup)
        if args.data is not None:
            _write_acquisition_json(args.data, args.scenario, info.config)
        snap = _follow(lab, info, setup, total, ProgressLine("acquire", quiet=args.quiet))
    wall_s, cpu_s = time.monotonic() - t_acq, time.process_time() - cpu_acq
    info = lab.acquisitions.get(info.id)
    if snap["state"] != "succeeded" or info.frf_id is None:
        kept = f"; its averages are kept in {args.data}: --resume goes on" if args.data else ""
        raise DataError(f"{snap.get('error') or info.message or snap['message']}{kept}")
    averages = [
        (a.input_index, a.accepted, a.reason.split("; ") if a.reason else []) for a in info.averages
    ]
    lag.observe_reasons(r for _j, ok, reasons in averages if not ok for r in reasons)
    lag.observe_reasons(r for st in info.input_states for r in st.get("lost_reasons", []))
    n_in = len(setup.excitations)
    per_input = info.accepted_per_input
    stored = lab.store.frf(info.frf_id)
    assert stored is not None
    return _Run(
        info=info,
        frf=stored[0],
        used=ImpactSettings.model_validate(info.config["applied"]),
        averages=averages,
        accepted=[per_input[j] if j < len(per_input) else 0 for j in range(n_in)],
        wall_s=wall_s,
        cpu_s=cpu_s,
    )


def _start_or_resume(args: argparse.Namespace, lab: Any, setup: Any) -> Any:
    """A new acquisition of ``setup`` in an empty folder, or the resumption of the folder's last
    acquisition (``--resume``: only the averages it is missing are struck); the acquisition.

    Raises
    ------
    SetupError
        A new acquisition in a folder that holds one; ``--resume`` on a folder without one, of
        another scenario or seed, another average count, or with nothing left to strike.
    """
    acquisitions = lab.acquisitions
    total = acquisitions.all(limit=0).total
    last = acquisitions.all(limit=1, offset=total - 1).items[0] if total else None
    if not args.resume:
        if last is not None:
            raise SetupError(
                f"--data {args.data} holds the averages of an acquisition; continue it with "
                "--resume, or give an empty folder"
            )
        setup_id = lab.store.save_setup(setup)
        return acquisitions.start({"setup_id": setup_id, **_impact_config(args)})
    if last is None:
        raise SetupError(
            f"--resume: {args.data} holds no acquisition; give the --data folder of an "
            "acquisition made with --data"
        )
    if lab.store.setup(last.setup_id) != setup:
        raise SetupError(
            f"--resume: {args.data} holds an acquisition of another setup than scenario "
            f"{args.scenario!r} with seed {args.seed}; give that acquisition's scenario and seed"
        )
    wanted = int(last.config.get("averages_per_input") or 0)
    if wanted != args.impacts_per_input:
        raise SetupError(
            f"--resume: --averages-per-input {args.impacts_per_input} differs from the "
            f"interrupted acquisition's {wanted}; give that"
        )
    if last.state == "succeeded":
        raise SetupError(
            f"--resume: every input in {args.data} has its {wanted} accepted averages; nothing "
            "to strike (run without --resume into a new folder)"
        )
    resumed = acquisitions.resume(last.id)
    assert resumed is not None
    return resumed


def _follow(lab: Any, info: Any, setup: Any, total: int, line: ProgressLine) -> dict[str, Any]:
    """Show the acquisition's progress (``[averages/total]`` and the session's message) and
    each rejected average until its job ends; its job's last state.

    Ctrl-C stops the acquisition as the API's stop does (the averages decided are kept) and
    is raised again once its job has ended.
    """
    from dimacq.services.lab.jobs import FINAL_STATES

    jobs, job_id = lab.jobs, info.job_id
    version, noted, message, fraction = -1, 0, "", 0.0
    try:
        while True:
            snap = jobs.wait_change(job_id, version, 1.0)
            assert snap is not None
            version = snap["version"]
            if snap["state"] == "running":
                message = snap["message"]
                fraction = float(snap["progress"])
                line.update(fraction, f"[{round(fraction * total)}/{total}] {message}")
            noted = _note_rejections(lab, info.id, setup, noted, line)
            if snap["state"] in FINAL_STATES:
                break
        if snap["state"] == "succeeded" and fraction < 1.0:
            line.update(1.0, f"[{total}/{total}] {message}")
    except KeyboardInterrupt:
        lab.acquisitions.stop(info.id)
        jobs.wait(job_id)
        raise
    finally:
        line.close()
    return dict(snap)


def _note_rejections(lab: Any, acq_id: int, setup: Any, noted: int, line: ProgressLine) -> int:
    """Note on the progress line every average rejected since the first ``noted`` averages;
    the number of averages seen now."""
    info = lab.acquisitions.get(acq_id)
    for a in info.averages[noted:]:
        if not a.accepted:
            line.note(f"input {setup.excitations[a.input_index].name} rejected: {a.reason}")
    return len(info.averages)


def _write_acquisition_json(data: Path, scenario: str, config: dict[str, Any]) -> None:
    """Keep the settings asked and applied in ``data/acquisition.json``."""
    data.mkdir(parents=True, exist_ok=True)
    asked = {k: v for k, v in config.items() if k != "applied"}
    (data / "acquisition.json").write_text(
        json.dumps(
            {"scenario": scenario, "config": asked, "applied": config.get("applied")}, indent=2
        )
        + "\n",
        encoding="utf-8",
    )


def _write_frf_files(
    args: argparse.Namespace, setup: Any, done: _Run
) -> tuple[list[Any], list[str]]:
    """Write the FRFs of the complete inputs; return those inputs and the incomplete names.

    Inputs with too few accepted averages have no FRF: the file holds the complete ones (what
    was acquired is kept) and the command ends with the reason, not with a mismatch of inputs.
    Under ``--data``, ``frf.npz`` keeps the FRFs with their coherence (UFF 58 holds none).
    """
    from dimacq.io.uff import write_uff_test

    frf, used = done.frf, done.used
    have = set(frf.inputs)
    complete = [e for e in setup.excitations if Channel(e.node, e.direction) in have]
    incomplete = [e.name for e in setup.excitations if Channel(e.node, e.direction) not in have]
    if not complete:
        raise DataError(
            f"acquisition incomplete: no input has {min(used.min_averages, used.averages_per_input)}"
            f" accepted averages ({_rejections(setup, done)}); nothing written to {args.frf}; "
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
    done: _Run,
    agreement: Any,
    incomplete: list[str],
    data_path: Path | None,
    elapsed: float,
) -> dict[str, Any]:
    """The ``--json`` summary without its ``time_lapse`` entry (which the caller appends last)."""
    n_in = len(setup.excitations)
    frf, used = done.frf, done.used
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
        "averages_accepted": done.accepted,
        "min_averages": min(used.min_averages, used.averages_per_input),
        "incomplete_inputs": incomplete,
        "averages_rejected": [
            {"input": setup.excitations[j].name, "reasons": reasons}
            for j, ok, reasons in done.averages
            if not ok
        ],
        "frf_vs_model": agreement.to_json(),
        "elapsed_s": elapsed,
    }


def _print_summary(
    args: argparse.Namespace,
    setup: Any,
    done: _Run,
    incomplete: list[str],
    min_averages: int,
    agreement: Any,
) -> None:
    """Write the test's shape, the rejections, the incomplete inputs and the model agreement."""
    out = sys.stdout
    n_in = len(setup.excitations)
    frf = done.frf
    rejected = [(j, reasons) for j, ok, reasons in done.averages if not ok]
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


def _rejections(setup: Any, done: _Run, names: list[str] | None = None) -> str:
    """Per input named (all, or ``names``): accepted count and the rejection reasons seen."""
    parts = []
    for j, e in enumerate(setup.excitations):
        if names is not None and e.name not in names:
            continue
        ok = done.accepted[j]
        why = sorted({r for i, a, rs in done.averages if i == j and not a for r in rs})
        parts.append(
            f"{e.name}: {ok} accepted" + (f", rejected for {'; '.join(why)}" if why else "")
        )
    return "; ".join(parts[:6]) + ("; …" if len(parts) > 6 else "")
