"""``dimacq solve``: rigid-body inertia properties from FRFs by the Dynamic Inertia Method.

Usage::

    dimacq solve INPUT [FRF.uff] [--band LO HI] [--known-mass KG] [--known-cg X Y Z]
                 [--known-inertia NAME=VALUE ...] [--reference-point X Y Z]
                 [--length-unit m|cm|mm] [--method joint|mean] [--scale-to-mass KG]
                 [--reference REF.json] [--json OUT]
                 [--no-select] [--no-select-responses] [--no-select-inputs] [--no-auto-band]
                 [--no-geometry-uncertainty] [--repair-orientation] [--plots DIR]
                 [--unbiased] [--refine-geometry] [--residual-flexibility]

INPUT is a setup file (``.toml``/``.json``, then FRF.uff holds the FRFs) or one UFF file holding
the whole test (geometry, coordinate systems and 58 records).

Defaults are the best method: the band is chosen automatically (above the support modes, below
the first elastic mode), response channels and inputs are selected, and every parameter gets a
95 % interval (inputs, sensors, lines and the setup's stated geometry uncertainty). ``--band LO HI``
overrides the band; ``--no-select`` turns both selections off. ``--select-responses``,
``--select-inputs`` and ``--auto-band`` are still accepted (they are the default).

Every result carries a verdict, ok / warn / fail, with its reasons. Exit status: 0 for ok or warn,
3 for fail (the reasons go to stderr; ``--json`` is still written, with the verdict), 2 for bad
input.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path
from typing import Any, TextIO

import numpy as np

from dimacq.cli.progress import plain
from dimacq.errors import SetupError
from dimacq.model.frf import FrfData
from dimacq.model.properties import (
    PRODUCT_SIGN_CONVENTION,
    RigidBodyProperties,
    principal_moments,
)
from dimacq.model.setup import PARAMETERS, TestSetup
from dimacq.pipeline import dim

_UFF_SUFFIXES = {".uff", ".unv"}
_SETUP_SUFFIXES = {".toml", ".json"}
#: Exit status of a solve whose verdict is ``fail``.
EXIT_FAIL = 3


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser(
        "solve",
        help="solve mass, CG and inertia from FRFs (DIM)",
        description=plain(__doc__),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    _add_problem_arguments(p)
    _add_chain_calibration_arguments(p)
    _add_selection_arguments(p)
    _add_estimator_arguments(p)
    p.set_defaults(func=run)


def _add_problem_arguments(p: argparse.ArgumentParser) -> None:
    """The data, the band, the known parameters, the reference point and the method."""
    p.add_argument(
        "input", type=Path, metavar="INPUT", help="setup file (.toml/.json) or whole-test UFF"
    )
    p.add_argument(
        "frf", type=Path, nargs="?", metavar="FRF.uff", help="FRFs when INPUT is a setup"
    )
    p.add_argument("--band", nargs=2, type=float, metavar=("LO", "HI"), help="analysis band, Hz")
    p.add_argument("--known-mass", type=float, metavar="KG", help="known mass, kg")
    p.add_argument(
        "--known-cg",
        nargs=3,
        metavar=("X", "Y", "Z"),
        help="known CG in the GCS, m; '-' leaves a component unknown",
    )
    p.add_argument(
        "--known-inertia",
        nargs="+",
        metavar="NAME=VALUE",
        default=[],
        help="known inertia terms about the reference point, kg·m² (tensor elements), e.g. Ixy=0",
    )
    p.add_argument(
        "--reference-point", nargs=3, type=float, metavar=("X", "Y", "Z"), help="point P, m"
    )
    p.add_argument(
        "--length-unit", choices=("m", "cm", "mm"), help="working length unit (row weighting)"
    )
    p.add_argument(
        "--method",
        choices=("joint", "mean"),
        default="joint",
        help="joint least squares over the band (default) or mean of per-line estimates",
    )
    p.add_argument(
        "--scale-to-mass",
        type=float,
        metavar="KG",
        help="scale the FRFs so that the band mass equals KG (FRF scaling, thesis §3.2.2.1)",
    )


def _add_chain_calibration_arguments(p: argparse.ArgumentParser) -> None:
    """Chain calibration on a weighed reference mass: measure the factor, record it, apply it."""
    c = p.add_argument_group(
        "chain calibration on a reference mass (dimacq.pipeline.chain_calibration)"
    )
    c.add_argument(
        "--reference-mass",
        type=Path,
        metavar="MASS.toml",
        help="the data were measured on this weighed reference body (its certificate, e.g. "
        "config/reference-block/mass.toml): report the chain factor it gives",
    )
    c.add_argument(
        "--write-rig",
        type=Path,
        metavar="RIG.toml",
        help="with --reference-mass: record the measured chain factor in this rig file's hammer "
        "(chain_calibration; the acquisition then uses the certificate's sensitivity × factor)",
    )
    c.add_argument(
        "--chain-calibration",
        type=Path,
        metavar="CAL.json",
        help="apply the chain calibration of a reference-mass solve (its --json output): FRFs "
        "times the factor, the hammer's certificate uncertainty replaced by its own",
    )


def _add_selection_arguments(p: argparse.ArgumentParser) -> None:
    """The reference values, the JSON output, data selection and diagnostics."""
    p.add_argument("--reference", type=Path, metavar="REF.json", help="true values: print %% error")
    p.add_argument("--json", type=Path, metavar="OUT", help="write the solution as JSON")
    g = p.add_argument_group(
        "data selection and diagnostics (selection and automatic band are on by default)"
    )
    g.add_argument("--no-select", action="store_true", help="turn off response and input selection")
    g.add_argument(
        "--no-select-responses", action="store_true", help="turn off perimeter response selection"
    )
    g.add_argument(
        "--no-select-inputs", action="store_true", help="turn off jackknife input selection"
    )
    g.add_argument(
        "--no-auto-band",
        action="store_true",
        help="no automatic band: solve over the whole span unless --band is given",
    )
    g.add_argument(
        "--no-geometry-uncertainty",
        action="store_true",
        help="leave the stated geometry uncertainty out of the intervals (the verdict warns)",
    )
    g.add_argument(
        "--select-responses", action="store_true", help="(default) perimeter response selection"
    )
    g.add_argument(
        "--select-inputs", action="store_true", help="(default) jackknife input selection"
    )
    g.add_argument(
        "--auto-band", action="store_true", help="(default) choose the band automatically"
    )
    g.add_argument(
        "--repair-orientation", action="store_true", help="apply sensor orientation repair"
    )
    g.add_argument("--plots", type=Path, metavar="DIR", help="write figures (PNG and SVG) to DIR")


def _add_estimator_arguments(p: argparse.ArgumentParser) -> None:
    """The estimator: output-error, geometry refinement, residual flexibility, modal correction."""
    e = p.add_argument_group("estimator (dimacq.pipeline.output_error)")
    e.add_argument(
        "--unbiased",
        action=argparse.BooleanOptionalAction,
        default=True,
        help="output-error (maximum-likelihood) estimate, FRF noise estimated from the data: "
        "no errors-in-variables bias (default on; --no-unbiased: equation-error least squares)",
    )
    e.add_argument(
        "--refine-geometry",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="estimate sensor rotations/offsets, input lines of action and channel gains with "
        "the properties, priors from the setup's [geometry_uncertainty] and "
        "[transducer_uncertainty], gauge fixed (default on, an output-error fit: off with "
        "--no-unbiased; --no-refine-geometry: stated geometry as exact, its uncertainty by "
        "Monte Carlo)",
    )
    e.add_argument(
        "--residual-flexibility",
        action=argparse.BooleanOptionalAction,
        default=False,
        help="fit residual terms (ω², ω⁴) of elastic modes above the band and test whether they "
        "were needed (default off)",
    )
    e.add_argument(
        "--modal-correction",
        choices=("auto", "on", "off"),
        default="auto",
        help="take the elastic modes identified from the FRFs (poles and residues of every "
        "pair, LSCF + LSFD) out of the accelerances and reactions and solve on the corrected "
        "FRFs: auto (default) when the rigid-body checks show elastic contamination, on, off",
    )


# ---------------------------------------------------------------------------------------------
def load_test(input_path: Path, frf_path: Path | None) -> tuple[TestSetup, FrfData]:
    """Read a setup + FRF pair or one whole-test UFF file."""
    from dimacq.io.uff import read_frf_uff, read_uff_test

    if not input_path.exists():
        raise SetupError(f"INPUT {input_path} does not exist; give a setup file or a UFF file")
    suffix = input_path.suffix.lower()
    if suffix in _UFF_SUFFIXES:
        if frf_path is not None:
            raise SetupError(
                f"INPUT {input_path} is a UFF file holding the whole test; give FRF.uff only "
                "with a setup file (.toml/.json)"
            )
        return read_uff_test(input_path)
    if suffix in _SETUP_SUFFIXES:
        if frf_path is None:
            raise SetupError(f"setup {input_path} needs its FRFs: give FRF.uff after it")
        if not frf_path.exists():
            raise SetupError(f"FRF.uff {frf_path} does not exist")
        from dimacq.io.setup_file import load_setup  # (TOML/JSON parsers: only for a setup file)

        setup = load_setup(input_path)
        return setup, read_frf_uff(frf_path, setup)
    raise SetupError(
        f"INPUT {input_path}: unknown file type {suffix!r}; use .toml/.json (setup) or .uff/.unv"
    )


def known_from_args(args: argparse.Namespace, setup: TestSetup) -> dict[str, float]:
    """Known properties: the setup's, overridden by the command line."""
    known = setup.known.as_dict()
    if args.known_mass is not None:
        if not args.known_mass > 0:
            raise SetupError(f"--known-mass {args.known_mass}: give a positive mass in kg")
        known["m"] = float(args.known_mass)
    if args.known_cg is not None:
        for name, text in zip(("cx", "cy", "cz"), args.known_cg, strict=True):
            if text in ("-", "_", "?"):
                known.pop(name, None)
                continue
            try:
                known[name] = float(text)
            except ValueError as err:
                raise SetupError(
                    f"--known-cg: {text!r} is not a number; give metres or '-' for unknown"
                ) from err
    for item in args.known_inertia:
        name, sep, value = item.partition("=")
        if not sep or name not in PARAMETERS[4:]:
            raise SetupError(
                f"--known-inertia {item!r}: write NAME=VALUE with NAME one of {', '.join(PARAMETERS[4:])}"
            )
        try:
            known[name] = float(value)
        except ValueError as err:
            raise SetupError(
                f"--known-inertia {item!r}: {value!r} is not a number (kg·m²)"
            ) from err
    return known


