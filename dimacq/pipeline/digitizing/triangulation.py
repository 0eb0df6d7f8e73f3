"""Sonic digitizer triangulation, vectorised over shots (method.md §1, thesis §2).

Per shot ``n`` (all arrays stacked over shots, no Python loop over shots):

1. Speed of sound from the calibration bar, fired ``B`` times, with the fixed delay ``tau_0``::

       t_bar,b = (n_bar,b + 1/2) / f_clk - tau_0,     c = L_bar / median_b(t_bar,b)

   (``+1/2``: a counter value ``n`` means the arrival fell in the period ``[n, n+1)``.)
   The spread ``c (max_b t_bar,b - min_b t_bar,b)`` flags an echo on the bar.
2. Ranges ``d_ek = c ((n_ek / A + 1/2) / f_clk - tau_0)`` for emitter ``e``, microphone ``k``.
3. Emitter position ``p_e = argmin_p Σ_k (|p - m_k| - d_ek)²``, started in closed form: with
   ``w = |p - m̄|²`` and microphones ``q_k = m_k - m̄`` relative to their centroid, each sphere
   ``|p - m_k|² = d_k²`` becomes linear in ``(p - m̄, w)``::

       -2 q_kᵀ (p - m̄) + w = d_k² - |q_k|²

   solved by one precomputed pseudoinverse for all shots (``M ≥ 4`` non-coplanar microphones).
   For a planar array the in-plane coordinates ``a`` and ``w`` come from the same equations written
   in the plane (``M ≥ 3``) and the out-of-plane coordinate is ``h = ±sqrt(w - |a|²)``, the sign
   being the side the array faces (configuration). Then Gauss–Newton on the range residuals
   ``r_k = |p - m_k| - d_k`` with Jacobian rows ``(p - m_k)ᵀ / |p - m_k|``, batched 3 × 3 solves.
4. Tip ``p_tip = p_1 + L_tip (p_1 - p_2) / |p_1 - p_2|``.
5. Quality: a shot is rejected when a status flag is set, the bar spread or the speed of sound is
   implausible, any ``|r_k|`` exceeds ``max_range_residual_m`` or the fitted spacing ``|p_1 - p_2|``
   differs from the known spacing by more than ``spacing_tolerance_m``. An echo makes one path
   look longer: with more microphones than unknowns the fit cannot absorb it (a residual appears)
   and the two emitters no longer sit the known distance apart.

Several shots of one point are combined by :func:`combine_shots` (median, outlier cut, mean).
"""

from __future__ import annotations

import enum
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from dimacq.errors import DataError, SetupError

__all__ = [
    "DigitizerGeometry",
    "PointEstimate",
    "QualityLimits",
    "Reject",
    "ShotSolution",
    "combine_shots",
    "triangulate",
    "trilaterate",
]

FloatArray = NDArray[np.float64]


class Reject(enum.IntFlag):
    """Why a shot was rejected (bit flags; 0 means accepted)."""

    STATUS = 1  #: device status flag (no arrival, fault)
    BAR = 2  #: calibration bar firings disagree (echo on the bar)
    SPEED = 4  #: speed of sound outside the plausible range
    RESIDUAL = 8  #: a range residual too large (echo on a path)
    SPACING = 16  #: fitted emitter spacing differs from the known spacing
    NONFINITE = 32  #: the solve did not give finite numbers


@dataclass(frozen=True)
class QualityLimits:
    """Acceptance limits of a shot (metres, m/s) and the outlier cut of a point."""

    max_range_residual_m: float = 1.0e-3
    spacing_tolerance_m: float = 1.5e-3
    bar_spread_tolerance_m: float = 1.0e-3
    speed_min_m_s: float = 300.0
    speed_max_m_s: float = 380.0
    point_outlier_m: float = 1.0e-3


