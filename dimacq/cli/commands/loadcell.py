"""``dimacq loadcell``: 6-DOF load cell calibration.

Usage::

    dimacq loadcell calibrate [--simulated] [--method static|inertial] [--node N] [--bench FILE]
                              [--download] [--circular-check] [--plan standard|minimal]
                              [--impacts-per-input N] [--seed S]
                              [--json OUT] [--matrix OUT.json] [--xml OUT.xml]

``--method static`` (dead weights, the default for the strain-gauge cell): the simulated cell on
the dead-weight bench behind the CAN amplifier simulator; the operator (virtual here) is prompted
for every load case of the plan (22 series — or 14 with ``--plan minimal`` — each 0, ½M, M, ½M,
0 with the cell turned six ways and the hanger at the arm's points), readings are averaged once
settled (creep detected), zero-corrected per series, and the 6×12 matrix is fitted with its
certificate: nonlinearity, hysteresis, crosstalk and uncertainty in % of the rated load per axis.

``--method inertial`` (method §8): the calibration mass hangs on its load cell, the hammer strikes
a fixture on the support side of the cell at the impact points of the calibration mass's setup
(the bench file's ``[inertial] setup_file``, with the mass's certified properties), the
accelerometers and the 12 gauges come through the rig's DAQ and amplifier, and the 6×12 matrix is
solved by rank-6 least squares.

Both methods run on the configured rig (``dimacq.toml``: the ``daq``/``loadcell`` backends and
``rig_file``; the bench file ``--bench``, default ``loadcell_bench.toml`` beside the rig file).
Without ``--simulated`` a person is prompted on the terminal: for every load case (Enter when the
load is in place) or every strike. The result becomes the next version of the cell's calibration
file (``<stem>-vN.json`` and ``.xml`` kept, the rig file's file replaced: the acquisition uses it
from then on) and a database record; ``--download`` stores it in the amplifier and reads it back
(verify count); ``--circular-check`` follows with the circular check. ``--simulated`` runs the same
code on the simulated lab (backends ``simulated``, scenario calibration-mass-bungee, the
``config/rig.toml`` folder copied to a scratch folder, so the configured calibration files stay
as they are; the dead weights on the simulated bench behind the CAN amplifier simulator).

The circular check (always when simulated): the same mass on the same cell, mounted as the
bench file's ``check_setup_file`` says (shipped: standing on the cell; simulated: scenario
calibration-mass-ground), struck on the mass, acquired with the amplifier applying the newly
installed matrix, solved by DIM, compared with the certificate (verdict ok within the bench
file's ``check_tolerance_pct``; inconclusive when the cell carries too little of the force in
the band for its matrix to matter: hung on bungees, a 1 % error of the cell moves DIM's mass by
about 0.001 %, ``circular_cell_sensitivity``; standing on it about 2.5 %). JSON keys:
``method``, ``matrix_error_rel`` (simulated runs: relative Frobenius error against the simulated
cell's true ``pinv(S)``), ``nonlinearity_pct_fs``, ``hysteresis_pct_fs``, ``uncertainty_pct_fs``
(six values each; the inertial method gives no nonlinearity or hysteresis: null),
``circular_mass_error_pct`` (null without the check); beside them ``matrix_uncertainty_rel``
(inertial: k = 2, relative Frobenius) and the check's ``circular_chain_uncertainty_pct``. Exit
status 1 when the certificate's verdict is ``fail``.
"""

from __future__ import annotations

