"""Uncertainty of a DIM solution: standard error and 95 % interval per parameter.

Two sources are combined:

- **Over inputs** (the dominant, honest one: inputs differ by their impact point, line of action
  and noise). Jackknife: ``SE_J = sqrt((N−1)/N · Σ_j (p_(−j) − p̄)²)`` over the N leave-one-out
  joint solutions (Efron & Tibshirani, ch. 11). Bootstrap: B resamplings of the inputs with
  replacement, done exactly with integer input weights (an input drawn k times enters the
  normal equations k times), ``SE_B`` = standard deviation of the B solutions.
- **Over response sensors** (optional): systems assembled with one sensor node (e.g. a triax) left
  out; the delete-one-group jackknife ``SE_R = sqrt((G−1)/G · Σ_g (p_(−g) − p̄)²)`` carries the
  sensor position and orientation errors that are common to every input and hence invisible to
  the input resampling.
- **Over lines**: ``SE_L = std_l(p_l) / sqrt(n_eff)``; adjacent lines of a smooth FRF are not
  independent, so ``n_eff`` is the number of lines divided by the integrated autocorrelation time
  of the per-line estimates (at least 1 line per effective sample).

The reported standard error is ``sqrt(SE_inputs² + SE_R² + SE_L²)`` (the line spread is largely included
in the input resampling, so this is mildly conservative) and the 95 % interval
``p ± t_{0.975, N−1} · SE`` (Student t with N − 1 degrees of freedom of the input resampling).
"""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray
from scipy import stats

from dimacq.errors import SetupError, SolverError
from dimacq.model.setup import PARAMETERS
from dimacq.pipeline.dim import DimResult, DimSystem, solve_system

__all__ = ["ParameterUncertainty", "Uncertainty", "effective_samples", "estimate_uncertainty"]

log = logging.getLogger(__name__)
FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class ParameterUncertainty:
    """Uncertainty of one parameter (units of the parameter: kg, m, kg·m²)."""

    value: float
    standard_error: float
    ci95: tuple[float, float]
    se_inputs: float
    se_lines: float
    se_responses: float = 0.0

    def to_json(self) -> dict[str, Any]:
        return {
            "value": self.value,
            "standard_error": self.standard_error,
            "ci95": list(self.ci95),
            "se_inputs": self.se_inputs,
            "se_lines": self.se_lines,
            "se_responses": self.se_responses,
        }


@dataclass(frozen=True, eq=False)
class Uncertainty:
    """Per-parameter uncertainty of a DIM solution.

    Attributes
    ----------
    parameters : dict
        ``m, cx, cy, cz`` (CG in the GCS), ``Ixx..Izz`` (about P) → :class:`ParameterUncertainty`.
    method : {"jackknife", "bootstrap"}
    n_inputs : int
    n_lines_effective : float
    samples : ndarray, shape (n_samples, 10)
        The leave-one-out or bootstrap solutions.
    """

    parameters: dict[str, ParameterUncertainty]
    method: str
    n_inputs: int
    n_lines_effective: float
    samples: FloatArray

    def to_json(self) -> dict[str, Any]:
        out: dict[str, Any] = {k: v.to_json() for k, v in self.parameters.items()}
        out["method"] = self.method
        out["n_inputs"] = self.n_inputs
        out["n_lines_effective"] = self.n_lines_effective
        return out


def effective_samples(x: NDArray[np.floating]) -> float:
    """Effective number of independent samples of a series, ``n / τ`` with the integrated
    autocorrelation time ``τ = 1 + 2 Σ_k ρ_k`` summed while ``ρ_k > 0`` (initial positive sequence)."""
    x = np.asarray(x, float)
    x = x[np.isfinite(x)]
    n = x.size
    if n < 3 or np.std(x) == 0:
        return float(max(n, 1))
    d = x - x.mean()
    ac = np.correlate(d, d, mode="full")[n - 1 :] / (d @ d)
    tau = 1.0
    for k in range(1, n):
        if ac[k] <= 0:
            break
        tau += 2 * ac[k]
    return float(max(1.0, n / tau))