@dataclass(frozen=True)
class DigitizerGeometry:
    """Array, counter, bar and probe constants.

    Attributes
    ----------
    microphones_m : ndarray, shape (M, 3)
        Microphone positions in the DACS, metres.
    facing : ndarray, shape (3,)
        Side the array faces (used for planar arrays only).
    bar_length_m, delay_s, clock_hz : float
        Calibration bar length, fixed electronic delay ``tau_0``, counter clock.
    emitter_spacing_m, tip_length_m : float
        Probe: emitter 1 to emitter 2, and tip beyond emitter 1.
    """

    microphones_m: FloatArray
    facing: FloatArray = field(default_factory=lambda: np.array([0.0, 0.0, 1.0]))
    bar_length_m: float = 1.0
    delay_s: float = 50e-6
    clock_hz: float = 10e6
    emitter_spacing_m: float = 0.12
    tip_length_m: float = 0.06

    def __post_init__(self) -> None:
        mics = np.asarray(self.microphones_m, dtype=float)
        if mics.ndim != 2 or mics.shape[1] != 3 or mics.shape[0] < 3:
            raise SetupError(
                f"digitizer geometry 'microphones_m' has shape {mics.shape}; "
                "give (M, 3) with M >= 3"
            )
        object.__setattr__(self, "microphones_m", mics)
        facing = np.asarray(self.facing, dtype=float)
        if facing.shape != (3,) or not np.linalg.norm(facing) > 0:
            raise SetupError("digitizer geometry 'facing' must be a non-zero 3-vector")
        object.__setattr__(self, "facing", facing / np.linalg.norm(facing))
        for name in ("bar_length_m", "clock_hz", "emitter_spacing_m"):
            if not getattr(self, name) > 0:
                raise SetupError(f"digitizer geometry '{name}' must be > 0")


@dataclass(frozen=True)
class _Solver:
    """Precomputed closed-form start for one microphone subset."""

    mics: FloatArray  # (M, 3)
    centroid: FloatArray  # (3,)
    planar: bool
    basis: FloatArray  # (2, 3) planar / (3, 3) otherwise
    normal: FloatArray  # (3,)
    local: FloatArray  # (M, 2|3) microphone coordinates relative to centroid, in basis
    pinv: FloatArray  # (3|4, M)


def _solver(mics: FloatArray, facing: FloatArray) -> _Solver:
    centroid = mics.mean(axis=0)
    q = mics - centroid
    _, s, vt = np.linalg.svd(q)
    planar = bool(len(s) < 3 or s[2] <= 1e-9 * s[0])
    if planar:
        basis = vt[:2]
        normal = vt[2] if vt.shape[0] > 2 else np.cross(vt[0], vt[1])
        if normal @ facing < 0:
            normal = -normal
    else:
        if len(mics) < 4:
            raise SetupError("a non-planar array needs at least 4 microphones")
        basis = np.eye(3)
        normal = facing
    local = q @ basis.T
    design = np.hstack([-2.0 * local, np.ones((len(mics), 1))])
    return _Solver(mics, centroid, planar, basis, normal, local, np.linalg.pinv(design))


def trilaterate(
    ranges_m: ArrayLike,
    microphones_m: ArrayLike,
    facing: ArrayLike = (0.0, 0.0, 1.0),
    iterations: int = 4,
) -> tuple[FloatArray, FloatArray]:
    """Positions from ranges to known microphones (closed-form start + Gauss–Newton).

    Parameters
    ----------
    ranges_m : array_like, shape (K, M)
        Ranges ``d_k`` for ``K`` independent problems.
    microphones_m : array_like, shape (M, 3)
    facing : array_like, shape (3,)
        Side a planar array faces.
    iterations : int
        Gauss–Newton iterations.

    Returns
    -------
    p : ndarray, shape (K, 3)
    residual_m : ndarray, shape (K, M)
        ``|p - m_k| - d_k``.
    """
    d = np.asarray(ranges_m, dtype=float)
    mics = np.asarray(microphones_m, dtype=float)
    sv = _solver(mics, np.asarray(facing, dtype=float))
    return _trilaterate(d, sv, iterations)