import argparse
import json
import sys
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
        help="bench calibration: dead weights (static) or the calibration mass (inertial)",
        description=plain(__doc__),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    c.add_argument(
        "--simulated",
        action="store_true",
        help="on the simulated lab (backends simulated, a scratch copy of config/rig.toml's folder)",
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
        help="the cell's gauges: DC strain-gauge bridges; piezo is refused (the AC-coupled cell "
        "is a scenario option, [loadcell] kind, and has no static calibration)",
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
        default=None,
        metavar="N",
        help="inertial bench and circular check: averages per input (default: the bench file's)",
    )
    c.add_argument(
        "--circular-check",
        action="store_true",
        help="real rig: after the calibration, the circular check (DIM on the calibration mass "
        "through the new matrix; simulated runs always do it)",
    )
    c.add_argument("--node", type=int, help="real rig: the load cell (node) of the rig file")
    c.add_argument("--bench", type=Path, metavar="FILE", help="real rig: the bench file")
    c.add_argument(
        "--download",
        action="store_true",
        help="store the new matrix in the amplifier and read it back (real rig; simulated: the "
        "inertial bench's amplifier)",
    )
    c.add_argument(
        "--seed",
        type=int,
        default=0,
        help="simulated dead-weight bench: its seed (the simulated lab of the inertial bench and "
        "the circular check is the scenario's own: its seed also places the sensors)",
    )
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
    """Both methods, simulated or real, through the configured rig (the simulated one is the
    virtual lab behind the same backends, on a scratch copy of the rig folder)."""
    import tempfile

    if args.impacts_per_input is not None and args.impacts_per_input < 1:
        raise SetupError(f"--impacts-per-input {args.impacts_per_input}: give at least 1")
    if args.gauges != "strain-gauge":
        raise SetupError(
            "--gauges piezo: the piezo cell is AC-coupled (no static calibration) and is a "
            "scenario option ([loadcell] kind = 'piezo'); calibrate the strain-gauge cell"
        )
    if not args.simulated:
        from dimacq.backends import is_simulated
        from dimacq.config import load_settings

        settings = load_settings()
        if is_simulated("daq", settings.daq) or is_simulated("loadcell", settings.loadcell):
            raise SetupError(
                f"daq = {settings.daq!r}, loadcell = {settings.loadcell!r}: the configured rig "
                "is the simulated lab, whose calibration files are the shipped ones; use "
                "--simulated (a scratch copy), or configure the real devices (dimacq.toml)"
            )
        return _calibrate(args, settings, simulated=False)
    from dimacq.config import Settings
    from dimacq.services.calibration.inertial_calibration import scratch_rig

    with tempfile.TemporaryDirectory(prefix="dimacq-bench-") as tmp:
        base = Settings(
            daq="simulated",
            loadcell="simulated",
            scenario=SIMULATED_SCENARIO,
            rig_file="",
            data_dir=Path(tmp) / "data",
        )
        return _calibrate(args, scratch_rig(base, Path(tmp) / "rig"), simulated=True)


#: The simulated bench: the calibration mass on strain-gauge cell 501 (``config/rig.toml``).
SIMULATED_SCENARIO = "calibration-mass-bungee"


def _progress(stage: str, quiet: bool) -> ProgressLine:
    """The simulated lab strikes by itself: one progress line (``--quiet``: none)."""
    return ProgressLine(stage, quiet=quiet)


class _Person(ProgressLine):
    """A person strikes: every request is printed on its own line, ``--quiet`` or not."""

    def update(self, fraction: float, message: str = "") -> None:
        self.stream.write(f"{self.label} [{100 * fraction:5.1f} %] {message}\n")
        self.stream.flush()


def _shown(stage: str, simulated: bool, quiet: bool) -> ProgressLine:
    return _progress(stage, quiet) if simulated else _Person(stage)


def _calibrate(args: argparse.Namespace, settings: Any, *, simulated: bool) -> int:
    from dimacq.io.rig_file import load_rig_file
    from dimacq.services.calibration.circular_check import circular_check
    from dimacq.services.calibration.inertial_calibration import select_cell

    rig = load_rig_file(settings.rig_path)
    entry = select_cell(rig, args.node)
    bench = None if args.bench is None else str(args.bench)
    cfg: dict[str, Any] = {}
    if args.impacts_per_input is not None:
        cfg["averages_per_input"] = args.impacts_per_input
    out = sys.stdout
    if args.method == "static":
        payload, cal = _static(args, settings, entry.node, bench, simulated)
    else:
        payload, cal = _inertial(args, settings, entry.node, bench, cfg, simulated)
    if simulated:
        payload["matrix_error_rel"] = _matrix_error(settings, entry.node, cal.matrix)
        out.write(
            f"  matrix error vs the simulated cell's pinv(S): "
            f"{100 * payload['matrix_error_rel']:.4f} % (Frobenius)\n"
        )
    if (simulated or args.circular_check) and payload["verdict"] != "fail":
        line = _shown("circular check", simulated, args.quiet)
        chk = circular_check(
            settings, node=entry.node, bench_file=bench, cfg=cfg, on_progress=line.update
        )
        line.close()
        payload.update(chk.to_json())
        e = chk.errors_pct
        out.write(
            f"circular check (DIM through calibration version {chk.calibration_version}): mass "
            f"{e['mass_pct']:+.4f} %, CG {e['cg_error_mm']:.3f} mm, principal moments "
            f"{e['I1_pct']:+.3f} / {e['I2_pct']:+.3f} / {e['I3_pct']:+.3f} %; verdict "
            f"{chk.verdict}"
            + (
                ""
                if chk.chain_uncertainty_pct is None
                else f" (cell sees {chk.cell_sensitivity:.2g} × its error; hammer and "
                f"accelerometer scales alone ± {chk.chain_uncertainty_pct:.2f} %, k = 2)"
            )
            + "".join(f"; {r}" for r in chk.reasons)
            + "\n"
        )
    payload = _ordered(payload)
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(payload, indent=2) + "\n", encoding="utf-8")
    for p, fmt in ((args.matrix, "json"), (args.xml, "xml")):
        if p is not None:
            _write_file(cal, p, fmt)
    return 1 if payload["verdict"] == "fail" else 0