def _reference_mass(path: Path | None) -> tuple[float, float] | None:
    if path is None:
        return None
    from dimacq.io.reference_mass import load_reference_mass

    ref = load_reference_mass(path)
    return ref.mass_kg, ref.u_kg


def _chain(path: Path | None) -> Any:
    if path is None:
        return None
    from dimacq.pipeline.chain_calibration import ChainCalibration

    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as err:
        raise SetupError(
            f"--chain-calibration {path.name}: cannot read it as JSON ({err})"
        ) from err
    cal = doc.get("chain_calibration") if isinstance(doc, dict) else None
    if not cal or cal.get("role") != "measured":
        raise SetupError(
            f"--chain-calibration {path.name}: holds no measured chain calibration; give the "
            "--json output of 'dimacq solve --reference-mass' on the reference body"
        )
    return ChainCalibration.from_json(cal, f"--chain-calibration {path.name}")


def _write_rig(args: argparse.Namespace, payload: dict[str, Any]) -> None:
    """``--write-rig``: the measured chain factor into the rig file (refused without one)."""
    import datetime as dt

    from dimacq.io.rig_file import write_chain_calibration

    if args.reference_mass is None:
        raise SetupError("--write-rig needs --reference-mass (the weighed reference body)")
    cal = payload.get("chain_calibration")
    if not cal:
        raise SetupError(
            "--write-rig: this solve measured no chain calibration (verdict "
            f"{payload.get('verdict')}); the rig file is unchanged"
        )
    from dimacq.io.reference_mass import load_reference_mass

    ref = load_reference_mass(args.reference_mass)
    data = Path(args.frf if args.frf is not None else args.input).name
    write_chain_calibration(
        args.write_rig,
        float(cal["factor"]),
        float(cal["u_rel"]),
        source=f"reference {ref.serial_number or args.reference_mass.name}, FRFs {data}",
        date=dt.date.today().isoformat(),
    )
    sys.stderr.write(
        f"{args.write_rig}: hammer chain_calibration updated (× {cal['factor']:.6f})\n"
    )


