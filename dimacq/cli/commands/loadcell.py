"""``dimacq loadcell``: 6-DOF load cell calibration.

Usage::

    dimacq loadcell calibrate --simulated [--method static|inertial] [--gauges strain-gauge|piezo]
                              [--plan standard|minimal] [--impacts-per-input N] [--seed S]
                              [--json OUT] [--matrix OUT.json] [--xml OUT.xml]

``--method static`` (dead weights, the default for the strain-gauge cell): the simulated cell on
the dead-weight bench behind the CAN amplifier simulator; the operator (virtual here) is prompted
for every load case of the plan (22 series — or 14 with ``--plan minimal`` — each 0, ½M, M, ½M,
0 with the cell turned six ways and the hanger at the arm's points), readings are averaged once
settled (creep detected), zero-corrected per series, and the 6×12 matrix is fitted with its
certificate: nonlinearity, hysteresis, crosstalk and uncertainty in % of the rated load per axis.

``--method inertial`` (method §8): the calibration mass hangs on its load cell, the hammer strikes
the support side of the cell at the 24 points, accelerometers and the 12 gauges come through the
simulated USB DAQ and CAN FD amplifier, and the 6×12 matrix is solved by rank-6 least squares.

Without ``--simulated`` the configured rig is calibrated for real (``--method static``): the
amplifier of the rig file's load cell (``--node``) on ``loadcell_interface``/``loadcell_channel``,
the plan, digitized hanger points and timing of the bench file (``--bench``, default
``loadcell_bench.toml`` beside the rig file); the operator is prompted on the terminal for every
load case (Enter when the load is in place). The result becomes the next version of the cell's
calibration file (``<stem>-vN.json`` and ``.xml`` kept, the rig file's file replaced: the
acquisition uses it from then on) and a database record; ``--download`` stores it in the
amplifier and reads it back (verify count).

Simulated, the circular check follows: the same mass on the same cell, struck on the mass,
acquired with the driver applying the new matrix, solved by DIM. JSON keys: ``method``,
``matrix_error_rel`` (relative Frobenius error against the simulated cell's true ``pinv(S)``),
``nonlinearity_pct_fs``, ``hysteresis_pct_fs``, ``uncertainty_pct_fs`` (six values each; the
inertial method gives no nonlinearity or hysteresis: null), ``circular_mass_error_pct``.
Exit status 1 when the certificate's verdict is ``fail``.
"""

from __future__ import annotations

import argparse
import json
import sys
from datetime import date
from pathlib import Path
from typing import Any

from dimacq.cli.progress import ProgressLine, add_quiet, plain
from dimacq.errors import SetupError


def register(subparsers: Any) -> None:
    p = subparsers.add_parser("loadcell", help="6-DOF load cell: bench calibration")
    sub = p.add_subparsers(dest="loadcell_command", metavar="ACTION")
    sub.required = True
    c = sub.add_parser(
        "calibrate",
        help="inertial calibration with the calibration mass (method §8)",
        description=plain(__doc__),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    c.add_argument(
        "--simulated",
        action="store_true",
        help="on the virtual bench (simulated DAQ and CAN amplifier)",
    )
    c.add_argument(
        "--method",
        choices=("static", "inertial"),
        default="inertial",
        help="static: dead weights (strain-gauge cells); inertial: the calibration mass",
    )
    c.add_argument(
        "--gauges",
        choices=("strain-gauge", "piezo"),
        default="strain-gauge",
        help="simulated cell: DC strain-gauge bridges (default) or AC-coupled piezo gauges",
    )
    c.add_argument(
        "--plan",
        choices=("standard", "minimal"),
        default="standard",
        help="dead-weight load plan: standard (22 series) or minimal (14)",
    )
    c.add_argument(
        "--averages-per-input",
        "--impacts-per-input",
        dest="impacts_per_input",
        type=int,
        default=5,
        metavar="N",
        help="inertial method: accepted averages per input (default 5)",
    )
    c.add_argument("--node", type=int, help="real rig: the load cell (node) of the rig file")
    c.add_argument("--bench", type=Path, metavar="FILE", help="real rig: the bench file")
    c.add_argument(
        "--download",
        action="store_true",
        help="real rig: store the new matrix in the amplifier and read it back",
    )
    c.add_argument("--seed", type=int, default=0)
    c.add_argument("--json", type=Path, metavar="OUT", help="write the figures as JSON")
    c.add_argument(
        "--matrix", type=Path, metavar="OUT.json", help="write the calibration file (JSON)"
    )
    c.add_argument(
        "--xml", type=Path, metavar="OUT.xml", help="write the calibration file (ATI-style XML)"
    )
    add_quiet(c)
    c.set_defaults(func=calibrate)


def calibrate(args: argparse.Namespace) -> int:
    if not args.simulated:
        return _calibrate_rig(args)
    if args.impacts_per_input < 1:
        raise SetupError(f"--impacts-per-input {args.impacts_per_input}: give at least 1")
    from dimacq.cli.simulated_lab import simulated_inertial_calibration
    from dimacq.services.acquisition import Progress

    line = ProgressLine("loadcell calibrate", quiet=args.quiet)

    def progress(stage: str, p: Progress) -> None:
        done, total = p.input_index * p.wanted + p.accepted, p.n_inputs * p.wanted
        line.update(done / max(total, 1), f"{stage}: [{done}/{total}] {p.message}")

    def static_progress(done: int, total: int, message: str) -> None:
        line.update(done / max(total, 1), f"dead weights: [{done}/{total}] {message}")

    run = simulated_inertial_calibration(
        seed=args.seed,
        averages_per_input=args.impacts_per_input,
        progress=progress,
        method=args.method,
        gauges=args.gauges,
        static_progress=static_progress,
        minimal_plan=args.plan == "minimal",
    )
    line.close()
    fit = run.fit
    out = sys.stdout
    if run.method == "static":
        cert = run.certificate
        out.write(
            f"load cell {run.node}: static calibration, {len(run.static_run.plan.cases)} load "
            f"cases ({fit.n_equations} hysteresis-free points fitted), gauges in {run.gauge_unit}\n"
        )
        out.write(f"  residual {fit.residual_rel:.3g}, condition σ1/σ6 {fit.condition:.3g}\n")
        out.write("  axis        Fx       Fy       Fz       Mx       My       Mz   (% of rated)\n")
        for label, v in (
            ("nonlinearity", cert.nonlinearity_pct_fs),
            ("hysteresis", cert.hysteresis_pct_fs),
            ("uncert. k=2", cert.uncertainty_pct_fs),
        ):
            out.write(f"  {label:<12}" + "".join(f"{x:9.4f}" for x in v) + "\n")
        out.write(f"  verdict {cert.verdict}" + "".join(f"; {r}" for r in cert.reasons) + "\n")
    else:
        out.write(
            f"load cell {run.node}: inertial calibration, {run.averages_per_input} averages × 24 "
            f"inputs, band {run.band_hz[0]:g}–{run.band_hz[1]:g} Hz ({fit.n_equations} equations)\n"
        )
        out.write(
            f"  residual {fit.residual_rel:.3g}, condition σ1/σ6 {fit.condition:.3g}, "
            f"noise separation σ7/σ6 {fit.noise_separation:.3g}\n"
        )
    out.write(f"  matrix error vs true pinv(S): {100 * run.matrix_error_rel:.4f} % (Frobenius)\n")
    e = run.circular_errors_pct
    out.write(
        f"circular check (DIM through the new matrix): mass {e['mass_pct']:+.4f} %, CG "
        f"{e['cg_error_mm']:.3f} mm, principal moments {e['I1_pct']:+.3f} / {e['I2_pct']:+.3f} / "
        f"{e['I3_pct']:+.3f} %\n"
    )
    payload = run.to_json()
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(payload, indent=2) + "\n", encoding="utf-8")
    if args.matrix or args.xml:
        _write_matrix(args.matrix, args.xml, run)
    return 1 if payload["verdict"] == "fail" else 0


