"""Perimeter response selection (thesis Eq. 30–31, Figs. 21–22, 39–40; method.md §4).

Rigid-body fit error
--------------------
With Ψ (n_ch × 6) the rigid-body shape matrix and a 0/1 weight W on the active channels, the
filtered responses are ``q_f = Ψ (WΨ)⁺ W q_m`` (Eq. 30) and the thesis's error of channel i is
``ε_i = |q_m,i − q_f,i| / |q_f,i|`` (Eq. 31). A channel that is itself wrong pulls the fit towards
it, which hides it and smears its error over the others. We therefore rank channels by the
*leave-one-out* (predicted) error, computed without refitting from the hat matrix
``h = diag(Ψ_S (Ψ_Sᵀ Ψ_S)⁻¹ Ψ_Sᵀ)`` of the active set S (the classic PRESS identity):

    e_i^(−i) = r_i / (1 − h_ii),    r = (I − Ψ_S Ψ_S⁺) q_S,
    ε_i = ‖e_i^(−i)‖ / ‖q_m,i − e_i^(−i)‖

with norms over the inputs for one line (per-line error) or over lines and inputs (band error).
A channel with ``h_ii → 1`` is the only one seeing some rigid-body motion: it cannot be tested,
nor removed (the rank would drop).

Automatic stopping rule (needs no known answer)
-----------------------------------------------
Each step takes the active, removable channel with the largest band error and asks whether it is
an outlier *of the other active channels' errors*. The reference is a "clean core" fit that
leaves out the candidate and the provisional suspects (active channels above twice the median
error; a forward-search idea), so that neither the candidate nor a second bad channel inflates the
reference spread; the candidate's error is its prediction from that core. It must exceed ``ratio`` times their median and
their median plus ``z`` robust standard deviations (1.4826·MAD, floored at 5 % of the median). If
it is not, the selection stops: the remaining channels agree with rigid-body motion as well as
each other. Guards on every removal: the active set keeps rank 6, at least ``min_per_direction``
channels with ``|d_k| ≥ 0.5`` per global direction k, and a condition number of the
length-normalised Ψ below ``max(cond_limit, cond_growth · initial)``.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from dimacq.errors import SetupError
from dimacq.model.frf import Channel, FrfData
from dimacq.model.setup import TestSetup
from dimacq.pipeline._batched import real_apply
from dimacq.pipeline.rigid_body import response_matrix
from dimacq.pipeline.selection._common import (
    ResponseGeometry,
    match_pairs,
    response_geometry,
    robust_outlier,
)

__all__ = [
    "ResponseErrors",
    "ResponseSelection",
    "ResponseStep",
    "rigid_body_errors",
    "select_responses",
    "select_responses_frf",
]

log = logging.getLogger(__name__)
FloatArray = NDArray[np.float64]


@dataclass(frozen=True, eq=False)
class ResponseErrors:
    """Rigid-body fit errors of every channel for one active set.

    Attributes
    ----------
    loo_band : ndarray, shape (n_ch,)
        Leave-one-out error over the band (the prediction of an inactive channel from the active
        set; ``inf`` for an active channel that cannot be predicted, ``h_ii ≈ 1``).
    eq31_band : ndarray, shape (n_ch,)
        The thesis's in-sample error ``|q_m − q_f| / |q_f|`` (Eq. 31) over the band.
    loo_per_line : ndarray, shape (n_lines, n_ch)
    eq31_per_line : ndarray, shape (n_lines, n_ch)
    leverage : ndarray, shape (n_ch,)
        ``h_ii`` of active channels (NaN for inactive).
    """

    loo_band: FloatArray
    eq31_band: FloatArray
    loo_per_line: FloatArray
    eq31_per_line: FloatArray
    leverage: FloatArray


def _norm_psi(psi: FloatArray) -> FloatArray:
    """Ψ with its rotational columns scaled by the RMS lever arm (unit-independent conditioning)."""
    rot = np.linalg.norm(psi[:, 3:], axis=1)
    L = float(np.sqrt(np.mean(rot**2))) if np.any(rot > 0) else 1.0
    out = psi.copy()
    out[:, 3:] /= L if L > 0 else 1.0
    return out


def rigid_body_errors(
    psi: NDArray[np.floating], q: NDArray[np.complexfloating], active: NDArray[np.bool_]
) -> ResponseErrors:
    """Leave-one-out and Eq. 31 rigid-body errors per channel, per line and over the band.

    Parameters
    ----------
    psi : ndarray, shape (n_ch, 6)
        Rigid-body shape matrix (rows ``[dᵀ, (r × d)ᵀ]``).
    q : ndarray, shape (n_lines, n_ch, n_inputs), complex
        Measured accelerances of the channels.
    active : ndarray of bool, shape (n_ch,)
        Channels used for the fit (W = diag(active)).
    """
    psi_n = _norm_psi(np.asarray(psi, float))
    q = np.asarray(q)
    act = np.asarray(active, bool)
    S = np.nonzero(act)[0]
    pS = psi_n[S]
    pinv = np.linalg.pinv(pS)  # (6, nS)
    every = S.size == psi_n.shape[0]  # every channel active: no gathered copies of q and r
    K = real_apply(pinv, q if every else q[:, S, :])
    qf = real_apply(psi_n, K)  # fit / prediction for all channels
    r = q - qf
    h = np.full(psi_n.shape[0], np.nan)
    h[S] = np.einsum("sk,ks->s", pS, pinv)
    testable = np.ones(psi_n.shape[0], dtype=bool)
    with np.errstate(divide="ignore", invalid="ignore"):
        hs = h[S]
        ok = hs < 1.0 - 1e-8
        testable[S] = ok
        loo = np.where(
            ok[None, :, None], (r if every else r[:, S, :]) / (1.0 - hs)[None, :, None], np.nan
        )
        if every:
            e = loo
        else:
            e = r.copy()
            e[:, S, :] = loo
        pred = q - e
        num_l = np.sum(np.abs(e) ** 2, axis=2)
        loo_l = np.sqrt(num_l / np.sum(np.abs(pred) ** 2, axis=2))
        loo_b = np.sqrt(np.sum(num_l, axis=0) / np.sum(np.abs(pred) ** 2, axis=(0, 2)))
        r2 = np.sum(np.abs(r) ** 2, axis=2)
        f2 = np.sum(np.abs(qf) ** 2, axis=2)
        eq_l = np.sqrt(r2 / f2)
        eq_b = np.sqrt(np.sum(r2, axis=0) / np.sum(f2, axis=0))
    loo_b = np.where(testable, loo_b, np.inf)
    return ResponseErrors(loo_b, eq_b, loo_l, eq_l, h)


@dataclass(frozen=True)
class ResponseStep:
    """One removal (or the final refusal) of the automatic selection."""

    channel: Channel
    error: float
    median_others: float
    threshold: float
    removed: bool
    reason: str

    def as_dict(self) -> dict[str, Any]:
        return {
            "node": self.channel.node,
            "direction": self.channel.direction,
            "error": self.error,
            "median_others": self.median_others,
            "threshold": self.threshold,
            "removed": self.removed,
            "reason": self.reason,
        }


@dataclass(frozen=True, eq=False)
class ResponseSelection:
    """Outcome of the perimeter response selection.

    Attributes
    ----------
    channels : tuple of Channel
        All accelerometer channels, in FRF order.
    keep : ndarray of bool, shape (n_ch,)
    excluded : tuple of Channel
        Removed automatically or forced out, in order of removal.
    reasons : dict
        Channel name → why it was excluded.
    initial, final : ResponseErrors
        Errors with all (not forced-out) channels, and with the kept set.
    steps : tuple of ResponseStep
    stop_reason : str
    condition_initial, condition_final : float
        Condition number of the length-normalised Ψ.
    per_direction : dict
        Global axis → number of kept channels with ``|d_k| ≥ 0.5``.
    frequencies_hz : ndarray, shape (n_lines,), optional
        Lines of the per-line errors (set by :func:`select_responses_frf`).
    """

    channels: tuple[Channel, ...]
    keep: NDArray[np.bool_]
    excluded: tuple[Channel, ...]
    reasons: dict[str, str]
    initial: ResponseErrors
    final: ResponseErrors
    steps: tuple[ResponseStep, ...]
    stop_reason: str
    condition_initial: float
    condition_final: float
    per_direction: dict[str, int] = field(default_factory=dict)
    frequencies_hz: FloatArray | None = None

    @property
    def weights(self) -> FloatArray:
        """0/1 weights for :func:`dimacq.pipeline.dim.assemble` ``response_weights``."""
        return self.keep.astype(float)

    def to_json(self) -> dict[str, Any]:
        return {
            "excluded": [c.as_dict() for c in self.excluded],
            "reasons": dict(self.reasons),
            "stop_reason": self.stop_reason,
            "steps": [s.as_dict() for s in self.steps],
            "condition_initial": self.condition_initial,
            "condition_final": self.condition_final,
            "per_direction": dict(self.per_direction),
            "band_error_loo": {
                c.name: float(e) for c, e in zip(self.channels, self.final.loo_band, strict=True)
            },
        }


def _guards(
    psi_n: FloatArray,
    dirs: FloatArray,
    active: NDArray[np.bool_],
    min_per_direction: int,
    cond_max: float,
) -> tuple[bool, str, float]:
    S = np.nonzero(active)[0]
    s = np.linalg.svd(psi_n[S], compute_uv=False)
    if s.size < 6 or s[-1] <= s[0] * 1e-10:
        return False, "removal would leave rank < 6", np.inf
    cond = float(s[0] / s[5])
    counts = np.sum(np.abs(dirs[S]) >= 0.5, axis=0)
    if np.any(counts < min_per_direction):
        ax = "XYZ"[int(np.argmin(counts))]
        return False, f"removal would leave {int(counts.min())} channels along {ax}", cond
    if cond > cond_max:
        return (
            False,
            f"removal would raise the condition number to {cond:.3g} > {cond_max:.3g}",
            cond,
        )
    return True, "", cond


def _checked_forces(
    psi: FloatArray,
    q: NDArray[np.complexfloating],
    channels: tuple[Channel, ...],
    force_in: NDArray[np.bool_] | None,
    force_out: NDArray[np.bool_] | None,
) -> tuple[NDArray[np.bool_], NDArray[np.bool_]]:
    """The forced-in and forced-out masks (n_ch,), after checking that the shapes agree and no
    channel is both."""
    n = psi.shape[0]
    if psi.shape != (n, 6) or q.shape[1] != n or len(channels) != n:
        raise SetupError(
            f"psi {psi.shape}, q {q.shape} and {len(channels)} channels do not match; "
            "give one Ψ row and one FRF row per channel"
        )
    fin = np.zeros(n, bool) if force_in is None else np.asarray(force_in, bool)
    fout = np.zeros(n, bool) if force_out is None else np.asarray(force_out, bool)
    if np.any(fin & fout):
        c = channels[int(np.argmax(fin & fout))]
        raise SetupError(f"channel {c.name} is both forced in and forced out; choose one")
    return fin, fout


def _core_error(
    psi: FloatArray,
    q: NDArray[np.complexfloating],
    psi_n: FloatArray,
    dirs: FloatArray,
    active: NDArray[np.bool_],
    trial: NDArray[np.bool_],
    errs: ResponseErrors,
    i: int,
) -> tuple[float, FloatArray]:
    """Candidate ``i``'s error predicted from a clean core, and the core channels' errors.

    The core leaves out the candidate (``trial``) and the provisional suspects (active channels
    above 2× the median error, at most a third of the channels), so that neither the candidate
    nor a second bad channel inflates the reference spread. A core that fails the rank guard
    keeps the suspects; one that still fails falls back to the current errors.
    """
    n = psi.shape[0]
    act_idx = np.nonzero(active)[0]
    med_all = float(np.median(errs.loo_band[act_idx][np.isfinite(errs.loo_band[act_idx])]))
    suspects = act_idx[errs.loo_band[act_idx] > 2.0 * med_all]
    suspects = suspects[np.argsort(errs.loo_band[suspects])[::-1]][: max(n // 3, 1)]
    core = trial.copy()
    core[suspects] = False
    if not _guards(psi_n, dirs, core, 0, np.inf)[0]:
        core = trial
    if _guards(psi_n, dirs, core, 0, np.inf)[0]:
        e_core = rigid_body_errors(psi, q, core).loo_band
        e_cand = float(e_core[i])
    else:
        e_core, e_cand = errs.loo_band, float(errs.loo_band[i])
    return e_cand, e_core[np.nonzero(core)[0]]


def _remove_outliers(
    psi: FloatArray,
    q: NDArray[np.complexfloating],
    channels: tuple[Channel, ...],
    active: NDArray[np.bool_],
    fin: NDArray[np.bool_],
    errs: ResponseErrors,
    excluded: list[Channel],
    reasons: dict[str, str],
    *,
    ratio: float,
    z: float,
    min_per_direction: int,
    cond_max: float,
    limit: int,
) -> tuple[NDArray[np.bool_], ResponseErrors, list[ResponseStep], str]:
    """The stopping rule of the module docstring, one removal at a time.

    Tests the removable active channels worst first against their clean core
    (:func:`_core_error`, :func:`~dimacq.pipeline.selection._common.robust_outlier`); an
    outlier that a guard needs is kept and the next one tried. Appends to ``excluded`` and
    ``reasons``; returns the kept set, its errors, the steps and why the selection stopped.
    """
    psi_n = _norm_psi(psi)
    dirs: FloatArray = psi[:, :3]
    steps: list[ResponseStep] = []
    stop = "no channel to test"
    n_removed = 0
    while True:
        if n_removed >= limit:
            stop = f"reached the removal limit ({limit} channels)"
            break
        cand = np.nonzero(active & ~fin & np.isfinite(errs.loo_band))[0]
        if cand.size == 0:
            stop = "no removable channel left"
            break
        order = cand[np.argsort(errs.loo_band[cand])[::-1]]
        removed_now = False
        for i in order:
            trial = active.copy()
            trial[i] = False
            e_cand, others = _core_error(psi, q, psi_n, dirs, active, trial, errs, i)
            out, med, thr = robust_outlier(e_cand, others, ratio=ratio, z=z)
            if not out:
                stop = (
                    f"worst remaining channel {channels[i].name} has error {e_cand:.3g}, "
                    f"within the spread of the others (median {med:.3g}, threshold {thr:.3g})"
                )
                steps.append(ResponseStep(channels[i], e_cand, med, thr, False, stop))
                break
            ok, why, _cond = _guards(psi_n, dirs, trial, min_per_direction, cond_max)
            if not ok:
                steps.append(ResponseStep(channels[i], e_cand, med, thr, False, "kept: " + why))
                log.info("channel %s is an outlier but kept: %s", channels[i].name, why)
                continue
            active = trial
            n_removed += 1
            excluded.append(channels[i])
            msg = (
                f"rigid-body error {e_cand:.3g} > threshold {thr:.3g} "
                f"(median of the others {med:.3g})"
            )
            reasons[channels[i].name] = msg
            steps.append(ResponseStep(channels[i], e_cand, med, thr, True, msg))
            log.info("removed channel %s: %s", channels[i].name, msg)
            errs = rigid_body_errors(psi, q, active)
            removed_now = True
            break
        if not removed_now:
            if not steps or steps[-1].removed or steps[-1].reason.startswith("kept"):
                stop = "every outlier channel is needed by a guard"
            break
    return active, errs, steps, stop


def select_responses(
    psi: NDArray[np.floating],
    q: NDArray[np.complexfloating],
    channels: tuple[Channel, ...],
    *,
    force_in: NDArray[np.bool_] | None = None,
    force_out: NDArray[np.bool_] | None = None,
    ratio: float = 4.0,
    z: float = 8.0,
    min_per_direction: int = 3,
    cond_limit: float = 100.0,
    cond_growth: float = 3.0,
    max_removals: int | None = None,
) -> ResponseSelection:
    """Iteratively remove channels that do not move rigidly with the rest (module docstring).

    Parameters
    ----------
    psi : ndarray, shape (n_ch, 6)
    q : ndarray, shape (n_lines, n_ch, n_inputs), complex
        Accelerances of the channels in the analysis band.
    channels : tuple of Channel, length n_ch
    force_in, force_out : ndarray of bool, shape (n_ch,), optional
        Channels the user keeps whatever their error, or drops whatever their error.
    ratio, z : float
        Outlier rule (see :func:`~dimacq.pipeline.selection._common.robust_outlier`).
    min_per_direction : int
        Channels per global direction that must remain (thesis: 3).
    cond_limit, cond_growth : float
        A removal may not raise cond(Ψ) above ``max(cond_limit, cond_growth · cond_initial)``.
    max_removals : int, optional
        Default: a third of the channels.
    """
    psi_f: FloatArray = np.asarray(psi, dtype=np.float64)
    psi = psi_f
    n = psi.shape[0]
    fin, fout = _checked_forces(psi, q, channels, force_in, force_out)
    psi_n = _norm_psi(psi_f)
    dirs: FloatArray = psi_f[:, :3]
    active = ~fout
    excluded: list[Channel] = [channels[i] for i in np.nonzero(fout)[0]]
    reasons = {channels[i].name: "forced out by the user" for i in np.nonzero(fout)[0]}
    ok, why, cond0 = _guards(psi_n, dirs, active, 0, np.inf)
    if not ok:
        raise SetupError(f"the response set after the forced-out channels is unusable: {why}")
    initial = rigid_body_errors(psi, q, active)
    active, errs, steps, stop = _remove_outliers(
        psi,
        q,
        channels,
        active,
        fin,
        initial,
        excluded,
        reasons,
        ratio=ratio,
        z=z,
        min_per_direction=min_per_direction,
        cond_max=max(cond_limit, cond_growth * cond0),
        limit=n // 3 if max_removals is None else max_removals,
    )
    _, _, cond_f = _guards(psi_n, dirs, active, 0, np.inf)
    counts = np.sum(np.abs(dirs[active]) >= 0.5, axis=0)
    return ResponseSelection(
        channels=tuple(channels),
        keep=active,
        excluded=tuple(excluded),
        reasons=reasons,
        initial=initial,
        final=errs,
        steps=tuple(steps),
        stop_reason=stop,
        condition_initial=cond0,
        condition_final=cond_f,
        per_direction={ax: int(c) for ax, c in zip("XYZ", counts, strict=True)},
    )


def select_responses_frf(
    frf: FrfData,
    setup: TestSetup,
    *,
    band_hz: tuple[float, float] | None = None,
    force_in: list[tuple[int, int]] | None = None,
    force_out: list[tuple[int, int]] | None = None,
    **kwargs: Any,
) -> tuple[ResponseSelection, ResponseGeometry]:
    """:func:`select_responses` on the accelerometer FRFs of a test, matched to its setup.

    ``force_in`` / ``force_out`` name channels by (node, UFF direction); either sign matches.
    Returns the selection and the matched geometry (whose ``output_index`` maps back to the FRF).
    """
    data = frf.band(*band_hz) if band_hz is not None else frf
    geo = response_geometry(data, setup)
    psi = response_matrix(geo.positions_m, geo.directions, setup.reference_point)
    q = data.H[:, geo.output_index, :]
    sel = select_responses(
        psi,
        q,
        geo.channels,
        force_in=match_pairs(force_in, geo.channels),
        force_out=match_pairs(force_out, geo.channels),
        **kwargs,
    )
    return replace(sel, frequencies_hz=data.frequencies_hz), geo