def run(args: argparse.Namespace) -> int:
    setup, frf = load_test(args.input, args.frf)
    if args.reference_point is not None:
        setup = setup.model_copy(update={"reference_point_m": tuple(args.reference_point)})
    known = known_from_args(args, setup)
    band = tuple(args.band) if args.band else None
    gamma: float | None = None
    if args.scale_to_mass is not None:
        gamma, _ = dim.scale_to_known_mass(
            frf, setup, args.scale_to_mass, band_hz=band, length_unit=args.length_unit
        )
        frf = frf.scaled(gamma)
    payload: dict[str, Any]
    from dimacq.services.solve.analysis import AnalysisOptions, analyse

    refine_geometry = args.refine_geometry
    if not args.unbiased:
        # equation error, as the flag says: the refinement and the residual terms are
        # output-error fits, so asking for them with it is a contradiction, not a preference
        for flag, on in (
            ("--refine-geometry", refine_geometry),
            ("--residual-flexibility", args.residual_flexibility),
        ):
            if on:
                raise SetupError(
                    f"--no-unbiased asks for the equation-error estimate, {flag} for an "
                    "output-error fit; give one of them"
                )
        refine_geometry = False
    elif refine_geometry is None:
        refine_geometry = True
    options = AnalysisOptions(
        select_responses=not (args.no_select or args.no_select_responses),
        select_inputs=not (args.no_select or args.no_select_inputs),
        repair_orientation=args.repair_orientation,
        auto_band=not args.no_auto_band,
        plots_dir=args.plots,
        band_hz=band,
        known=known,
        length_unit=args.length_unit,
        geometry_samples=0 if args.no_geometry_uncertainty else 400,
        method=args.method,
        unbiased=args.unbiased,
        refine_geometry=refine_geometry,
        residual_flexibility=args.residual_flexibility,
        reference_mass=_reference_mass(args.reference_mass),
        chain=_chain(args.chain_calibration),
        modal_correction=args.modal_correction,
    )
    report = analyse(frf, setup, options)
    result = report.result
    payload = report.to_json()
    if gamma is not None:
        payload["frf_scale_factor"] = gamma
    if args.write_rig is not None:
        _write_rig(args, payload)
    reference = _load_reference(args.reference) if args.reference else None
    if reference is not None:
        payload["reference"] = reference.to_json(result.reference_point_m)
        payload["error_pct"] = error_pct(result, reference)
    print_report(result, payload, reference, sys.stdout)
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(payload, indent=2, allow_nan=True) + "\n", encoding="utf-8")
    if report.verdict == "fail":
        sys.stderr.write("dimacq solve: verdict FAIL — the result is refused:\n")
        for r in report.verdict_reasons:
            if r.severity == "fail":
                sys.stderr.write(f"  {r.check}: {r.message}\n")
        return EXIT_FAIL
    if report.verdict == "warn":
        for r in report.verdict_reasons:
            if r.severity == "warn":
                sys.stderr.write(f"dimacq solve: warning: {r.check}: {r.message}\n")
    return 0