_CONTRACT = (
    "method",
    "matrix_error_rel",
    "nonlinearity_pct_fs",
    "hysteresis_pct_fs",
    "uncertainty_pct_fs",
    "circular_mass_error_pct",
)


def _ordered(payload: dict[str, Any]) -> dict[str, Any]:
    """The contract keys first (null when not measured: ``matrix_error_rel`` off the simulated
    lab, nonlinearity and hysteresis for the inertial method, the circular check when not run)."""
    return {**{k: payload.get(k) for k in _CONTRACT}, **payload}


def _matrix_error(settings: Any, node: int, matrix: Any) -> float:
    """``‖C − S⁺‖_F / ‖S⁺‖_F`` against the simulated cell (this command plays the virtual lab:
    it may read the simulator's truth, the service never does)."""
    import numpy as np

    from dimacq.simulators.lab.bridge import strain_gauge_cell

    S = np.asarray(strain_gauge_cell(node).sensitivity_mvv, float)
    C_true = np.linalg.pinv(S)
    return float(np.linalg.norm(np.asarray(matrix) - C_true) / np.linalg.norm(C_true))


def _write_file(cal: Any, path: Path, fmt: str) -> None:
    from dimacq.io.loadcell_calibration import write_calibration_json, write_calibration_xml

    path.parent.mkdir(parents=True, exist_ok=True)
    (write_calibration_json if fmt == "json" else write_calibration_xml)(cal, path)


def _record(settings: Any, document: dict[str, Any]) -> int:
    from dimacq.persistence import open_database
    from dimacq.services.calibration.loadcell_calibration import record_calibration

    db = open_database(settings.db_url)
    try:
        return record_calibration(db, document)
    finally:
        db.close()


def _certificate_table(cert: Any) -> None:
    out = sys.stdout
    out.write("  axis        Fx       Fy       Fz       Mx       My       Mz   (% of rated)\n")
    for label, v in (
        ("nonlinearity", cert.nonlinearity_pct_fs),
        ("hysteresis", cert.hysteresis_pct_fs),
        ("uncert. k=2", cert.uncertainty_pct_fs),
    ):
        out.write(f"  {label:<12}" + "".join(f"{x:9.4f}" for x in v) + "\n")
    out.write(f"  verdict {cert.verdict}" + "".join(f"; {r}" for r in cert.reasons) + "\n")


def _static(
    args: argparse.Namespace, settings: Any, node: int, bench: str | None, simulated: bool
) -> tuple[dict[str, Any], Any]:
    """Dead weights: the simulated bench (``loadcell-bench`` backend) or the configured
    amplifier with a person at the bench. The result is installed as the cell's next
    calibration version."""
    from dimacq.pipeline.loadcell_calibration import LoadCase
    from dimacq.services.calibration.loadcell_calibration import (
        calibrate_rig_cell,
        simulated_static_calibration,
    )

    out = sys.stdout
    if simulated:
        from dimacq.services.calibration.loadcell_calibration import install_static

        line = _progress("dead weights", args.quiet)

        def static_progress(done: int, total: int, message: str) -> None:
            line.update(done / max(total, 1), f"[{done}/{total}] {message}")

        sim = simulated_static_calibration(
            seed=args.seed,
            node=node,
            minimal_plan=args.plan == "minimal",
            progress=static_progress,
        )
        line.close()
        res = install_static(settings, node, sim.run, serial_number=str(node), bench_file=bench)
    else:

        def operator(case: LoadCase, _sample: int) -> None:
            sys.stderr.write(f"\n{case.prompt()}\n  press Enter when the load is in place: ")
            sys.stderr.flush()
            sys.stdin.readline()

        def progress(done: int, total: int, message: str) -> None:
            sys.stderr.write(f"[{done:3d}/{total}] {message}\n")

        res = calibrate_rig_cell(
            settings,
            operator,
            node=node,
            bench_file=bench,
            download=args.download,
            progress=progress,
        )
    payload = res.to_json()
    if simulated:  # the scratch folder is gone after the run
        payload.update(calibration_file=None, versioned_files=None)
    else:
        payload["record_id"] = _record(settings, res.installed_document())
    fit = res.run.certificate.fit
    out.write(
        f"load cell {node} (serial {res.serial_number}): static calibration, "
        f"{len(res.run.plan.cases)} load cases ({fit.n_equations} hysteresis-free points "
        f"fitted), gauges in mV/V; version {res.installed.version}"
        + ("" if simulated else f" in {res.installed.current_path}")
        + "\n"
    )
    out.write(f"  residual {fit.residual_rel:.3g}, condition σ1/σ6 {fit.condition:.3g}\n")
    _certificate_table(res.run.certificate)
    _download_line(res.download)
    return payload, res.calibration


