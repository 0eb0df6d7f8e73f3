"""Pre-test planning service (``dimacq plan``): choose the triaxes and inputs of a test from a
candidate setup, predict the 95 % bounds of mass, CG and principal moments, and check the
prediction by a Monte Carlo of real solves distributed with Dask.

The numerical core is :mod:`dimacq.pipeline.planning` (information of a layout, greedy + exchange
selection, the simulated test of a layout). This module orchestrates it:

1. the candidates and the error model from the setup file (its ``[geometry_uncertainty]`` and
   ``[transducer_uncertainty]``) and the FRF noise level;
2. the layout, its predicted bounds, observability, the error budget per source, what one more
   triax or input buys, and the median bounds of random layouts of the same size;
3. the Monte Carlo: ``trials`` simulated tests of the layout (model FRFs of the true — perturbed —
   geometry, with noise), each solved by the default ``dimacq solve``
   (:func:`dimacq.services.solve.analysis.analyse`); the 95 % bounds of the errors and the coverage of
   the solve's own 95 % intervals.

Trial ``i`` draws from ``SeedSequence(seed, spawn_key=(i,))`` (``SeedSequence(seed).spawn(n)[i]``):
the answer does not depend on where or in which order the trials run (in-process, a LocalCluster,
a remote scheduler). Numbers in the JSON are rounded to 6 significant digits.
"""

from __future__ import annotations

import logging
import os
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Literal, cast

import numpy as np

from dimacq.errors import DimacqError, SetupError
from dimacq.model.frf import Channel, FrfData
from dimacq.model.properties import RigidBodyProperties
from dimacq.model.setup import KnownProperties, TestSetup
from dimacq.pipeline import planning as pl

__all__ = [
    "DEFAULT_LINES",
    "DEFAULT_NOISE",
    "TRIAL_COLUMNS",
    "TrialSpec",
    "layout_setup",
    "make_plan",
    "run_trial",
    "run_trial_batch",
    "run_trials",
    "trial_batches",
]

log = logging.getLogger(__name__)

#: FRF noise relative to each FRF's RMS (``dimacq simulate --noise``; the README's accuracy table).
DEFAULT_NOISE = 0.01
#: Lines of the simulated FRFs (20–100 Hz every 2 Hz) and of the information.
DEFAULT_LINES = 41
#: Largest batch of Monte Carlo trials in one Dask task (:func:`run_trial_batch`).
BATCH_MAX = 25
#: Random layouts whose median bounds the plan is compared with.
N_RANDOM = 200
#: Columns of a trial's row: errors, whether the solve's 95 % interval holds the truth, verdict.
TRIAL_COLUMNS = (
    "mass_pct",
    "cx_mm",
    "cy_mm",
    "cz_mm",
    "pm1_pct",
    "pm2_pct",
    "pm3_pct",
    "in_m",
    "in_cx",
    "in_cy",
    "in_cz",
    "in_pm1",
    "in_pm2",
    "in_pm3",
    "verdict",  # 0 ok, 1 warn, 2 fail, 3 error (no answer)
)
_VERDICT = {"ok": 0, "warn": 1, "fail": 2}

ProgressFn = Callable[[int, int, float], None]