def _load_reference(path: Path) -> RigidBodyProperties:
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError as err:
        raise SetupError(f"--reference {path} does not exist") from err
    except json.JSONDecodeError as err:
        raise SetupError(f"--reference {path}: not valid JSON ({err})") from err
    return RigidBodyProperties.from_json(data)


# ---------------------------------------------------------------------------------------------
def _rows(result: dim.DimResult) -> list[tuple[str, str, float, str]]:
    """(name, unit, value, stats-key) rows of the report."""
    p = result.parameters
    units = ["kg", "m", "m", "m"] + ["kg·m²"] * 6
    return [(n, u, float(v), n) for n, u, v in zip(PARAMETERS, units, p, strict=True)]


def error_pct(result: dim.DimResult, ref: RigidBodyProperties) -> dict[str, float]:
    """% error per parameter against a reference.

    Mass and inertia terms: ``100 (est − true)/|true|``; inertia terms whose true value is below
    1e-6 of the largest principal moment, and CG components below 1 mm, are reported relative to
    the largest principal moment and to 1 m respectively, so a zero true value gives no infinity.
    """
    true = ref.parameter_vector(result.reference_point_m)
    true[1:4] = ref.cg_m
    est = result.parameters
    big_i = float(np.max(np.abs(np.linalg.eigvalsh(ref.inertia_about(result.reference_point_m)))))
    out: dict[str, float] = {}
    for i, name in enumerate(PARAMETERS):
        if i == 0:
            scale = abs(true[0])
        elif i < 4:
            scale = abs(true[i]) if abs(true[i]) >= 1e-3 else 1.0
        else:
            scale = abs(true[i]) if abs(true[i]) >= 1e-6 * big_i else big_i
        out[name] = float(100.0 * (est[i] - true[i]) / scale) if scale > 0 else math.nan
    return out


