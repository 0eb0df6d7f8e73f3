"""``dimacq sensitivity``: Monte Carlo sensitivity of DIM to geometry errors (thesis §2.2).

``dimacq sensitivity cube --half-size H --sensors K --max-angle-deg A --trials N --seed S
[--json OUT] [--plots DIR]`` runs the thesis's analytical cube model (8 triaxes at (±H, ±H, ±H),
six unit forces and moments at the origin, free-free, the calibration mass), the first K triaxes
randomly rotated within ±A degrees about each axis, and prints the per-parameter table (min, max,
mean, std, actual, mean error %) as thesis Tables 2–4. The JSON has one object per parameter
(the parameter names ``m``, ``cx`` .. ``Izz``, and ``mass_kg`` repeating ``m``) with ``min``, ``max``, ``mean``, ``std``, ``actual``,
``mean_error_pct``, plus ``study`` (the inputs).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from dimacq.errors import SetupError
from dimacq.pipeline.sensitivity import SensitivityResult, cube_study


def register(subparsers: Any) -> None:
    parser = subparsers.add_parser(
        "sensitivity", help="Monte Carlo sensitivity of DIM to geometry errors"
    )
    sub = parser.add_subparsers(dest="sensitivity_command", metavar="MODEL")
    sub.required = True
    cube = sub.add_parser("cube", help="the thesis's analytical cube model (Tables 2-13)")
    cube.add_argument(
        "--half-size",
        type=float,
        required=True,
        metavar="H",
        help="triaxes at (±H, ±H, ±H) m (the thesis's 0.02 m cube has H = 0.01)",
    )
    cube.add_argument(
        "--sensors", type=int, default=1, metavar="K", help="triaxes randomised (1-8)"
    )
    cube.add_argument(
        "--max-angle-deg",
        type=float,
        required=True,
        metavar="A",
        help="rotation angles uniform within ±A degrees about each axis",
    )
    cube.add_argument("--trials", type=int, default=500, metavar="N")
    cube.add_argument("--seed", type=int, default=None, metavar="S")
    cube.add_argument(
        "--json", type=Path, default=None, metavar="OUT", help="write the table as JSON"
    )
    cube.add_argument("--plots", type=Path, default=None, metavar="DIR", help="write histograms")
    cube.set_defaults(func=run_cube)


def format_table(res: SensitivityResult) -> str:
    """The thesis-style table: one row per parameter."""
    from dimacq.pipeline.sensitivity import UNITS

    head = f"{'parameter':<13} {'minimum':>14} {'maximum':>14} {'mean':>14} {'std':>12} {'actual':>12} {'mean err %':>11}"
    lines = [head, "-" * len(head)]
    for key, s in res.stats.items():
        lines.append(
            f"{key + ' (' + UNITS[key].replace('kg m^2', 'kg m²') + ')':<13} {s['min']:>14.6g} {s['max']:>14.6g} {s['mean']:>14.6g} {s['std']:>12.4g} "
            f"{s['actual']:>12.6g} {s['mean_error_pct']:>11.4g}"
        )
    return "\n".join(lines)


def run_cube(args: Any) -> int:
    if args.trials < 1:
        raise SetupError(f"--trials {args.trials}: give at least 1 trial")
    if args.max_angle_deg < 0:
        raise SetupError(f"--max-angle-deg {args.max_angle_deg}: give a non-negative angle")
    res = cube_study(
        args.half_size,
        n_sensors=args.sensors,
        max_angle_deg=args.max_angle_deg,
        n_trials=args.trials,
        seed=args.seed,
    )
    print(
        f"Cube {2 * args.half_size:g} m (triaxes at ±{args.half_size:g} m), {args.sensors} triax(es) "
        f"rotated within ±{args.max_angle_deg:g}°, {args.trials} trials, seed {args.seed}"
    )
    print(format_table(res))
    if args.json is not None:
        try:
            args.json.write_text(json.dumps(res.to_json(), indent=2) + "\n")
        except OSError as err:
            raise SetupError(f"cannot write {args.json}: {err}; give a writable path") from err
    if args.plots is not None:
        from dimacq.plotting import plot_sensitivity

        plot_sensitivity(
            res.samples,
            res.truth,
            args.plots,
            title=f"Cube {2 * args.half_size:g} m, {args.sensors} triax(es), ±{args.max_angle_deg:g}°",
        )
    return 0