def _round(v: Any) -> Any:
    """6 significant digits, recursively (identical JSON wherever the trials ran)."""
    if isinstance(v, float):
        return float(f"{v:.6g}") if np.isfinite(v) else None
    if isinstance(v, dict):
        return {k: _round(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_round(x) for x in v]
    return v


def layout_setup(setup: TestSetup, cand: pl.Candidates, layout: pl.Layout) -> TestSetup:
    """The setup of a layout: its triaxes' channels and its inputs; no load cells (the plan's
    model is the free-free rigid body) and nothing known."""
    nodes = {cand.nodes[t] for t in layout.triaxes}
    return setup.model_copy(
        update={
            "name": f"{setup.name} plan".strip(),
            "responses": tuple(c for c in setup.responses if c.node in nodes),
            "excitations": tuple(setup.excitations[j] for j in layout.inputs),
            "load_cells": (),
            "known": KnownProperties(),
        }
    )


@dataclass(frozen=True)
class TrialSpec:
    """Everything one Monte Carlo trial needs (pickled once to the workers)."""

    candidates: pl.Candidates
    layout: pl.Layout
    setup: TestSetup
    properties: RigidBodyProperties
    errors: pl.ErrorModel
    seed: int


def run_trial(spec: TrialSpec, index: int) -> list[float]:
    """One simulated test of the layout solved by the default ``dimacq solve``; a row of
    :data:`TRIAL_COLUMNS` (NaN errors and verdict 3 when the solve gave no answer)."""
    from dimacq.services.solve.analysis import AnalysisOptions, analyse

    rng = np.random.default_rng(np.random.SeedSequence(spec.seed, spawn_key=(index,)))
    n_lines = spec.errors.n_lines
    H, ch = pl.simulated_frf(
        spec.candidates, spec.layout, spec.properties, spec.errors, n_lines, rng
    )
    setup = spec.setup
    kinds = cast(
        tuple[Literal["acceleration", "reaction"], ...], ("acceleration",) * len(setup.responses)
    )
    frf = FrfData(
        np.asarray(20.0 + 2.0 * np.arange(n_lines), dtype=np.float64),
        H,
        tuple(Channel(c.node, c.direction) for c in setup.responses),
        kinds,
        tuple(Channel(e.node, e.direction) for e in setup.excitations),
        meta={"source": f"dimacq plan trial {index}"},
    )
    assert len(ch) == len(setup.responses)
    try:
        report = analyse(frf, setup, AnalysisOptions())
    except DimacqError as exc:
        log.warning("plan trial %d: no answer (%s)", index, exc)
        return [float("nan")] * 14 + [3.0]
    res = report.result
    est = np.concatenate([[res.properties.mass_kg], res.properties.cg_m, res.parameters[4:]])
    err = pl.trial_errors(est, spec.properties, res.reference_point_m)
    unc = report.uncertainty
    truth_p = np.linalg.eigvalsh(spec.properties.inertia_cg_kgm2)
    inside = []
    for k, name in enumerate(("m", "cx", "cy", "cz")):
        lo, hi = unc.parameters[name].ci95
        t = spec.properties.mass_kg if k == 0 else spec.properties.cg_m[k - 1]
        inside.append(float(lo <= t <= hi))
    for k in range(3):
        if len(unc.principal) == 3:
            lo, hi = unc.principal[k].ci95
            inside.append(float(lo <= truth_p[k] <= hi))
        else:
            inside.append(float("nan"))
    return [*map(float, err), *inside, float(_VERDICT.get(report.verdict, 3))]


def run_trial_batch(spec: TrialSpec, indices: list[int]) -> list[list[float]]:
    """Rows of :func:`run_trial` for several trials: one Dask task for a batch of trials, so
    that the scheduler's per-task cost (a few ms and a message each way) is paid per batch."""
    return [run_trial(spec, i) for i in indices]


def trial_batches(n_trials: int, workers: int) -> list[list[int]]:
    """Consecutive trial indices in batches: about 8 per worker so that the progress and the
    load stay even, at most :data:`BATCH_MAX` trials each."""
    size = max(1, min(BATCH_MAX, n_trials // max(8 * workers, 1)))
    return [list(range(i, min(i + size, n_trials))) for i in range(0, n_trials, size)]


def _check_scheduler(scheduler: str | None, workers: int) -> None:
    """Refuse a ``--scheduler`` / ``--workers`` pair :func:`run_trials` cannot use, before any
    work (the layout search of :func:`make_plan` takes seconds)."""
    if scheduler is None or scheduler == "none" or workers == 0:
        return
    if scheduler == "local":
        if workers < 1:
            raise SetupError(f"--workers {workers}: give 1 or more (0 runs in-process)")
    elif "://" not in scheduler:
        raise SetupError(
            f"--scheduler {scheduler!r}: give local, none or a scheduler address (tcp://host:8786)"
        )


def run_trials(
    spec: TrialSpec,
    n_trials: int,
    *,
    scheduler: str | None = "local",
    workers: int = 2,
    progress: ProgressFn | None = None,
) -> np.ndarray:
    """Rows of :func:`run_trial` for trials ``0 .. n_trials − 1``, in trial order.

    ``scheduler``: ``None`` or ``"none"`` (or ``workers == 0``) runs in this process; ``"local"``
    starts a Dask LocalCluster of ``workers`` single-threaded worker processes; an address
    (``tcp://host:8786``) uses that scheduler. ``progress(done, total, seconds_left)`` is called
    after each trial in-process, after each batch of trials (:func:`trial_batches`) on Dask.
    """
    if n_trials < 1:
        raise SetupError(f"--trials {n_trials}: give at least 1 trial")
    _check_scheduler(scheduler, workers)
    t0 = time.perf_counter()
    rows: list[list[float] | None] = [None] * n_trials

    def tick(done: int) -> None:
        if progress is not None:
            el = time.perf_counter() - t0
            progress(done, n_trials, el / done * (n_trials - done))

    if scheduler in (None, "none") or workers == 0:
        for i in range(n_trials):
            rows[i] = run_trial(spec, i)
            tick(i + 1)
        return np.asarray(rows, dtype=float)
    import dask
    from dask.distributed import Client, LocalCluster, as_completed

    # distributed logs every connection at INFO on stderr, in this process and in the workers it
    # spawns (they read the config from the environment), and at shutdown on a loaded machine a
    # worker's last heartbeat may find the scheduler gone (a traceback at ERROR): keep stderr
    # for the progress. A failing trial still raises here, through its future.
    os.environ.setdefault("DASK_LOGGING__DISTRIBUTED", "critical")
    dask.config.set({"logging.distributed": "critical"})
    logging.getLogger("distributed").setLevel(logging.CRITICAL)
    cluster = None
    try:
        if scheduler == "local":
            cluster = LocalCluster(
                n_workers=workers,
                threads_per_worker=1,
                processes=True,
                dashboard_address=None,
                # no dashboard, yet the scheduler's HTTP server binds 8787 by default: taken by
                # another cluster on this PC it warns and moves; a free loopback port instead
                scheduler_kwargs={"dashboard_address": "127.0.0.1:0"},
                silence_logs=logging.ERROR,
            )
            client = Client(cluster)
        else:  # an address (_check_scheduler)
            try:
                client = Client(scheduler, timeout=30)
            except OSError as err:
                raise SetupError(
                    f"--scheduler {scheduler}: cannot reach the Dask scheduler ({err}); start one "
                    "(dask scheduler; dask worker ADDRESS) or use --scheduler local"
                ) from err
        with client:
            [spec_f] = client.scatter([spec], broadcast=True)
            batches = trial_batches(n_trials, workers if scheduler == "local" else 8)
            futures = client.map(run_trial_batch, [spec_f] * len(batches), batches, pure=False)
            index = {f.key: b for f, b in zip(futures, batches, strict=True)}
            done = 0
            for fut in as_completed(futures):
                for i, row in zip(index[fut.key], fut.result(), strict=True):
                    rows[i] = row
                done += len(index[fut.key])
                tick(done)
    finally:
        if cluster is not None:
            cluster.close()
    return np.asarray(rows, dtype=float)


def _bounds_json(b: pl.Bounds) -> dict[str, Any]:
    return {**b.to_json(), "sigma": b.sigma}


def make_plan(
    setup: TestSetup,
    props: RigidBodyProperties,
    n_triaxes: int,
    n_inputs: int,
    *,
    noise: float = DEFAULT_NOISE,
    n_lines: int = DEFAULT_LINES,
    noise_model: str = "channel",
    trials: int = 0,
    seed: int = 0,
    scheduler: str | None = "local",
    workers: int = 2,
    progress: ProgressFn | None = None,
    n_random: int = N_RANDOM,
) -> dict[str, Any]:
    """The plan as the JSON of ``dimacq plan`` (keys in the README's "Planning" section)."""
    if trials > 0:
        _check_scheduler(scheduler, workers)
    cand = pl.candidates_from_setup(setup)
    errors = pl.ErrorModel.from_setup(setup, noise=noise, n_lines=n_lines, noise_model=noise_model)
    model = pl.build_model(cand, props, errors)
    layout = pl.exchange_select(model, n_triaxes, n_inputs)
    cov = pl.layout_covariance(model, layout)
    predicted = pl.predicted_bounds(model, cov)

    # random layouts of the same size
    rand = [
        pl.predicted_bounds(model, pl.layout_covariance(model, lay))
        for lay in pl.random_layouts(
            cand.n_triaxes, cand.n_inputs, n_triaxes, n_inputs, n_random, seed
        )
    ]
    random_median = {
        k: float(np.median([getattr(b, k) for b in rand]))
        for k in ("mass_pct", "cg_mm", "principal_pct")
    }

    # error budget: each source left out in turn
    budget: dict[str, Any] = {}
    for src in pl.SOURCES:
        m2 = model.with_errors(errors.without(src))
        b2 = pl.predicted_bounds(m2, pl.layout_covariance(m2, layout))
        budget[src] = {
            "without": b2.to_json(),
            "share_pct": {
                k: 100 * (1 - (getattr(b2, k) / getattr(predicted, k)) ** 2)
                if getattr(predicted, k) > 0
                else 0.0
                for k in ("mass_pct", "cg_mm", "principal_pct")
            },
        }

    # what the layout controls: the same without the hammer's common scale (layout-independent)
    m_nf = model.with_errors(errors.without("force_gain"))
    pred_nf = pl.predicted_bounds(m_nf, pl.layout_covariance(m_nf, layout))
    rand_nf = [
        pl.predicted_bounds(m_nf, pl.layout_covariance(m_nf, lay))
        for lay in pl.random_layouts(
            cand.n_triaxes, cand.n_inputs, n_triaxes, n_inputs, n_random, seed
        )
    ]
    med_nf = {
        k: float(np.median([getattr(b, k) for b in rand_nf]))
        for k in ("mass_pct", "cg_mm", "principal_pct")
    }
    layout_part = {
        "predicted": pred_nf.to_json(),
        "random_median": med_nf,
        "factor_over_random": {
            k: med_nf[k] / v if v > 0 else None for k, v in pred_nf.to_json().items()
        },
        "note": "the hammer's sensitivity (force_gain) left out: a common scale of m and I that "
        "no layout changes",
    }

    out: dict[str, Any] = {
        "layout": layout.to_json(cand),
        "predicted": _bounds_json(predicted),
        "random_median": random_median,
        "factor_over_random": {
            k: random_median[k] / v if v > 0 else None for k, v in predicted.to_json().items()
        },
        "layout_controlled": layout_part,
        "observability": pl.observability(model, layout),
        "error_budget": budget,
        "one_more": _one_more(model, layout, predicted),
        "candidates": {"triaxes": cand.n_triaxes, "inputs": cand.n_inputs},
        "error_model": errors.to_json(),
        "model": "free-free rigid body from the expected properties; FRF noise on every line "
        "(noise_model channel: the level times the RMS of the strike's FRFs over every candidate "
        "channel; relative: times each FRF's own magnitude); nuisances (triax position/rotation, channel gains, input point "
        "and line of action) with the setup's stated uncertainties as priors; the hammer's "
        "sensitivity as a common scale of m and I. Bounds: 95 % quantiles of |mass error|, of the "
        "largest |CG component error| and of the largest |principal moment error|.",
        "request": {"triaxes": n_triaxes, "inputs": n_inputs, "seed": seed, "trials": trials},
    }
    if trials > 0:
        spec = TrialSpec(cand, layout, layout_setup(setup, cand, layout), props, errors, seed)
        rows = run_trials(spec, trials, scheduler=scheduler, workers=workers, progress=progress)
        out["monte_carlo"] = _mc_summary(rows, predicted)
    return _round(out)


def _one_more(model: pl.PlanModel, layout: pl.Layout, now: pl.Bounds) -> dict[str, Any]:
    """The best single triax and the best single input to add, and the bounds with it."""
    cand = model.candidates
    out: dict[str, Any] = {}
    for kind in ("triax", "input"):
        pool = cand.n_triaxes if kind == "triax" else cand.n_inputs
        have = layout.triaxes if kind == "triax" else layout.inputs
        best: tuple[float, int, pl.Layout] | None = None
        for i in range(pool):
            if i in have:
                continue
            lay = (
                pl.Layout(tuple(sorted((*have, i))), layout.inputs)
                if kind == "triax"
                else pl.Layout(layout.triaxes, tuple(sorted((*have, i))))
            )
            c = pl.criterion(model, lay)
            if best is None or c < best[0]:
                best = (c, i, lay)
        if best is None:
            out[kind] = None
            continue
        b = pl.predicted_bounds(model, pl.layout_covariance(model, best[2]))
        node = cand.nodes[best[1]] if kind == "triax" else cand.input_nodes[best[1]][0]
        out[kind] = {
            "node": int(node),
            "predicted": b.to_json(),
            "gain_pct": {
                k: 100 * (1 - getattr(b, k) / getattr(now, k)) if getattr(now, k) > 0 else 0.0
                for k in ("mass_pct", "cg_mm", "principal_pct")
            },
        }
    return out


def _mc_summary(rows: np.ndarray, predicted: pl.Bounds) -> dict[str, Any]:
    ok = rows[:, 14] < 3
    err = rows[ok, :7]
    emp = pl.empirical_bounds(err)
    inside = rows[ok, 7:14]
    with np.errstate(invalid="ignore"):
        cov = {
            "mass": float(np.nanmean(inside[:, 0])) if inside.size else float("nan"),
            "cg": float(np.nanmean(inside[:, 1:4])) if inside.size else float("nan"),
            "principal": float(np.nanmean(inside[:, 4:7])) if inside.size else float("nan"),
        }
    v = rows[:, 14]
    return {
        "n_trials": int(rows.shape[0]),
        "n_solved": int(ok.sum()),
        "bounds": emp,
        "ratio_to_predicted": {
            k: emp[k] / getattr(predicted, k) if getattr(predicted, k) > 0 else None
            for k in ("mass_pct", "cg_mm", "principal_pct")
        },
        "coverage": cov,
        "within_predicted": {
            "mass_pct": float(np.mean(np.abs(err[:, 0]) <= predicted.mass_pct)),
            "cg_mm": float(np.mean(np.abs(err[:, 1:4]).max(axis=1) <= predicted.cg_mm)),
            "principal_pct": float(
                np.mean(np.abs(err[:, 4:7]).max(axis=1) <= predicted.principal_pct)
            ),
        }
        if err.size
        else None,
        "verdicts": {
            "ok": int(np.sum(v == 0)),
            "warn": int(np.sum(v == 1)),
            "fail": int(np.sum(v == 2)),
            "error": int(np.sum(v == 3)),
        },
        "rms": {
            "mass_pct": float(np.sqrt(np.mean(err[:, 0] ** 2))) if err.size else None,
            "cg_mm": float(np.sqrt(np.mean(err[:, 1:4] ** 2))) if err.size else None,
            "principal_pct": float(np.sqrt(np.mean(err[:, 4:7] ** 2))) if err.size else None,
        },
    }
