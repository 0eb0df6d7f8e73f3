"""Digitizer self-test: digitize the simulator's known points through the wire protocol.

:func:`run_selftest` gives the figures of ``dimacq digitizer selftest``: tip RMS error, echoes
rejected, jig orientation error, triangulation throughput.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np
from numpy.typing import NDArray

from dimacq.devices.digitizer import Digitizer, ShotRecord
from dimacq.errors import DataError, SetupError
from dimacq.pipeline.digitizing.orientation import JigDefinition
from dimacq.pipeline.digitizing.registration import register
from dimacq.pipeline.digitizing.triangulation import combine_shots, triangulate
from dimacq.services.geometry.digitizer_config import ArrayConfig
from dimacq.services.geometry.digitizing import records_to_arrays

__all__ = ["SelftestReport", "run_selftest"]

FloatArray = NDArray[np.float64]


class _SimControl(Digitizer, Protocol):
    def command(self, text: str, expect: str = "OK") -> list[str]: ...


@dataclass(frozen=True)
class SelftestReport:
    """Figures of :func:`run_selftest` (lengths in mm, angles in degrees).

    ``as_dict()`` gives the JSON keys of ``dimacq digitizer selftest --json``.
    """

    values: dict[str, Any]
    orthogonality_checks: list[FloatArray]
    jig_names: list[str]

    def as_dict(self) -> dict[str, Any]:
        return dict(self.values)


def _random_axes(
    rng: np.random.Generator, n: int, facing: FloatArray, cone_deg: float
) -> FloatArray:
    """Unit probe axes within ``cone_deg`` of ``facing`` (the tip points away from the array)."""
    out = np.empty((n, 3))
    for i in range(n):
        while True:
            v = facing + np.tan(np.radians(cone_deg)) * rng.uniform(-1, 1, 3)
            v /= np.linalg.norm(v)
            if np.degrees(np.arccos(np.clip(v @ facing, -1, 1))) <= cone_deg:
                out[i] = v
                break
    return out


def _shots_at(device: _SimControl, tip_m: FloatArray, axis: FloatArray, n: int) -> list[ShotRecord]:
    vals = ",".join(f"{v:.6f}" for v in (*tip_m, *axis))
    device.command(f"SIM:PROBE {vals}")
    return [device.fire() for _ in range(n)]


def _solve(records: Sequence[ShotRecord], cfg: ArrayConfig) -> Any:
    counts, bar, avg, status, _ = records_to_arrays(records)
    return triangulate(
        counts, bar, cfg.geometry(), averaging=avg, status=status, limits=cfg.limits()
    )


def _points_from(
    records: Sequence[ShotRecord], cfg: ArrayConfig, per_point: int
) -> tuple[FloatArray, Any]:
    sol = _solve(records, cfg)
    n_points = len(records) // per_point
    pts = np.empty((n_points, 3))
    for i in range(n_points):
        sl = slice(i * per_point, (i + 1) * per_point)
        try:
            pts[i] = combine_shots(
                sol.tip_m[sl], sol.accepted[sl], cfg.quality.point_outlier_m
            ).position_m
        except DataError:
            pts[i] = np.nan
    return pts, sol


def run_selftest(
    device: _SimControl,
    cfg: ArrayConfig,
    jig: JigDefinition,
    *,
    shots: int = 1000,
    shots_per_point: int = 5,
    echo_rate: float = 0.02,
    temperature_c: float = 20.0,
    temperature_step_c: float = 10.0,
    n_jigs: int = 4,
    seed: int = 1,
    min_timing_s: float = 0.3,
) -> SelftestReport:
    """Digitize the simulator's known points through the wire and report the accuracy figures.

    Steps: (1) ``shots`` shots on ``shots // shots_per_point`` random points of the digitizer
    volume at ``temperature_c`` with echo rate ``echo_rate``: tip RMS error per point and per shot,
    echoes injected (the simulator's ``SIM:ECHOES?``) and accepted; (2) the same points after a
    ``temperature_step_c`` change of air temperature; (3) a random DACS→GCS registration from 8
    reference nodes, then ``n_jigs`` jig placements (24 indentations × ``shots_per_point`` shots)
    fitted with three rods (rigid and thesis affine), two rods (cross product and rigid), and the Z
    rod as a line of action; (4) triangulation throughput on the recorded shots.
    """
    if cfg.volume is None:
        raise SetupError("selftest: the array config has no [volume] section; add min_m and max_m")
    if shots < shots_per_point:
        raise SetupError(f"selftest: shots {shots} < shots_per_point {shots_per_point}")
    rng = np.random.default_rng(seed)
    geometry = cfg.geometry()
    lo, hi = np.asarray(cfg.volume.min_m), np.asarray(cfg.volume.max_m)
    n_mics = len(geometry.microphones_m)
    device.reset()
    device.configure(emitters=2, microphones=n_mics, averaging=1, bar_repeats=4)
    device.command(f"SIM:TEMP {temperature_c:g}")
    device.command(f"SIM:ECHO {echo_rate:g}")

    # (1) known points over the volume
    n_points = shots // shots_per_point
    tips = rng.uniform(lo, hi, size=(n_points, 3))
    axes = _random_axes(rng, n_points, geometry.facing, 40.0)
    records = _shots_at_points(device, tips, axes, shots_per_point)
    tip_rms, known_points = _known_points_figures(device, records, tips, cfg, shots_per_point)

    # (2) temperature step
    device.command("SIM:ECHO 0")
    device.command(f"SIM:TEMP {temperature_c + temperature_step_c:g}")
    step = _temperature_step_figures(device, records, tips, axes, cfg, shots_per_point, tip_rms)
    device.command(f"SIM:TEMP {temperature_c:g}")
    device.command(f"SIM:ECHO {echo_rate:g}")

    # (3) registration + jig placements
    placements, checks, names = _jig_placement_figures(
        device, cfg, jig, rng, lo, hi, n_jigs, shots_per_point
    )

    # (4) throughput on the recorded shots (solver only, no serial link)
    rate = _triangulation_rate(records, cfg, min_timing_s)

    values: dict[str, Any] = {
        "shots": len(records),
        "points": n_points,
        "shots_per_point": shots_per_point,
        "echo_rate": echo_rate,
        "temperature_c": temperature_c,
        **known_points,
        "temperature_step_c": temperature_step_c,
        **step,
        **placements,
        "triangulation_shots_per_second": rate,
    }
    return SelftestReport(values=values, orthogonality_checks=checks, jig_names=names)


def _rms(v: Sequence[float]) -> float:
    """Root mean square of ``v``; NaN when empty."""
    return float(np.sqrt(np.mean(np.square(v)))) if len(v) else float("nan")


def _shots_at_points(
    device: _SimControl, points: FloatArray, axes: FloatArray, shots_per_point: int
) -> list[ShotRecord]:
    """``shots_per_point`` shots with the probe at each point, its axis along ``axes``."""
    records: list[ShotRecord] = []
    for tip, ax in zip(points, axes, strict=True):
        records += _shots_at(device, tip, ax, shots_per_point)
    return records


def _known_points_figures(
    device: _SimControl,
    records: list[ShotRecord],
    tips: FloatArray,
    cfg: ArrayConfig,
    shots_per_point: int,
) -> tuple[float, dict[str, Any]]:
    """Step 1's figures: tip RMS (m) and the tip errors per point and per clean shot (mm), and
    how many of the echoes the simulator injected were accepted."""
    echo_fields = device.command("SIM:ECHOES?", expect="SIM")
    echo_seqs = {int(v) for v in echo_fields[3:]}
    pts, sol = _points_from(records, cfg, shots_per_point)
    seqs = np.array([r.seq for r in records])
    is_echo = np.isin(seqs, list(echo_seqs))
    truth_per_shot = np.repeat(tips, shots_per_point, axis=0)
    shot_err = np.linalg.norm(sol.tip_m - truth_per_shot, axis=1)
    ok = sol.accepted
    point_err = np.linalg.norm(pts - tips, axis=1)
    tip_rms = float(np.sqrt(np.nanmean(point_err**2)))
    return tip_rms, {
        "tip_rms_mm": 1e3 * tip_rms,
        "tip_max_mm": 1e3 * float(np.nanmax(point_err)),
        "tip_rms_single_shot_mm": 1e3 * float(np.sqrt(np.mean(shot_err[ok & ~is_echo] ** 2))),
        "echoes_injected": int(is_echo.sum()),
        "echoes_accepted": int((is_echo & ok).sum()),
        "echoes_rejected": int((is_echo & ~ok).sum()),
        "clean_shots_rejected": int((~is_echo & ~ok).sum()),
    }


def _temperature_step_figures(
    device: _SimControl,
    records: list[ShotRecord],
    tips: FloatArray,
    axes: FloatArray,
    cfg: ArrayConfig,
    shots_per_point: int,
    tip_rms: float,
) -> dict[str, Any]:
    """Step 2's figures: the same points shot again after the air temperature changed, with
    the speed of sound tracked (bar) and frozen at the first pass's."""
    geometry = cfg.geometry()
    rec_t = _shots_at_points(device, tips, axes, shots_per_point)
    pts_t, _ = _points_from(rec_t, cfg, shots_per_point)
    rms_t = float(np.sqrt(np.nanmean(np.sum((pts_t - tips) ** 2, axis=1))))
    # the same shots with the speed of sound frozen at the first pass (no bar tracking)
    counts_t, _, avg_t, status_t, _ = records_to_arrays(rec_t)
    _, bar_0, _, _, _ = records_to_arrays(records[: len(rec_t)])
    frozen = triangulate(
        counts_t, bar_0, geometry, averaging=avg_t, status=status_t, limits=cfg.limits()
    )
    truth_per_shot = np.repeat(tips, shots_per_point, axis=0)
    frozen_err = np.linalg.norm(frozen.tip_m - truth_per_shot, axis=1)
    return {
        "tip_rms_mm_after_step": 1e3 * rms_t,
        "temperature_step_added_mm": 1e3 * float(np.sqrt(max(rms_t**2 - tip_rms**2, 0.0))),
        "tip_rms_mm_speed_not_tracked": 1e3 * float(np.sqrt(np.mean(frozen_err**2))),
    }


def _jig_placement_figures(
    device: _SimControl,
    cfg: ArrayConfig,
    jig: JigDefinition,
    rng: np.random.Generator,
    lo: FloatArray,
    hi: FloatArray,
    n_jigs: int,
    shots_per_point: int,
) -> tuple[dict[str, Any], list[FloatArray], list[str]]:
    """Step 3: register a random DACS→GCS placement on 8 reference nodes, then digitize
    ``n_jigs`` random jig placements and fit each; the RMS errors, the affine fits'
    orthogonality checks and their jig names."""
    from scipy.spatial.transform import Rotation

    geometry = cfg.geometry()
    true_rot = Rotation.random(random_state=int(rng.integers(2**31)))
    true_off = rng.uniform(-1, 1, 3)
    corners = np.array([[i, j, k] for i in (0, 1) for j in (0, 1) for k in (0, 1)], dtype=float)
    ref_dacs = lo + 0.1 * (hi - lo) + corners * 0.8 * (hi - lo)
    ref_gcs = true_rot.apply(ref_dacs) + true_off
    ref_axes = _random_axes(rng, len(ref_dacs), geometry.facing, 30.0)
    ref_rec = _shots_at_points(device, ref_dacs, ref_axes, shots_per_point)
    ref_meas, _ = _points_from(ref_rec, cfg, shots_per_point)
    reg = register(ref_meas, ref_gcs)
    errs: dict[str, list[float]] = {
        k: [] for k in ("rigid", "affine", "cross", "rigid2", "loa", "loa13")
    }
    checks: list[FloatArray] = []
    names: list[str] = []
    margin = 0.25
    for j in range(n_jigs):
        r_sensor = Rotation.random(random_state=int(rng.integers(2**31)))
        origin_dacs = rng.uniform(lo + margin, hi - margin)
        # the sensor's true orientation in the GCS: C = R_reg · R_sensor(DACS)
        jig_dacs = r_sensor.apply(jig.points_local_m) + origin_dacs
        jig_axes = _random_axes(rng, len(jig_dacs), geometry.facing, 30.0)
        jig_rec = _shots_at_points(device, jig_dacs, jig_axes, shots_per_point)
        meas_dacs, _ = _points_from(jig_rec, cfg, shots_per_point)
        c_true = true_rot.as_matrix() @ r_sensor.as_matrix()
        o_true = true_rot.apply(origin_dacs) + true_off
        affine = _jig_fit_errors(jig, reg.apply(meas_dacs), c_true, o_true, errs)
        if affine is not None:
            checks.append(affine.orthogonality)
            names.append(f"jig {j + 1}")
    values = {
        "registration_rms_mm": 1e3 * reg.rms_m,
        "jigs": n_jigs,
        "jig_orientation_rms_deg": _rms(errs["rigid"]),
        "jig_orientation_affine_nearest_rms_deg": _rms(errs["affine"]),
        "jig_two_rod_cross_rms_deg": _rms(errs["cross"]),
        "jig_two_rod_rigid_rms_deg": _rms(errs["rigid2"]),
        "jig_max_orthogonality_off_diagonal": float(
            max((np.abs(c - np.diag(np.diag(c))).max() for c in checks), default=float("nan"))
        ),
        "line_of_action_rms_deg": _rms(errs["loa"]),
        "line_of_action_eq13_rms_deg": _rms(errs["loa13"]),
    }
    return values, checks, names


def _jig_fit_errors(
    jig: JigDefinition,
    meas_gcs: FloatArray,
    c_true: FloatArray,
    o_true: FloatArray,
    errs: dict[str, list[float]],
) -> Any:
    """Fit one digitized jig placement every way and append each fit's error (deg) to ``errs``:
    three rods (rigid, affine), two rods (cross, rigid), the Z rod as a line of action (SVD and
    the thesis's eq. 13). Returns the three-rod rigid fit's affine part (None when absent)."""
    from dimacq.pipeline.digitizing.lines_of_action import (
        angle_between_deg,
        line_of_action_svd,
        line_of_action_thesis,
    )
    from dimacq.pipeline.digitizing.orientation import fit_orientation, rotation_error_deg

    local = jig.points_local_m
    good = np.isfinite(meas_gcs).all(axis=1)
    full = fit_orientation(local[good], meas_gcs[good], jig.rod[good], method="rigid")
    aff = fit_orientation(local[good], meas_gcs[good], jig.rod[good], method="affine")
    two = good & (jig.rod != 2)
    cross = fit_orientation(local[two], meas_gcs[two], jig.rod[two], method="cross")
    rigid2 = fit_orientation(local[two], meas_gcs[two], jig.rod[two], method="rigid")
    errs["rigid"].append(rotation_error_deg(full.rotation, c_true))
    errs["affine"].append(rotation_error_deg(aff.rotation, c_true))
    errs["cross"].append(rotation_error_deg(cross.rotation, c_true))
    errs["rigid2"].append(rotation_error_deg(rigid2.rotation, c_true))
    zrod = good & (jig.rod == 2)
    true_dir = -c_true[:, 2]  # from the rod's points towards the input node (jig origin)
    errs["loa"].append(
        angle_between_deg(line_of_action_svd(meas_gcs[zrod], o_true).direction, true_dir)
    )
    errs["loa13"].append(
        angle_between_deg(line_of_action_thesis(meas_gcs[zrod], o_true).direction, true_dir)
    )
    return full.affine


def _triangulation_rate(records: list[ShotRecord], cfg: ArrayConfig, min_timing_s: float) -> float:
    """Step 4: shots triangulated per second (solver only, no serial link), timed over at least
    ``min_timing_s``."""
    import time

    geometry = cfg.geometry()
    counts, bar, avg, status, _ = records_to_arrays(records)
    n_done, t0 = 0, time.perf_counter()
    while True:
        triangulate(counts, bar, geometry, averaging=avg, status=status, limits=cfg.limits())
        n_done += len(records)
        elapsed = time.perf_counter() - t0
        if elapsed >= min_timing_s:
            break
    return n_done / elapsed