def print_report(
    result: dim.DimResult,
    payload: dict[str, Any],
    reference: RigidBodyProperties | None,
    out: TextIO,
) -> None:
    """A table like the thesis's: estimate, band statistics and, with a reference, % error."""
    w = out.write
    _print_header(result, w)
    _print_table(result, payload, reference, w)
    _print_principal_axes(result, payload, w)
    _print_modal(payload, w)
    _print_cross_check(result, payload, reference, w)
    _print_data_corrections(payload, w)
    _print_estimator(payload, w)
    _print_checks(result, payload, w)


def _print_header(result: dim.DimResult, w: Any) -> None:
    """The band, the method, the reference point, the channel counts and the known values."""
    lo, hi = result.band_hz
    w(
        f"DIM solution — band {lo:g}–{hi:g} Hz ({result.frequencies_hz.size} lines), "
        f"method {result.method}, length unit {result.length_unit}\n"
    )
    w(
        f"reference point P = ({', '.join(f'{x:g}' for x in result.reference_point_m)}) m; "
        f"{len(result.responses)} responses, {len(result.inputs)} inputs, "
        f"{len(result.load_cells)} load cells\n"
    )
    if result.known:
        w("known: " + ", ".join(f"{k} = {v:g}" for k, v in result.known.items()) + "\n")


def _print_table(
    result: dim.DimResult,
    payload: dict[str, Any],
    reference: RigidBodyProperties | None,
    w: Any,
) -> None:
    """One row per parameter: estimate, band statistics, 95 % interval, true value and error."""
    header = f"{'parameter':<10}{'unit':<7}{'estimate':>14}{'band mean':>14}{'band std':>12}{'band min':>14}{'band max':>14}"
    unc = payload.get("uncertainty") or {}
    if unc:
        header += f"{'95 % interval':>28}"
    errs = payload.get("error_pct")
    if reference is not None:
        header += f"{'true':>14}{'error %':>10}"
        true = reference.parameter_vector(result.reference_point_m)
        true[1:4] = reference.cg_m
    w(header + "\n" + "-" * len(header) + "\n")
    for i, (name, unit, value, key) in enumerate(_rows(result)):
        st = result.band_stats[key]
        line = (
            f"{name:<10}{unit:<7}{value:>14.6g}{st['mean']:>14.6g}{st['std']:>12.3g}"
            f"{st['min']:>14.6g}{st['max']:>14.6g}"
        )
        if unc:
            ci = unc.get(name, {}).get("ci95")
            line += f"{f'[{ci[0]:.6g}, {ci[1]:.6g}]' if ci else '':>28}"
        if reference is not None and errs is not None:
            line += f"{true[i]:>14.6g}{errs[name]:>10.3f}"
        w(line + "\n")