def _download_line(check: Any) -> None:
    if check is not None:
        sys.stdout.write(
            f"  downloaded to the amplifier: {check.verified}/{check.of} elements verified on "
            "read-back\n"
        )


def _inertial(
    args: argparse.Namespace,
    settings: Any,
    node: int,
    bench: str | None,
    cfg: dict[str, Any],
    simulated: bool,
) -> tuple[dict[str, Any], Any]:
    """The calibration mass on the cell, struck on its support side (simulated: the world's
    hand; real: a person prompted for each strike); installed as the next version, recorded
    (real rig) and downloaded on request."""
    import numpy as np

    from dimacq.io.rig_file import load_rig_file
    from dimacq.services.calibration.inertial_calibration import (
        install_inertial,
        installed_document,
        run_inertial_calibration,
        select_cell,
    )
    from dimacq.services.calibration.loadcell_calibration import download_and_verify

    line = _shown("inertial bench", simulated, args.quiet)
    run, check = run_inertial_calibration(
        settings,
        node=node,
        bench_file=bench,
        cfg=cfg,
        on_progress=line.update,
        download=download_and_verify if args.download else None,
    )
    line.close()
    rig = load_rig_file(settings.rig_path)
    installed = install_inertial(rig, select_cell(rig, node), run)
    cal = run.calibration()
    payload: dict[str, Any] = {
        "method": "inertial",
        "nonlinearity_pct_fs": None,
        "hysteresis_pct_fs": None,
        "uncertainty_pct_fs": run.uncertainty_pct_fs(),
        "matrix_uncertainty_rel": run.matrix_uncertainty_rel(),
        "verdict": run.verdict,
        "reasons": list(run.reasons),
        "load_cell_node": node,
        "serial_number": run.serial_number,
        "gauge_unit": run.gauge_unit,
        "averages_per_input": run.averages_per_input,
        "band_hz": list(run.band_hz),
        "version": installed.version,
        "calibration_file": None if simulated else str(installed.current_path),
        "versioned_files": (
            None if simulated else [str(installed.json_path), str(installed.xml_path)]
        ),
        "downloaded": check is not None,
        "download_verified": None if check is None else check.verified,
        "download_elements": None if check is None else check.of,
        "fit": run.fit_json(),
        "matrix": run.matrix.tolist(),
    }
    if not simulated:
        payload["record_id"] = _record(settings, installed_document(cal, installed.version))
    fit = run.fit
    sys.stdout.write(
        f"load cell {node} (serial {run.serial_number}): inertial calibration, "
        f"{run.averages_per_input} averages × {run.n_inputs} inputs, band "
        f"{run.band_hz[0]:g}–{run.band_hz[1]:g} Hz ({fit.n_equations} equations); version "
        f"{installed.version}" + ("" if simulated else f" in {installed.current_path}") + "\n"
        f"  residual {fit.residual_rel:.3g}, condition σ1/σ6 {fit.condition:.3g}, noise "
        f"separation σ7/σ6 {fit.noise_separation:.3g}; matrix uncertainty (k = 2) "
        f"{100 * run.matrix_uncertainty_rel():.3f} % (Frobenius)\n"
    )
    g = run.gains
    if g is not None and g.identified:
        dev = 100 * (1 / g.gains - 1)
        sys.stdout.write(
            f"  accelerometers: relative gains from the rigid-body fit (λ₁/λ₂ {g.separation:.2g}),"
            f" {np.max(np.abs(dev)):.2f} % at most from their certificates; common scale ± "
            f"{100 * g.scale_std:.3f} % (the certificates' mean)\n"
        )
    for reason in run.reasons:
        sys.stdout.write(f"  warning: {reason}\n")
    if run.hammer_ratio is not None:
        r, sd = run.hammer_ratio
        sys.stdout.write(
            f"  hammer: stated sensitivity / the calibration mass's {r:.4f} ± {sd:.4f} (DIM's "
            f"mass through this hammer comes out {100 * (1 / r - 1):+.2f} % off)\n"
        )
    _download_line(check)
    return payload, cal