def _trilaterate(d: FloatArray, sv: _Solver, iterations: int) -> tuple[FloatArray, FloatArray]:
    rhs = d * d - np.einsum("md,md->m", sv.local, sv.local)  # (K, M)
    sol = rhs @ sv.pinv.T  # (K, 3|4)
    if sv.planar:
        a = sol[:, :2]
        h = np.sqrt(np.maximum(sol[:, 2] - np.einsum("kd,kd->k", a, a), 0.0))
        p = sv.centroid + a @ sv.basis + h[:, None] * sv.normal
    else:
        p = sv.centroid + sol[:, :3]
    eye = np.eye(3)
    for _ in range(iterations):
        diff = p[:, None, :] - sv.mics[None, :, :]  # (K, M, 3)
        dist = np.sqrt(np.einsum("kmd,kmd->km", diff, diff))
        jac = diff / dist[..., None]
        r = dist - d
        jtj = np.einsum("kmi,kmj->kij", jac, jac)
        jtr = np.einsum("kmi,km->ki", jac, r)
        jtj += 1e-12 * np.trace(jtj, axis1=1, axis2=2)[:, None, None] * eye
        p = p - np.linalg.solve(jtj, jtr[..., None])[..., 0]
    diff = p[:, None, :] - sv.mics[None, :, :]
    residual = np.sqrt(np.einsum("kmd,kmd->km", diff, diff)) - d
    return p, residual


@dataclass(frozen=True)
class ShotSolution:
    """Triangulated shots with their quality measures (``N`` shots, ``E`` emitters, ``M`` mics).

    Attributes
    ----------
    speed_m_s : ndarray, shape (N,)
        Speed of sound from the bar.
    bar_spread_m : ndarray, shape (N,)
        Spread of the bar firings, as a length.
    emitters_m : ndarray, shape (N, E, 3)
    tip_m : ndarray, shape (N, 3)
        Tip (``E = 2``) or emitter 1 (``E = 1``), DACS metres.
    range_residual_m : ndarray, shape (N, E, M)
    spacing_error_m : ndarray, shape (N,)
        ``|p_1 - p_2| - s`` (0 when ``E = 1``).
    reject : ndarray of int, shape (N,)
        :class:`Reject` flags; 0 for accepted shots.
    """

    speed_m_s: FloatArray
    bar_spread_m: FloatArray
    emitters_m: FloatArray
    tip_m: FloatArray
    range_residual_m: FloatArray
    spacing_error_m: FloatArray
    reject: NDArray[np.int64]

    @property
    def accepted(self) -> NDArray[np.bool_]:
        return np.asarray(self.reject == 0)

    @property
    def n_shots(self) -> int:
        return int(self.reject.shape[0])