def estimate_uncertainty(
    system: DimSystem,
    result: DimResult,
    *,
    known: Mapping[str, float] | None = None,
    method: Literal["jackknife", "bootstrap"] = "jackknife",
    n_bootstrap: int = 200,
    seed: int | None = 0,
    response_systems: Sequence[DimSystem] = (),
) -> Uncertainty:
    """Standard error and 95 % interval of every parameter of ``result`` (module docstring).

    Parameters
    ----------
    system : DimSystem
        The system ``result`` was solved from (same inputs and lines).
    result : DimResult
    known : dict, optional
        Known properties used for ``result`` (their uncertainty is 0).
    method : {"jackknife", "bootstrap"}
    n_bootstrap : int
    seed : int, optional
        Seed of the bootstrap resampling.
    response_systems : sequence of DimSystem, optional
        The same test assembled with one response node left out each (delete-one-group
        jackknife over sensors); empty: no sensor term.
    """
    n_in = system.K.shape[2]
    if n_in < 3:
        raise SetupError(
            f"{n_in} inputs are too few to estimate an uncertainty over inputs; give 3 or more"
        )
    samples: list[FloatArray] = []
    if method == "jackknife":
        for j in range(n_in):
            w = np.ones(n_in)
            w[j] = 0.0
            try:
                samples.append(
                    solve_system(
                        system, known=known, input_weights=w, check_plausibility=False
                    ).parameters
                )
            except SolverError:
                log.info("leave-one-out without input %s is rank deficient", system.inputs[j].name)
        s = np.array(samples).reshape(-1, 10)
        n = s.shape[0]
        se_in = (
            np.sqrt((n - 1) / n * np.sum((s - s.mean(axis=0)) ** 2, axis=0))
            if n > 1
            else np.zeros(10)
        )
    elif method == "bootstrap":
        rng = np.random.default_rng(seed)
        for _ in range(n_bootstrap):
            w = np.bincount(rng.integers(0, n_in, n_in), minlength=n_in).astype(float)
            try:
                samples.append(
                    solve_system(
                        system, known=known, input_weights=w, check_plausibility=False
                    ).parameters
                )
            except SolverError:
                continue
        s = np.array(samples).reshape(-1, 10)
        se_in = s.std(axis=0, ddof=1) if s.shape[0] > 1 else np.zeros(10)
    else:
        raise SetupError(
            f"uncertainty method {method!r} is unknown; use 'jackknife' or 'bootstrap'"
        )
    pl = result.per_line
    finite = pl[np.all(np.isfinite(pl), axis=1)]
    n_eff = (
        float(np.median([effective_samples(finite[:, k]) for k in range(10)]))
        if finite.shape[0] > 2
        else 1.0
    )
    se_l = finite.std(axis=0, ddof=1) / np.sqrt(n_eff) if finite.shape[0] > 1 else np.zeros(10)
    rs: list[FloatArray] = []
    for sy in response_systems:
        try:
            rs.append(solve_system(sy, known=known, check_plausibility=False).parameters)
        except SolverError:
            continue
    se_r = np.zeros(10)
    if len(rs) > 1:
        r_arr = np.array(rs)
        g = r_arr.shape[0]
        se_r = np.sqrt((g - 1) / g * np.sum((r_arr - r_arr.mean(axis=0)) ** 2, axis=0))
    se = np.sqrt(se_in**2 + se_r**2 + se_l**2)
    for k in known or {}:
        se[PARAMETERS.index(k)] = 0.0
    tq = float(stats.t.ppf(0.975, max(n_in - 1, 1)))
    p = result.parameters
    params = {
        name: ParameterUncertainty(
            float(p[i]),
            float(se[i]),
            (float(p[i] - tq * se[i]), float(p[i] + tq * se[i])),
            float(se_in[i]),
            float(se_l[i]),
            float(se_r[i]),
        )
        for i, name in enumerate(PARAMETERS)
    }
    return Uncertainty(params, method, n_in, n_eff, s)
