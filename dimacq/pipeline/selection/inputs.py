"""Jackknife excitation selection and the excitation check (thesis §3.1, Eq. 16, Table 14).

Excitation check (Eq. 16)
-------------------------
For the unit 6-DOF force vectors of the inputs at P, ``Φ = [φ_1 … φ_N]`` (6 × N, forces in N/N,
moments in N·m/N), the autopower ``G = Φ Φᵀ`` (6 × 6): its diagonal says how strongly each of
Fx, Fy, Fz, Mx, My, Mz is excited; the rank and singular values of Φ say whether every
rigid-body DOF is excited (rank < 6: a DOF is not excited and DIM cannot be solved).

Jackknife cycles (§3.1)
-----------------------
One cycle over the N active inputs: solve DIM N times, each with one input left out, giving
``p_(−j)`` (10 parameters). With the jackknife mean ``p̄``, the deviation ``|p_(−j) − p̄|`` of each
parameter is scaled to a maximum of 1 over j and summed over the parameters: the scaled-deviation
sum ``S_j`` (thesis Fig. 11). The cycle also records the jackknife standard deviation of each
parameter (thesis Fig. 12) and, for each input, its *predictive residual*
``ρ_j = ‖A_j x_(−j) − b_j‖ / ‖b_j‖`` — how badly the input's own equations (Eq. 34) are met by the
solution from the other inputs (rows scaled by their RMS over all inputs, so that forces and
moments count alike).

Which input a cycle removes, and when to stop (needs no known answer)
--------------------------------------------------------------------
The thesis removes the input with the largest scaled-deviation sum and notes that the jackknife
standard deviation alone does not always show when to stop. The scaled-deviation sum measures an
input's *influence* on the parameters, which is leverage times inconsistency: a badly struck input
in a well-covered direction (low leverage) moves the parameters less than a good input that alone
excites some DOF, so the sum can point at a good input while a bad one stays in (seen on an
X-38-like vehicle: the bad impact had 15× the median predictive residual but the second-largest
sum, the good input with the largest sum passed the stop rule, and the cycle stopped with the bad
impact kept). Candidate and stop therefore use one statistic, each input's consistency with the
rigid-body model fitted to the others:

- the predictive residual ``ρ_j`` (above), the misfit of input j's measured force and the motion
  it caused under the parameters of the other inputs;
- corrected for leverage: for least squares the in-sample residual ``e_j`` and the predictive one
  ``e_(−j)`` obey ``e_(−j) = (1 − h_j)⁻¹ e_j``, and the externally studentised residual is
  ``e_(−j) √(1 − h_j) = √(e_j · e_(−j))``. With the in-sample residual ``r_j`` of the fit to every
  active input (same row scaling), the statistic is ``t_j = √(r_j ρ_j)``: an input that alone
  excites a direction (large ``h_j``) is not penalised for the extrapolation of the others.

The candidate is the input with the largest ``t_j`` whose removal keeps the excitation rank 6 (a
removal dropping the rank is refused and recorded). The removal is *justified* when ``t_j`` is an
outlier of the other active inputs' statistics (above ``ratio`` times their median and their median
plus ``z`` robust standard deviations, :func:`~dimacq.pipeline.selection._common.robust_outlier`):
the other inputs' spread is the data's own noise-and-geometry level. The chosen cycle is the number
of leading justified removals; clean data lose nothing. The scaled-deviation sums and jackknife
standard deviations are still computed every cycle (thesis Figs. 11–12). Cycles continue past the
chosen one for the history (figures), to a limit.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from dimacq.errors import SetupError, SolverError
from dimacq.model.frf import Channel
from dimacq.model.setup import PARAMETERS
from dimacq.pipeline.dim import DimSystem, solve_joint, solve_joint_many
from dimacq.pipeline.selection._common import robust_outlier

__all__ = [
    "ExcitationCheck",
    "JackknifeCycle",
    "JackknifeSelection",
    "PredictiveResiduals",
    "excitation_check",
    "jackknife_estimates",
    "jackknife_inputs",
    "predictive_residuals",
]

log = logging.getLogger(__name__)
FloatArray = NDArray[np.float64]
_DOF = ("Fx", "Fy", "Fz", "Mx", "My", "Mz")


@dataclass(frozen=True)
class ExcitationCheck:
    """Eq. 16: rank, autopower diagonal and singular values of the inputs' 6-DOF force vectors.

    Attributes
    ----------
    rank : int
    autopower : ndarray, shape (6,)
        ``diag(Φ Φᵀ)`` for Fx, Fy, Fz, Mx, My, Mz (moments in metres).
    singular_values : ndarray, shape (6,)
        Of Φ, descending (zeros when fewer than 6 inputs).
    ok : bool
        Rank 6.
    weakest : str
        The DOF with the smallest autopower.
    n_inputs : int
    """

    rank: int
    autopower: FloatArray
    singular_values: FloatArray
    ok: bool
    weakest: str
    n_inputs: int

    def to_json(self) -> dict[str, Any]:
        return {
            "rank": self.rank,
            "autopower": dict(zip(_DOF, map(float, self.autopower), strict=True)),
            "singular_values": [float(s) for s in self.singular_values],
            "ok": self.ok,
            "weakest": self.weakest,
            "n_inputs": self.n_inputs,
        }


def excitation_check(phi_m: NDArray[np.floating], rtol: float = 1e-6) -> ExcitationCheck:
    """Excitation check of Eq. 16.

    Parameters
    ----------
    phi_m : ndarray, shape (6, n_inputs)
        Unit force vectors at P, forces in N/N and moments in N·m/N (metres).
    rtol : float
        A singular value below ``rtol · σ_max`` counts as zero.
    """
    phi = np.asarray(phi_m, float)
    if phi.ndim != 2 or phi.shape[0] != 6:
        raise SetupError(f"phi has shape {phi.shape}; give the (6, n_inputs) unit force vectors")
    G = phi @ phi.T
    s = np.zeros(6)
    if phi.shape[1]:
        sv = np.linalg.svd(phi, compute_uv=False)
        s[: sv.size] = sv[:6]
    rank = int(np.sum(s > rtol * s.max(initial=0.0))) if s.max(initial=0.0) > 0 else 0
    diag = np.diag(G).copy()
    return ExcitationCheck(rank, diag, s, rank == 6, _DOF[int(np.argmin(diag))], phi.shape[1])


def _phi_m(system: DimSystem) -> FloatArray:
    phi = system.phi.copy()
    phi[3:] *= system.unit_m
    return phi


def _x_working(params: FloatArray, system: DimSystem) -> FloatArray:
    """[m, CG (GCS, m), I about P (kg·m²)] → x = [m, s, I] in the working unit (shape (..., 10))."""
    u = system.unit_m
    x = np.empty_like(params)
    x[..., 0] = params[..., 0]
    x[..., 1:4] = params[..., :1] * (params[..., 1:4] - system.reference_point_m) / u
    x[..., 4:] = params[..., 4:] / u**2
    return x


def predictive_residuals(system: DimSystem, params: FloatArray) -> FloatArray:
    """Relative residual of each input's equations for given parameters.

    Parameters
    ----------
    system : DimSystem
    params : ndarray, shape (10,) or (n_inputs, 10)
        One parameter set for all inputs, or one per input (e.g. its leave-one-out solution).

    Returns
    -------
    ndarray, shape (n_inputs,)
        ``sqrt(mean_{lines, rows} |(A_j x − b_j)_r / s_r|²)`` with ``s_r`` the RMS of row r of b
        over lines and inputs.
    """
    return PredictiveResiduals(system)(params)


class PredictiveResiduals:
    """:func:`predictive_residuals` of one system for several parameter sets: the motions,
    right sides and row scales are laid out once (the jackknife asks twice a cycle).

    ``A(a, α) x`` (:func:`dimacq.pipeline.dim.design_matrices`, Eq. 33) is formed from the
    motions directly, ``[m a + α × s; s × a + I α]`` with ``s = m c`` and ``I`` the symmetric
    tensor of ``x[4:]``, instead of through the (L, J, 6, 10) design matrices (30 MB on an
    acquired test, formed three times by the jackknife's cycles): the same products, summed in
    another order (the residuals agree to rounding, 1e-16 relative)."""

    def __init__(self, system: DimSystem) -> None:
        self.system = system
        k = np.moveaxis(system.K, -1, -2)  # (L, J, 6)
        self.a, self.al = k[..., :3], k[..., 3:]
        self.b = np.moveaxis(system.F, -1, -2)  # (L, J, 6)
        s = np.sqrt(np.mean(np.abs(self.b) ** 2, axis=(0, 1)))
        self.s = np.where(s > 0, s, 1.0)

    def predict(self, x: FloatArray) -> NDArray[np.complexfloating]:
        """``A(a, α) x`` for ``x`` (10,) or one per input (J, 10): (L, J, 6)."""
        a0, a1, a2 = self.a[..., 0], self.a[..., 1], self.a[..., 2]
        w0, w1, w2 = self.al[..., 0], self.al[..., 1], self.al[..., 2]
        m, s0, s1, s2 = x[..., 0], x[..., 1], x[..., 2], x[..., 3]
        ixx, ixy, ixz, iyy, iyz, izz = (x[..., k] for k in range(4, 10))
        out = np.empty(self.a.shape[:-1] + (6,), dtype=np.result_type(self.a, x))
        out[..., 0] = m * a0 + (w1 * s2 - w2 * s1)
        out[..., 1] = m * a1 + (w2 * s0 - w0 * s2)
        out[..., 2] = m * a2 + (w0 * s1 - w1 * s0)
        out[..., 3] = (s1 * a2 - s2 * a1) + (ixx * w0 + ixy * w1 + ixz * w2)
        out[..., 4] = (s2 * a0 - s0 * a2) + (ixy * w0 + iyy * w1 + iyz * w2)
        out[..., 5] = (s0 * a1 - s1 * a0) + (ixz * w0 + iyz * w1 + izz * w2)
        return out

    def __call__(self, params: FloatArray) -> FloatArray:
        b, s = self.b, self.s
        x = _x_working(np.asarray(params, float), self.system)
        r = self.predict(x) - b
        # r · (1/s): numpy divides a complex by a real number as (re·(1/s), im·(1/s))
        out: FloatArray = np.sqrt(np.mean(np.abs(r * (1.0 / s)) ** 2, axis=(0, 2)))
        return out


def jackknife_estimates(
    system: DimSystem,
    active: NDArray[np.bool_],
    *,
    known: Mapping[str, float] | None = None,
) -> tuple[FloatArray, NDArray[np.bool_]]:
    """Leave-one-out joint solutions over the active inputs.

    Returns
    -------
    estimates : ndarray, shape (n_inputs, 10)
        ``p_(−j)`` for every active input j (NaN rows for inactive inputs or rank-deficient solves).
    solved : ndarray of bool, shape (n_inputs,)
    """
    n = system.K.shape[2]
    est = np.full((n, 10), np.nan)
    ok = np.zeros(n, dtype=bool)
    idx = np.nonzero(active)[0]
    if idx.size:
        # only the joint answers, all from the inputs' band sums (dim.solve_joint_many)
        w = np.broadcast_to(np.asarray(active, float), (idx.size, n)).copy()
        w[np.arange(idx.size), idx] = 0.0
        est[idx], ok[idx] = solve_joint_many(system, w, known=known)
    return est, ok


@dataclass(frozen=True, eq=False)
class JackknifeCycle:
    """One jackknife cycle.

    Attributes
    ----------
    active : ndarray of bool, shape (n_inputs,)
        Inputs in play during this cycle.
    estimates : ndarray, shape (n_inputs, 10)
        Leave-one-out solutions (NaN for inactive inputs).
    scaled_deviation : ndarray, shape (n_inputs, 10)
        ``|p_(−j) − p̄| / max_j |p_(−j) − p̄|`` per parameter.
    score : ndarray, shape (n_inputs,)
        Scaled-deviation sum ``S_j`` (NaN for inactive inputs).
    std : ndarray, shape (10,)
        Jackknife standard deviation of each parameter over the leave-one-out solutions.
    residual : ndarray, shape (n_inputs,)
        Predictive residual ``ρ_j``.
    statistic : ndarray, shape (n_inputs,)
        Leverage-corrected (studentised) predictive residual ``t_j = √(r_j ρ_j)``, the statistic
        that picks the candidate and decides the removal (NaN for inactive inputs).
    removed : int or None
        Index of the input removed at the end of this cycle.
    justified : bool
        Whether that removal passed the outlier rule.
    median_others, threshold : float
    refused : tuple of int
        Candidates refused by the excitation check (rank would drop below 6).
    excitation : ExcitationCheck
        Of the active inputs after the removal.
    """

    active: NDArray[np.bool_]
    estimates: FloatArray
    scaled_deviation: FloatArray
    score: FloatArray
    std: FloatArray
    residual: FloatArray
    removed: int | None
    justified: bool
    median_others: float
    threshold: float
    refused: tuple[int, ...]
    excitation: ExcitationCheck
    statistic: FloatArray | None = None


@dataclass(frozen=True, eq=False)
class JackknifeSelection:
    """Outcome of the jackknife excitation selection.

    Attributes
    ----------
    inputs : tuple of Channel
    keep : ndarray of bool, shape (n_inputs,)
        Inputs kept at the chosen cycle.
    excluded : tuple of Channel
        Removed (in order) plus the forced-out ones.
    cycles : tuple of JackknifeCycle
        The full history (may run past the chosen cycle).
    chosen_cycle : int
        Number of automatic removals accepted.
    stop_reason : str
    excitation : ExcitationCheck
        Of the kept inputs.
    """

    inputs: tuple[Channel, ...]
    keep: NDArray[np.bool_]
    excluded: tuple[Channel, ...]
    reasons: dict[str, str]
    cycles: tuple[JackknifeCycle, ...]
    chosen_cycle: int
    stop_reason: str
    excitation: ExcitationCheck

    @property
    def std_history(self) -> FloatArray:
        """Jackknife standard deviations per cycle, shape (n_cycles, 10)."""
        return np.array([c.std for c in self.cycles]).reshape(-1, 10)

    def to_json(self) -> dict[str, Any]:
        return {
            "excluded": [c.as_dict() for c in self.excluded],
            "reasons": dict(self.reasons),
            "chosen_cycle": self.chosen_cycle,
            "stop_reason": self.stop_reason,
            "excitation_check": self.excitation.to_json(),
            "cycles": [
                {
                    "n_active": int(c.active.sum()),
                    "removed": None if c.removed is None else self.inputs[c.removed].as_dict(),
                    "justified": c.justified,
                    "residual_removed": None if c.removed is None else float(c.residual[c.removed]),
                    "statistic_removed": None
                    if c.removed is None or c.statistic is None
                    else float(c.statistic[c.removed]),
                    "median_others": c.median_others,
                    "threshold": c.threshold,
                    "refused": [self.inputs[i].as_dict() for i in c.refused],
                    "std": dict(zip(PARAMETERS, map(float, c.std), strict=True)),
                }
                for c in self.cycles
            ],
        }


def _cycle_statistics(
    system: DimSystem, active: NDArray[np.bool_], known: Mapping[str, float] | None
) -> (
    tuple[FloatArray, NDArray[np.intp], FloatArray, FloatArray, FloatArray, FloatArray, FloatArray]
    | None
):
    """One jackknife cycle's statistics over the active inputs (None: fewer than 3 solved).

    Scaled deviations ``|x₋ⱼ − x̄| / max_j |x₋ⱼ − x̄|`` and their sum per input; the
    predictive residual ``e_j`` of each input under the fit without it, studentised as
    ``√(e_j(x₋ⱼ) e_j(x))`` with ``x`` the joint fit over all active inputs.

    Returns
    -------
    est, idx, sdev, score, std, resid, stat
    """
    n = system.K.shape[2]
    est, solved = jackknife_estimates(system, active, known=known)
    idx = np.nonzero(active & solved)[0]
    if idx.size < 3:
        return None
    mean = est[idx].mean(axis=0)
    dev = np.abs(est - mean)
    mx = np.nanmax(dev[idx], axis=0)
    sdev = dev / np.where(mx > 0, mx, 1.0)
    score = np.where(active & solved, np.nansum(sdev, axis=1), np.nan)
    std = est[idx].std(axis=0, ddof=1)
    resid = np.full(n, np.nan)
    pred = PredictiveResiduals(system.select_inputs(idx))
    resid[idx] = pred(est[idx])
    stat = resid.copy()
    try:
        full = solve_joint(system, known=known, input_weights=active.astype(float))
        stat[idx] = np.sqrt(resid[idx] * pred(full))
    except SolverError:  # pragma: no cover - the active inputs excite rank 6 (checked)
        pass
    return est, idx, sdev, score, std, resid, stat


def _candidate(
    phi: FloatArray,
    active: NDArray[np.bool_],
    fin: NDArray[np.bool_],
    idx: NDArray[np.intp],
    stat: FloatArray,
    can_remove: bool,
) -> tuple[int | None, ExcitationCheck, list[int]]:
    """The input with the largest studentised predictive residual whose removal keeps rank 6.

    Returns
    -------
    removed : int or None
    after : ExcitationCheck
        The excitation without it (with every active input when none).
    refused : list of int
        Inputs passed over because their removal would drop the rank below 6.
    """
    refused: list[int] = []
    removed: int | None = None
    after = excitation_check(phi[:, active])
    if can_remove:
        for j in idx[np.argsort(stat[idx])[::-1]]:
            if fin[j]:
                continue
            trial = active.copy()
            trial[j] = False
            chk_j = excitation_check(phi[:, trial])
            if not chk_j.ok:
                refused.append(int(j))
                continue
            removed, after = int(j), chk_j
            break
    return removed, after, refused


def _selection(
    system: DimSystem,
    phi: FloatArray,
    fout: NDArray[np.bool_],
    removed_order: list[int],
    chosen: int,
    reasons: dict[str, str],
    cycles: list[JackknifeCycle],
    stop: str,
) -> JackknifeSelection:
    """The kept inputs: all but the forced-out and the first ``chosen`` removed, with reasons."""
    keep = ~fout
    for j in removed_order[:chosen]:
        keep[j] = False
    excluded = [system.inputs[i] for i in np.nonzero(fout)[0]] + [
        system.inputs[j] for j in removed_order[:chosen]
    ]
    return JackknifeSelection(
        inputs=system.inputs,
        keep=keep,
        excluded=tuple(excluded),
        reasons={k: v for k, v in reasons.items() if any(c.name == k for c in excluded)},
        cycles=tuple(cycles),
        chosen_cycle=chosen,
        stop_reason=stop,
        excitation=excitation_check(phi[:, keep]),
    )


def jackknife_inputs(
    system: DimSystem,
    *,
    known: Mapping[str, float] | None = None,
    force_in: NDArray[np.bool_] | None = None,
    force_out: NDArray[np.bool_] | None = None,
    ratio: float = 3.0,
    z: float = 6.0,
    min_inputs: int = 8,
    max_removals: int | None = None,
    extra_cycles: int = 2,
) -> JackknifeSelection:
    """Jackknife excitation selection with automatic cycle choice (module docstring).

    Parameters
    ----------
    system : DimSystem
        Assembled over the analysis band (responses already selected).
    known : dict, optional
        Known properties, passed to every solve.
    force_in, force_out : ndarray of bool, shape (n_inputs,), optional
        Inputs the user keeps / drops whatever the jackknife says.
    ratio, z : float
        Outlier rule on the studentised predictive residual of the candidate.
    min_inputs : int
        Never go below this many inputs.
    max_removals : int, optional
        Default: a third of the inputs.
    extra_cycles : int
        Cycles recorded past the chosen one (history for the figures).
    """
    n = system.K.shape[2]
    fin = np.zeros(n, bool) if force_in is None else np.asarray(force_in, bool)
    fout = np.zeros(n, bool) if force_out is None else np.asarray(force_out, bool)
    if np.any(fin & fout):
        c = system.inputs[int(np.argmax(fin & fout))]
        raise SetupError(f"input {c.name} is both forced in and forced out; choose one")
    phi = _phi_m(system)
    active = ~fout
    chk = excitation_check(phi[:, active])
    if not chk.ok:
        raise SolverError(
            f"the inputs excite rank {chk.rank} < 6 (weakest {chk.weakest}); add inputs that "
            "excite every force and moment, or force fewer out"
        )
    limit = n // 3 if max_removals is None else max_removals
    cycles: list[JackknifeCycle] = []
    chosen: int | None = None
    stop = ""
    removed_order: list[int] = []
    reasons: dict[str, str] = {
        system.inputs[i].name: "forced out by the user" for i in np.nonzero(fout)[0]
    }
    while True:
        stats = _cycle_statistics(system, active, known)
        if stats is None:
            stop = stop or "too few inputs for a jackknife cycle"
            break
        est, idx, sdev, score, std, resid, stat = stats
        can_remove = int(active.sum()) - 1 >= min_inputs and len(removed_order) < limit
        removed, after, refused = _candidate(phi, active, fin, idx, stat, can_remove)
        justified, med, thr = False, float("nan"), float("nan")
        if removed is not None:
            others = idx[idx != removed]
            justified, med, thr = robust_outlier(
                float(stat[removed]), stat[others], ratio=ratio, z=z
            )
        cycles.append(
            JackknifeCycle(
                active.copy(),
                est,
                sdev,
                score,
                std,
                resid,
                removed,
                justified,
                med,
                thr,
                tuple(refused),
                after,
                stat,
            )
        )
        if removed is None:
            if not stop:
                stop = (
                    "every candidate removal would drop the excitation rank below 6"
                    if refused
                    else f"reached the limit (at least {min_inputs} inputs, at most {limit} removals)"
                )
            break
        if chosen is None and not justified:
            chosen = len(removed_order)
            stop = (
                f"cycle {chosen}: the least consistent input {system.inputs[removed].name} has "
                f"studentised predictive residual {stat[removed]:.3g}, within the spread of the "
                f"others (median {med:.3g}, threshold {thr:.3g})"
            )
        if chosen is not None and len(cycles) - chosen > extra_cycles:
            break
        if chosen is None:
            reasons[system.inputs[removed].name] = (
                f"jackknife cycle {len(removed_order) + 1}: its force and the motion it caused "
                f"disagree with the rigid body fitted to the other inputs: studentised predictive "
                f"residual {stat[removed]:.3g} > threshold {thr:.3g} (median of the others "
                f"{med:.3g}; scaled-deviation sum {score[removed]:.3g})"
            )
        removed_order.append(removed)
        active = active.copy()
        active[removed] = False
    if chosen is None:
        chosen = len(removed_order)
    return _selection(system, phi, fout, removed_order, chosen, reasons, cycles, stop)
