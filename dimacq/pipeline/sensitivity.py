"""Monte Carlo sensitivity of DIM to geometry errors (thesis §2.2, Eq. 14–15, Tables 2–13).

Model (free-free rigid body, frequency independent; method.md §6): with the 6×6 rigid-body mass
matrix ``M`` about P and the *true* unit input force vectors ``Φ_t`` (6 × N), the motion of P per
unit input is ``K_t = M⁻¹ Φ_t`` (accelerance of a free rigid body). Channels with the *true*
directions and positions measure ``q = Ψ_t K_t``. The analyst uses the *nominal* geometry:
``K̂ = Ψ_n⁺ q`` and forces ``Φ_n``, and solves the DIM equations ``A(K̂_j) x = φ_n,j`` stacked over
the inputs (Eq. 33–35) for ``x = [m, s, I6]``. Trials differ only in the random geometry errors:

- sensor rotations: angles ``θx, θy, θz`` uniform within ±max, transformation ``O_T`` of Eq. 15
  (``O_T = (R_z(θz) R_y(θy) R_x(θx))ᵀ``) applied about the sensor's local axes, ``C' = C O_T``
  (Eq. 14 with the rotation expressed in the sensor frame; identical for GCS-aligned sensors);
- sensor position errors: each coordinate uniform within ±max;
- line-of-action errors: the input direction rotated like a sensor axis (uniform angles within ±max
  about x, y, z);
- input position errors: each coordinate uniform within ±max.

Studies above 20 000 trials run in chunks with seeds spawned from the given one (bounded memory);
at most 1 000 000 trials. Everything is vectorised over trials: the stacked design matrices of all trials are solved at once
by batched SVD (least squares, as robust as the per-trial solve for the ill-conditioned 200 m cube).

The thesis cube (Tables 2–5): 8 triaxes at ``(±H, ±H, ±H)`` (H = 0.01, 1, 100 m for its 0.02 m,
2 m and 200 m cubes), aligned with the GCS, six unit forces and moments at the origin, the
calibration mass properties (method.md §9) about the origin.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from dimacq.errors import SetupError
from dimacq.model.properties import (
    THESIS_CALIBRATION_MASS,
    THESIS_CALIBRATION_MASS_INERTIA_ORIGIN_KGM2,
    inertia_to_vector,
)
from dimacq.model.setup import PARAMETERS
from dimacq.pipeline.dim import design_matrices
from dimacq.pipeline.rigid_body import skew

__all__ = [
    "CALIBRATION_MASS",
    "CUBE_CORNERS",
    "SensitivityResult",
    "cube_model",
    "cube_study",
    "mass_matrix",
    "monte_carlo",
    "random_rotations",
    "solve_trials",
]

FloatArray = NDArray[np.float64]

#: Thesis calibration mass about the GCS origin: m (kg), CG (m), [Ixx, Ixy, Ixz, Iyy, Iyz, Izz] (kg·m²).
CALIBRATION_MASS: dict[str, Any] = {
    "mass_kg": THESIS_CALIBRATION_MASS.mass_kg,
    "cg_m": tuple(THESIS_CALIBRATION_MASS.cg_m.tolist()),
    "inertia_origin_kgm2": tuple(
        inertia_to_vector(THESIS_CALIBRATION_MASS_INERTIA_ORIGIN_KGM2).tolist()
    ),
}

#: Largest study accepted, and trials solved per vectorised chunk (bounds the memory).
MAX_TRIALS = 1_000_000
_CHUNK = 20_000

#: Names of the parameters in the JSON of the study: the ten parameter names of ``known`` and
#: ``uncertainty`` (m in kg, CG in m, inertia about P in kg·m²).
JSON_KEYS = PARAMETERS
#: Units of the parameters (``study.units`` in the JSON).
UNITS = {"m": "kg", "cx": "m", "cy": "m", "cz": "m"} | dict.fromkeys(PARAMETERS[4:], "kg m^2")


def mass_matrix(mass: float, cg: FloatArray, i6: FloatArray) -> FloatArray:
    """Rigid-body mass matrix ``[[m E, −m[c]x], [m[c]x, I]]`` (6, 6) from the mass, the CG and
    the six inertia components ``(Ixx, Ixy, Ixz, Iyy, Iyz, Izz)``."""
    I = np.array([[i6[0], i6[1], i6[2]], [i6[1], i6[3], i6[4]], [i6[2], i6[4], i6[5]]])
    M = np.zeros((6, 6))
    M[:3, :3] = mass * np.eye(3)
    M[:3, 3:] = -mass * skew(cg)
    M[3:, :3] = mass * skew(cg)
    M[3:, 3:] = I
    return M


def random_rotations(
    n_trials: int, n: int, max_angle_deg: float, rng: np.random.Generator
) -> FloatArray:
    """``O_T`` of Eq. 15 for angles uniform within ±max about x, y, z; shape (n_trials, n, 3, 3)."""
    ang = rng.uniform(-max_angle_deg, max_angle_deg, size=(n_trials * n, 3))
    # O_T = (Rz(θz) Ry(θy) Rx(θx))ᵀ; scipy "ZYX" intrinsic = Rz Ry Rx
    R = Rotation.from_euler("ZYX", ang[:, ::-1], degrees=True).as_matrix()
    return np.swapaxes(R, -1, -2).reshape(n_trials, n, 3, 3)


def solve_trials(K: FloatArray, phi: FloatArray) -> FloatArray:
    """Batched DIM least squares for many trials of a frequency-independent model.

    Parameters
    ----------
    K : ndarray, shape (n_trials, 6, n_inputs)
        Estimated ``[a; α]`` per unit input.
    phi : ndarray, shape (n_trials, 6, n_inputs) or (6, n_inputs)
        Nominal force vectors used by the analyst.

    Returns
    -------
    ndarray, shape (n_trials, 10)
        ``[m, cx, cy, cz, Ixx, Ixy, Ixz, Iyy, Iyz, Izz]`` (CG relative to P, inertia about P).
    """
    T = K.shape[0]
    A = design_matrices(K).reshape(T, -1, 10)  # (T, 6N, 10)
    b = np.broadcast_to(np.swapaxes(phi, -1, -2), (T, K.shape[2], 6)).reshape(T, -1)
    d = np.linalg.norm(A, axis=1)  # column equilibration
    d = np.where(d > 0, d, 1.0)
    x = (np.linalg.pinv(A / d[:, None, :], rcond=1e-13) @ b[..., None])[..., 0] / d
    out = x.copy()
    with np.errstate(divide="ignore", invalid="ignore"):
        out[:, 1:4] = x[:, 1:4] / x[:, :1]
    return out


@dataclass(frozen=True, eq=False)
class SensitivityResult:
    """Monte Carlo estimates and their statistics.

    Attributes
    ----------
    samples : ndarray, shape (n_trials, 10)
    truth : ndarray, shape (10,)
    stats : dict
        Per parameter (keys of :data:`JSON_KEYS`): ``min``, ``max``, ``mean``, ``std``,
        ``actual``, ``mean_error_pct`` (``|mean − actual| / |actual| · 100``, as the thesis tables).
    description : dict
    """

    samples: FloatArray
    truth: FloatArray
    stats: dict[str, dict[str, float]]
    description: dict[str, Any] = field(default_factory=dict)

    def to_json(self) -> dict[str, Any]:
        """Per parameter name its statistics, and ``study`` (the description and the units).
        ``mass_kg`` repeats ``m``: scripts read that key."""
        out: dict[str, Any] = {k: dict(v) for k, v in self.stats.items()}
        out["mass_kg"] = dict(self.stats["m"])
        out["study"] = {**self.description, "units": dict(UNITS)}
        return out


def _stats(samples: FloatArray, truth: FloatArray) -> dict[str, dict[str, float]]:
    out: dict[str, dict[str, float]] = {}
    with np.errstate(invalid="ignore"):
        for k, key in enumerate(JSON_KEYS):
            col = samples[:, k]
            col = col[np.isfinite(col)]
            mean = float(col.mean()) if col.size else float("nan")
            out[key] = {
                "min": float(col.min()) if col.size else float("nan"),
                "max": float(col.max()) if col.size else float("nan"),
                "mean": mean,
                "std": float(col.std(ddof=1)) if col.size > 1 else 0.0,
                "actual": float(truth[k]),
                "mean_error_pct": float(abs(mean - truth[k]) / abs(truth[k]) * 100)
                if truth[k] != 0
                else float("nan"),
            }
    return out


def _in_chunks(
    kw: dict[str, Any], n_trials: int, seed: int | np.random.SeedSequence | None
) -> SensitivityResult:
    """:func:`monte_carlo` of ``n_trials`` in chunks of at most ``_CHUNK`` trials (bounded
    memory), each with a child of ``seed``'s sequence, concatenated."""
    parts, left = [], n_trials
    ss = seed if isinstance(seed, np.random.SeedSequence) else np.random.SeedSequence(seed)
    for child in ss.spawn(-(-n_trials // _CHUNK)):
        k = min(_CHUNK, left)
        left -= k
        parts.append(monte_carlo(**kw, n_trials=k, seed=child))
    samples_all = np.concatenate([r.samples for r in parts])
    return SensitivityResult(
        samples_all,
        parts[0].truth,
        _stats(samples_all, parts[0].truth),
        {**parts[0].description, "n_trials": n_trials, "seed": seed},
    )


def _sensor_trials(
    pos: FloatArray,
    axes: FloatArray,
    rs: NDArray[np.intp],
    T: int,
    max_angle_deg: float,
    sensor_position_error_m: float,
    rng: np.random.Generator,
) -> tuple[FloatArray, FloatArray]:
    """Nominal Ψ (n_ch, 6) and the true Ψ of each trial (T, n_ch, 6), rows ``[dᵀ, (r × d)ᵀ]``.

    Sensors ``rs`` are turned by a random rotation within ``max_angle_deg``
    (:func:`random_rotations`) and moved by ``U(−e, e)`` per coordinate,
    ``e = sensor_position_error_m``; 3 channels per sensor, along its axes' columns.
    """
    n_s = pos.shape[0]
    if rs.size and (rs.min() < 0 or rs.max() >= n_s):
        raise SetupError(f"rotate_sensors must be sensor indices 0..{n_s - 1}")
    axes_t = np.broadcast_to(axes, (T, n_s, 3, 3)).copy()
    pos_t = np.broadcast_to(pos, (T, n_s, 3)).copy()
    if rs.size and max_angle_deg > 0:
        axes_t[:, rs] = axes_t[:, rs] @ random_rotations(T, rs.size, max_angle_deg, rng)
    if rs.size and sensor_position_error_m > 0:
        pos_t[:, rs] += rng.uniform(
            -sensor_position_error_m, sensor_position_error_m, (T, rs.size, 3)
        )
    d_n = np.swapaxes(axes, -1, -2).reshape(-1, 3)  # channel directions (3 per sensor)
    p_n = np.repeat(pos, 3, axis=0)
    psi_n = np.concatenate([d_n, np.cross(p_n, d_n)], axis=1)
    d_t = np.swapaxes(axes_t, -1, -2).reshape(T, -1, 3)
    p_t = np.repeat(pos_t, 3, axis=1)
    psi_t = np.concatenate([d_t, np.cross(p_t, d_t)], axis=2)  # (T, n_ch, 6)
    return psi_n, psi_t


def _input_trials(
    phi: NDArray[np.floating] | None,
    input_positions_m: NDArray[np.floating] | None,
    input_directions: NDArray[np.floating] | None,
    perturb_inputs: Sequence[int],
    input_angle_deg: float,
    input_position_error_m: float,
    T: int,
    rng: np.random.Generator,
) -> tuple[FloatArray, FloatArray]:
    """Nominal input force vectors Φ (6, N) and the true ones of each trial (T, 6, N).

    The unit loads ``phi`` as given, then each force input ``[d; r × d]``; inputs
    ``perturb_inputs`` have their line of action turned within ``input_angle_deg`` and their
    point moved by ``U(−e, e)`` per coordinate, ``e = input_position_error_m``.
    """
    phis_n, phis_t = [], []
    if phi is not None:
        ph = np.asarray(phi, float).reshape(6, -1)
        phis_n.append(ph)
        phis_t.append(np.broadcast_to(ph, (T, 6, ph.shape[1])))
    if input_positions_m is not None and input_directions is not None:
        ip = np.asarray(input_positions_m, float).reshape(-1, 3)
        idr = np.asarray(input_directions, float).reshape(-1, 3)
        n_in = ip.shape[0]
        pi = np.asarray(perturb_inputs, dtype=np.intp)
        ip_t = np.broadcast_to(ip, (T, n_in, 3)).copy()
        id_t = np.broadcast_to(idr, (T, n_in, 3)).copy()
        if pi.size and input_angle_deg > 0:
            R = random_rotations(T, pi.size, input_angle_deg, rng)
            id_t[:, pi] = np.einsum("tnij,tnj->tni", R, id_t[:, pi])
        if pi.size and input_position_error_m > 0:
            ip_t[:, pi] += rng.uniform(
                -input_position_error_m, input_position_error_m, (T, pi.size, 3)
            )
        phis_n.append(np.concatenate([idr, np.cross(ip, idr)], axis=1).T)
        phis_t.append(np.swapaxes(np.concatenate([id_t, np.cross(ip_t, id_t)], axis=2), 1, 2))
    if not phis_n:
        raise SetupError("no input: give phi (unit loads at P) or input positions and directions")
    return np.concatenate(phis_n, axis=1), np.concatenate(phis_t, axis=2)


def monte_carlo(
    *,
    mass_kg: float,
    cg_m: Sequence[float],
    inertia_p_kgm2: Sequence[float],
    sensor_positions_m: NDArray[np.floating],
    sensor_axes: NDArray[np.floating],
    phi: NDArray[np.floating] | None = None,
    input_positions_m: NDArray[np.floating] | None = None,
    input_directions: NDArray[np.floating] | None = None,
    rotate_sensors: Sequence[int] = (),
    max_angle_deg: float = 0.0,
    sensor_position_error_m: float = 0.0,
    perturb_inputs: Sequence[int] = (),
    input_angle_deg: float = 0.0,
    input_position_error_m: float = 0.0,
    n_trials: int = 500,
    seed: int | np.random.SeedSequence | None = None,
) -> SensitivityResult:
    """Monte Carlo over geometry errors of the free-free rigid-body model (module docstring).

    P is the origin of the coordinates given.

    Parameters
    ----------
    mass_kg, cg_m, inertia_p_kgm2
        True properties; inertia ``[Ixx, Ixy, Ixz, Iyy, Iyz, Izz]`` about P (tensor elements).
    sensor_positions_m : ndarray, shape (n_s, 3)
    sensor_axes : ndarray, shape (n_s, 3, 3)
        Columns: the sensor's measuring axes in the GCS (3 channels per sensor).
    phi : ndarray, shape (6, n_extra), optional
        Extra ideal inputs given directly as 6-DOF unit loads at P (e.g. the cube's unit forces and
        moments); never perturbed.
    input_positions_m, input_directions : ndarray, shape (n_in, 3), optional
        Force inputs (position and unit line of action).
    rotate_sensors : indices of sensors whose orientation is randomised (``max_angle_deg``).
    sensor_position_error_m : float
        Uniform ±error on each coordinate of the ``rotate_sensors`` sensors' positions.
    perturb_inputs : indices of force inputs whose line of action (``input_angle_deg``) and
        position (``input_position_error_m``) are randomised.
    """
    if not 1 <= n_trials <= MAX_TRIALS:
        raise SetupError(f"n_trials {n_trials}: give 1 to {MAX_TRIALS} trials")
    if n_trials > _CHUNK:  # bounded memory: independent chunks from spawned seed sequences
        kw = dict(locals())
        kw.pop("n_trials"), kw.pop("seed")
        return _in_chunks(kw, n_trials, seed)
    rng = np.random.default_rng(seed)
    pos = np.asarray(sensor_positions_m, float).reshape(-1, 3)
    axes = np.asarray(sensor_axes, float).reshape(-1, 3, 3)
    n_s = pos.shape[0]
    if axes.shape[0] != n_s:
        raise SetupError(
            f"{n_s} sensor positions but {axes.shape[0]} axis sets; give one of each per sensor"
        )
    T = n_trials
    cg = np.asarray(cg_m, float)
    i6 = np.asarray(inertia_p_kgm2, float)
    M = mass_matrix(mass_kg, cg, i6)
    truth = np.concatenate([[mass_kg], cg, i6])
    rs = np.asarray(rotate_sensors, dtype=np.intp)
    psi_n, psi_t = _sensor_trials(pos, axes, rs, T, max_angle_deg, sensor_position_error_m, rng)
    phi_n, phi_t = _input_trials(
        phi,
        input_positions_m,
        input_directions,
        perturb_inputs,
        input_angle_deg,
        input_position_error_m,
        T,
        rng,
    )

    # forward and inverse -----------------------------------------------------------------------
    K_t = np.linalg.solve(M, phi_t)  # (T, 6, N): free rigid body, a = M⁻¹ F
    q = psi_t @ K_t  # (T, n_ch, N)
    K_hat = np.asarray(np.linalg.pinv(psi_n) @ q, dtype=np.float64)  # (T, 6, N)
    samples = solve_trials(K_hat, phi_n)
    desc = {
        "n_trials": T,
        "seed": seed,
        "rotated_sensors": rs.tolist(),
        "max_angle_deg": max_angle_deg,
        "sensor_position_error_m": sensor_position_error_m,
        "perturbed_inputs": list(map(int, perturb_inputs)),
        "input_angle_deg": input_angle_deg,
        "input_position_error_m": input_position_error_m,
    }
    return SensitivityResult(samples, truth, _stats(samples, truth), desc)


#: Corner order of the cube's triaxes, in units of the half size. The thesis does not say which
#: triax its one-triax studies (Tables 2–5) randomise; the study is not symmetric because the
#: calibration mass is not (its Ixz product of inertia). Table 5 identifies it: over its seven
#: cases, with 20 000 trials per corner, the mean mass of a randomised corner with ``x·z < 0``
#: agrees with the thesis within its Monte Carlo noise (500 trials; χ² 1.9–6 over 7 cases) and one
#: with ``x·z > 0`` does not (χ² ≈ 60: 5σ low on the 2 m cube at 0.1° and 1°). The best,
#: ``(−H, +H, +H)``, comes first; the order of the others (studies with several randomised
#: triaxes, Tables 6–13) is the first corner's mirror images, then the rest.
CUBE_CORNERS: tuple[tuple[int, int, int], ...] = (
    (-1, 1, 1),
    (-1, -1, 1),
    (1, 1, -1),
    (1, -1, -1),
    (-1, -1, -1),
    (-1, 1, -1),
    (1, -1, 1),
    (1, 1, 1),
)


def cube_model(half_size_m: float) -> tuple[FloatArray, FloatArray, FloatArray]:
    """The thesis cube: 8 GCS-aligned triaxes at ``(±H, ±H, ±H)`` (in the order of
    :data:`CUBE_CORNERS`) and the six unit loads at P.

    Returns positions (8, 3), axes (8, 3, 3) and phi (6, 6) = identity.
    """
    if not half_size_m > 0:
        raise SetupError(f"half size {half_size_m} m must be positive")
    H = float(half_size_m)
    pos = H * np.array(CUBE_CORNERS, dtype=float)
    return pos, np.broadcast_to(np.eye(3), (8, 3, 3)).copy(), np.eye(6)


def cube_study(
    half_size_m: float,
    *,
    n_sensors: int = 1,
    max_angle_deg: float = 1.0,
    n_trials: int = 500,
    seed: int | None = None,
) -> SensitivityResult:
    """Thesis Tables 2–13 study on the cube: the first ``n_sensors`` triaxes (order of
    :data:`CUBE_CORNERS`) randomly rotated."""
    if not 1 <= n_sensors <= 8:
        raise SetupError(f"sensors {n_sensors}: the cube has 8 triaxes; give 1..8")
    pos, axes, phi = cube_model(half_size_m)
    cm = CALIBRATION_MASS
    res = monte_carlo(
        mass_kg=cm["mass_kg"],
        cg_m=cm["cg_m"],
        inertia_p_kgm2=cm["inertia_origin_kgm2"],
        sensor_positions_m=pos,
        sensor_axes=axes,
        phi=phi,
        rotate_sensors=range(n_sensors),
        max_angle_deg=max_angle_deg,
        n_trials=n_trials,
        seed=seed,
    )
    desc = {"model": "cube", "half_size_m": half_size_m, "n_sensors": n_sensors, **res.description}
    return SensitivityResult(res.samples, res.truth, res.stats, desc)


__all__ += ["JSON_KEYS", "PARAMETERS"]