def _write_matrix(path: Path | None, xml: Path | None, run: Any) -> None:
    from dimacq.io.loadcell_calibration import (
        LoadCellCalibration,
        write_calibration_json,
        write_calibration_xml,
    )

    fit = run.fit
    cal = LoadCellCalibration(
        serial_number=str(run.node),
        date=date.today().isoformat(),
        matrix=run.matrix,
        method=run.method,
        gauge_unit=run.gauge_unit,
        diagnostics={
            "residual_rel": fit.residual_rel,
            "condition": fit.condition,
            "noise_separation": fit.noise_separation,
            "matrix_error_rel_vs_simulated": run.matrix_error_rel,
        },
        notes=f"virtual bench (dimacq loadcell calibrate --simulated --method {run.method})",
    )
    for p, write in ((path, write_calibration_json), (xml, write_calibration_xml)):
        if p is not None:
            p.parent.mkdir(parents=True, exist_ok=True)
            write(cal, p)


def _calibrate_rig(args: argparse.Namespace) -> int:
    """The configured rig, for real: the operator answers on the terminal."""
    from dimacq.config import load_settings
    from dimacq.persistence import open_database
    from dimacq.pipeline.loadcell_calibration import LoadCase
    from dimacq.services.loadcell_calibration import calibrate_rig_cell, record_calibration

    if args.method != "static":
        raise SetupError(
            "--method inertial on the real rig is not in this build (it needs the calibration "
            "mass test through the DAQ); calibrate with --method static, or --simulated"
        )
    settings = load_settings()

    def operator(case: LoadCase, _sample: int) -> None:
        line.close()  # the prompt is always shown, --quiet or not
        sys.stderr.write(f"\n{case.prompt()}\n  press Enter when the load is in place: ")
        sys.stderr.flush()
        sys.stdin.readline()

    line = ProgressLine("loadcell calibrate", quiet=args.quiet)

    def progress(done: int, total: int, message: str) -> None:
        line.update(done / max(total, 1), f"[{done}/{total}] {message}")

    res = calibrate_rig_cell(
        settings,
        operator,
        node=args.node,
        bench_file=None if args.bench is None else str(args.bench),
        download=args.download,
        progress=progress,
    )
    db = open_database(settings.db_url)
    try:
        rec = record_calibration(db, res.installed_document())
    finally:
        db.close()
    payload = {**res.to_json(), "record_id": rec}
    cert = res.run.certificate
    out = sys.stdout
    out.write(
        f"load cell {res.node} (serial {res.serial_number}): static calibration version "
        f"{res.installed.version} in {res.installed.current_path} (record {rec})\n"
    )
    out.write("  axis        Fx       Fy       Fz       Mx       My       Mz   (% of rated)\n")
    for label, v in (
        ("nonlinearity", cert.nonlinearity_pct_fs),
        ("hysteresis", cert.hysteresis_pct_fs),
        ("uncert. k=2", cert.uncertainty_pct_fs),
    ):
        out.write(f"  {label:<12}" + "".join(f"{x:9.4f}" for x in v) + "\n")
    out.write(f"  verdict {cert.verdict}" + "".join(f"; {r}" for r in cert.reasons) + "\n")
    if res.download is not None:
        out.write(
            f"  downloaded to the amplifier: {res.download.verified}/{res.download.of} "
            "elements verified on read-back\n"
        )
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(payload, indent=2) + "\n", encoding="utf-8")
    return 0