def _print_principal_axes(result: dim.DimResult, payload: dict[str, Any], w: Any) -> None:
    """Principal moments and axes about the CG, the solve's rank, conditioning and residual."""
    pm = payload["principal_moments_kgm2"]
    w("principal moments about the CG: " + ", ".join(f"{x:.6g}" for x in pm) + " kg·m²\n")
    axes = np.asarray(payload["principal_axes"])
    for k in range(3):
        w(f"  axis {k + 1}: ({', '.join(f'{x:+.4f}' for x in axes[:, k])})\n")
    w(
        f"rank {result.rank}/{result.n_unknowns}, condition number {result.condition_number:.3g}, "
        f"relative residual {result.residual_rel:.3g}\n"
    )
    w(f"sign convention: {PRODUCT_SIGN_CONVENTION}\n")


def _print_data_corrections(payload: dict[str, Any], w: Any) -> None:
    """What was done to the data: FRF scaling, chain calibration, band, exclusions, orientations."""
    if "frf_scale_factor" in payload:
        w(f"FRFs scaled by {payload['frf_scale_factor']:.9g} to the known mass\n")
    chain = payload.get("chain_calibration")
    if isinstance(chain, dict):
        if chain.get("role") == "measured":
            w(
                f"chain calibration measured: factor {chain['factor']:.6f} ± "
                f"{100 * chain['u_rel']:.3f} % (1σ; the reference body measures "
                f"{chain['measured_mass_kg']:.5g} kg against its weighed "
                f"{chain['reference_mass_kg']:.5g} kg); apply it with --chain-calibration\n"
            )
        else:
            w(
                f"chain calibration applied: FRFs × {chain['factor']:.6f} ± "
                f"{100 * chain['u_rel']:.3f} % ({chain.get('source') or 'given'})\n"
            )
    band_sel = payload.get("band_selection")
    if isinstance(band_sel, dict) and band_sel.get("reason"):
        w(f"band: {band_sel['reason']}\n")
    for key in ("excluded_responses", "excluded_inputs"):
        if payload.get(key):
            items = ", ".join(f"{d['node']}:{d['direction']:+d}" for d in payload[key])
            w(f"{key.replace('_', ' ')}: {items}\n")
    for corr in payload.get("orientation_corrections") or []:
        if isinstance(corr, dict):
            applied = "applied" if corr.get("applied") else "not applied"
            angle = float(corr.get("angle_deg", float("nan")))
            w(f"orientation correction node {corr.get('node')}: {angle:.3f} deg ({applied})\n")


def _print_estimator(payload: dict[str, Any], w: Any) -> None:
    """The estimator used and, for output-error, its fit and the corrections it estimated."""
    oe = payload.get("output_error")
    if isinstance(oe, dict) and oe.get("used"):
        w(
            f"estimator: output-error (geometry refined: {'yes' if oe['refine_geometry'] else 'no'}), "
            f"{oe['iterations']} iterations, reduced χ² {oe['chi2_reduced']:.3g}\n"
        )
        est = [c for c in oe["sensor_corrections"] if c["rotation_estimated"]]
        if est:
            worst = max(est, key=lambda c: float(np.linalg.norm(c["rotation_deg"])))
            w(
                f"  sensor corrections: {len(est)} nodes, largest rotation node {worst['node']} "
                f"{float(np.linalg.norm(worst['rotation_deg'])):.3f} deg\n"
            )
        for gross in oe.get("gross_errors") or []:
            w(
                f"  gross error: {gross['item']} (its correction {gross['correction_sigma']:.1f} σ "
                "of the stated uncertainty)\n"
            )
        for c in oe.get("load_cell_corrections") or []:
            if not (c.get("offset_estimated") or c.get("moment_gain_estimated")):
                continue
            off = float(np.linalg.norm(c["offset_mm"]))
            gains = ", ".join(f"{v:+.2f}" for v in c["moment_gain_pct"])
            w(
                f"  load cell {c['node']}: moved {off:.2f} mm (prior {c['offset_prior_mm']:.2g} mm "
                f"per axis), turned {float(np.linalg.norm(c['rotation_deg'])):.3f} deg, moment "
                f"gains {gains} % (prior {c['moment_gain_prior_pct']:.2g} %)\n"
            )
        rf = oe.get("residual_flexibility") or {}
        if rf.get("mode") != "off":
            w(
                f"  residual flexibility: {'fitted' if rf.get('fitted') else 'not fitted'}, "
                f"{'needed' if rf.get('needed') else 'not needed'} by the test\n"
            )
    elif isinstance(oe, dict):
        w(f"estimator: equation-error (output-error not used: {oe.get('reason')})\n")
    else:
        w("estimator: equation-error least squares (output-error fit not asked for)\n")