def triangulate(
    counts: ArrayLike,
    bar_counts: ArrayLike,
    geometry: DigitizerGeometry,
    *,
    averaging: ArrayLike = 1,
    status: ArrayLike | None = None,
    limits: QualityLimits | None = None,
    iterations: int = 4,
) -> ShotSolution:
    """Triangulate shots from raw counter values (see the module docstring for the equations).

    Parameters
    ----------
    counts : array_like of int, shape (N, E, M)
        Summed counter values per shot, emitter, microphone (the first ``M`` microphones).
    bar_counts : array_like of int, shape (N, B)
        Calibration bar counter values.
    geometry : DigitizerGeometry
    averaging : int or array_like, shape (N,)
        Firings summed into each counter value.
    status : array_like of int, shape (N,), optional
        Device status flags; any non-zero flag rejects the shot.
    limits : QualityLimits, optional

    Returns
    -------
    ShotSolution
    """
    limits = limits or QualityLimits()
    n = np.asarray(counts, dtype=float)
    nb = np.asarray(bar_counts, dtype=float)
    if n.ndim != 3 or nb.ndim != 2 or nb.shape[0] != n.shape[0] or nb.shape[1] < 1:
        raise DataError(
            f"triangulate: 'counts' shape {n.shape} must be (N, E, M) and 'bar_counts' shape "
            f"{nb.shape} must be (N, B) with B >= 1"
        )
    n_shots, n_em, n_mic = n.shape
    if n_em not in (1, 2):
        raise DataError(f"triangulate: 'counts' has {n_em} emitters; the probe has 1 or 2")
    if n_mic > len(geometry.microphones_m) or n_mic < 3:
        raise DataError(
            f"triangulate: 'counts' has {n_mic} microphones; the array has "
            f"{len(geometry.microphones_m)} (need 3..{len(geometry.microphones_m)})"
        )
    avg = np.broadcast_to(np.asarray(averaging, dtype=float), (n_shots,))
    clk, tau0 = geometry.clock_hz, geometry.delay_s

    t_bar = (nb + 0.5) / clk - tau0  # (N, B)
    t_bar_med = np.median(t_bar, axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        c = geometry.bar_length_m / t_bar_med
    bar_spread = c * (t_bar.max(axis=1) - t_bar.min(axis=1))

    t = (n / avg[:, None, None] + 0.5) / clk - tau0
    d = c[:, None, None] * t  # (N, E, M)
    sv = _solver(geometry.microphones_m[:n_mic], geometry.facing)
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        p, res = _trilaterate(d.reshape(-1, n_mic), sv, iterations)
    emitters = p.reshape(n_shots, n_em, 3)
    residual = res.reshape(n_shots, n_em, n_mic)
    if n_em == 2:
        axis = emitters[:, 0] - emitters[:, 1]
        spacing = np.linalg.norm(axis, axis=1)
        with np.errstate(invalid="ignore", divide="ignore"):
            tip = emitters[:, 0] + geometry.tip_length_m * axis / spacing[:, None]
        spacing_error = spacing - geometry.emitter_spacing_m
    else:
        tip = emitters[:, 0].copy()
        spacing_error = np.zeros(n_shots)

    reject = np.zeros(n_shots, dtype=np.int64)
    if status is not None:
        reject |= np.where(np.asarray(status) != 0, int(Reject.STATUS), 0)
    reject |= np.where(~(bar_spread <= limits.bar_spread_tolerance_m), int(Reject.BAR), 0)
    reject |= np.where(
        ~((c >= limits.speed_min_m_s) & (c <= limits.speed_max_m_s)), int(Reject.SPEED), 0
    )
    max_res = np.abs(residual).max(axis=(1, 2))
    reject |= np.where(~(max_res <= limits.max_range_residual_m), int(Reject.RESIDUAL), 0)
    reject |= np.where(
        ~(np.abs(spacing_error) <= limits.spacing_tolerance_m), int(Reject.SPACING), 0
    )
    finite = np.isfinite(tip).all(axis=1) & np.isfinite(emitters).all(axis=(1, 2))
    reject |= np.where(~finite, int(Reject.NONFINITE), 0)
    return ShotSolution(
        speed_m_s=c,
        bar_spread_m=bar_spread,
        emitters_m=emitters,
        tip_m=tip,
        range_residual_m=residual,
        spacing_error_m=spacing_error,
        reject=reject,
    )


@dataclass(frozen=True)
class PointEstimate:
    """One digitized point from several shots.

    Attributes
    ----------
    position_m : ndarray, shape (3,)
        Mean of the shots kept.
    spread_m : ndarray, shape (3,)
        Standard deviation of the kept shots per axis (0 with one shot).
    standard_error_m : float
        RMS radial spread / sqrt(n_used).
    n_shots, n_accepted, n_used : int
        Shots fired, passing the per-shot checks, kept after the outlier cut.
    used : ndarray of bool, shape (n_shots,)
    """

    position_m: FloatArray
    spread_m: FloatArray
    standard_error_m: float
    n_shots: int
    n_accepted: int
    n_used: int
    used: NDArray[np.bool_]


def combine_shots(
    tips_m: ArrayLike, accepted: ArrayLike, outlier_m: float = 1.0e-3
) -> PointEstimate:
    """Robust combination of the shots of one point.

    ``x̃ = median(x_i, accepted)``, keep shots with ``|x_i - x̃| ≤ outlier_m``, return their mean and
    spread.

    Raises
    ------
    DataError
        No shot passed the checks: digitize the point again.
    """
    tips = np.asarray(tips_m, dtype=float).reshape(-1, 3)
    ok = np.asarray(accepted, dtype=bool).reshape(-1)
    if not ok.any():
        raise DataError(
            f"no accepted shot among {len(tips)} for this point (echoes or bad geometry); "
            "digitize it again or move the array"
        )
    med = np.median(tips[ok], axis=0)
    used = ok & (np.linalg.norm(tips - med, axis=1) <= outlier_m)
    if not used.any():
        used = ok
    kept = tips[used]
    mean = kept.mean(axis=0)
    spread = kept.std(axis=0, ddof=1) if len(kept) > 1 else np.zeros(3)
    stderr = float(np.sqrt((spread**2).sum() / len(kept)))
    return PointEstimate(
        position_m=mean,
        spread_m=spread,
        standard_error_m=stderr,
        n_shots=len(tips),
        n_accepted=int(ok.sum()),
        n_used=int(used.sum()),
        used=used,
    )