def _print_checks(result: dim.DimResult, payload: dict[str, Any], w: Any) -> None:
    """Each diagnostic with its mark, then the verdict and the reasons that are not ok."""
    for d in result.diagnostics:
        mark = "ok  " if d.ok else ("FAIL" if d.severity == "error" else "warn")
        w(f"[{mark}] {d.code}: {d.message}\n")
    v = payload.get("verdict")
    if v:
        w(f"verdict: {str(v).upper()}" + (" (result refused)" if v == "fail" else "") + "\n")
        for r in payload.get("verdict_reasons") or []:
            if r.get("severity") != "ok":
                w(f"  [{r['severity']}] {r['check']}: {r['message']}\n")


def _print_modal(payload: dict[str, Any], w: Any) -> None:
    """The modal correction: why, the poles, the modes taken out, the correction's size."""
    mc = payload.get("modal_correction")
    if not isinstance(mc, dict) or (not mc.get("applied") and mc.get("mode") == "off"):
        return
    w(f"modal correction ({mc['mode']}): {mc['reason']}\n")
    if not mc.get("poles"):
        return
    w(
        "  poles (Hz, damping %, shape's rigid-body error): "
        + "; ".join(
            f"{p['frequency_hz']:.3f} {100 * p['damping_ratio']:.2f} % "
            f"{p['shape_rigid_body_error']:.2f}{' elastic' if p['elastic'] else ''}"
            for p in mc["poles"]
        )
        + "\n"
    )
    lo, hi = mc["fit_range_hz"]
    w(
        f"  fit {lo:.3g}–{hi:.3g} Hz, residual {100 * mc['fit_error_rel']:.2g} % of each pair's "
        f"RMS; modes taken out: {', '.join(f'{f:.3g}' for f in mc['modes_removed_hz']) or 'none'}"
        f" Hz; left in: {', '.join(f'{f:.3g}' for f in mc['modes_kept_hz']) or 'none'} Hz\n"
    )
    q = mc.get("fit_quality")
    if q:
        w(
            f"  fit quality: FRFs clean up to {q['clean_span_hz'][1]:.4g} Hz (noise ≤ "
            f"{100 * q['noise_limit_rel']:.2g} %); the fit holds (residual ≤ "
            f"{q['holds_limit']:g}× the noise or the median residual) on {q.get('lines_held', 0)} of "
            f"{q.get('lines_fitted', 0)} lines, DIM band within {q['holds_range_hz'][0]:.4g}–"
            f"{q['holds_range_hz'][1]:.4g} Hz\n"
        )
    size = mc.get("correction_size")
    if size and size["relative"]:
        f, r = np.asarray(size["frequencies_hz"]), np.asarray(size["relative"])
        step = max(1, f.size // 8)
        w(
            "  correction / accelerance per line: "
            + ", ".join(
                f"{a:.4g} Hz {100 * b:.2g} %" for a, b in zip(f[::step], r[::step], strict=True)
            )
            + f" (largest {100 * size['max']:.3g} %)\n"
        )


def _print_cross_check(
    result: dim.DimResult,
    payload: dict[str, Any],
    reference: RigidBodyProperties | None,
    w: Any,
) -> None:
    """DIM and the mass-line cross-check side by side, with the z-score of each difference."""
    cc = payload.get("cross_check")
    if not isinstance(cc, dict):
        return
    if cc.get("error"):
        w(f"cross-check (mass line): not made: {cc['error']}\n")
        return
    w(
        "cross-check (mass line: A ≈ Ψ M⁻¹ F fitted on the same band, channels and inputs, "
        "stated geometry); ± = each estimator's own 95 % interval;\n  z = difference over the "
        "comparison standard errors (what moves both alike left out: JSON "
        "cross_check.comparison_standard_error, dim_standard_error); agrees: |z| ≤ 1.96, "
        f"verdict warns beyond |z| {cc.get('family_wise_z_limit', 2.89):.3g}\n"
    )
    unc = payload.get("uncertainty") or {}
    head = f"{'quantity':<12}{'DIM':>14}{'± (95 %)':>12}{'mass line':>14}{'± (95 %)':>12}{'z':>8}  agrees"
    if reference is not None:
        head += f"{'DIM err %':>11}{'ML err %':>10}"
    w(head + "\n" + "-" * len(head) + "\n")
    se = cc["standard_error"]
    z, ag = cc["z"], cc["agrees"]
    pm_dim = payload["principal_moments_kgm2"]
    pu = unc.get("principal_moments") or [{}] * 3
    ref_pm = ref_ip = None
    if reference is not None:
        ref_pm = principal_moments(reference.inertia_cg_kgm2)[0]
        ref_ip = reference.parameter_vector(result.reference_point_m)[4:10]
    rows: list[tuple[str, float, float, float, float, float, bool, float | None]] = []
    rows.append(
        (
            "m kg",
            result.mass_kg,
            float(unc.get("m", {}).get("standard_error", 0.0)),
            cc["mass_kg"],
            se["m"],
            z["mass"],
            ag["mass"],
            reference.mass_kg if reference is not None else None,
        )
    )
    for k, name in enumerate(("cx", "cy", "cz")):
        rows.append(
            (
                f"{name} m",
                float(result.cg_m[k]),
                float(unc.get(name, {}).get("standard_error", 0.0)),
                cc["cg_m"][k],
                se[name],
                z["cg"][k],
                ag["cg"][k],
                float(reference.cg_m[k]) if reference is not None else None,
            )
        )
    for i, name in enumerate(("Ixx", "Ixy", "Ixz", "Iyy", "Iyz", "Izz")):
        rows.append(
            (
                f"{name}(P)",
                float(result.parameters[4 + i]),
                float(unc.get(name, {}).get("standard_error", 0.0)),
                cc["inertia_p_kgm2"][[0, 0, 0, 1, 1, 2][i]][[0, 1, 2, 1, 2, 2][i]],
                se[f"{name}_p"],
                z["inertia"][name],
                ag["inertia"][name],
                float(ref_ip[i]) if ref_ip is not None else None,
            )
        )
    for k in range(3):
        rows.append(
            (
                f"I{k + 1} kg·m²",
                float(pm_dim[k]),
                float(pu[k].get("standard_error", 0.0)) if pu[k] else 0.0,
                cc["principal_moments_kgm2"][k],
                se[f"I{k + 1}"],
                z["principal"][k],
                ag["principal"][k],
                float(ref_pm[k]) if ref_pm is not None else None,
            )
        )
    for name, xd, sd, xc, sc, zz, a, t in rows:
        line = (
            f"{name:<12}{xd:>14.6g}{1.96 * sd:>12.3g}{xc:>14.6g}{1.96 * sc:>12.3g}{zz:>8.2f}  "
            f"{'yes' if a else 'NO':<6}"
        )
        if t is not None:
            e1 = 100 * (xd - t) / abs(t) if t else float("nan")
            e2 = 100 * (xc - t) / abs(t) if t else float("nan")
            line += f"{e1:>11.3f}{e2:>10.3f}"
        w(line + "\n")
    st = cc.get("rigid_structure") or {}
    w(
        f"mass-line fit: relative residual {cc['residual_rel']:.3g}, non-rigid part of its mass "
        f"matrix {st.get('rel', float('nan')):.3g} (χ² {st.get('chi2', float('nan')):.3g} on 11 "
        f"dof, p = {st.get('p_value', float('nan')):.3g})\n"
    )
