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
- **Over the geometry** (optional, :func:`geometry_spread`): the stated 1σ of sensor positions and
  orientations, input points and lines of action (and the registration residual) propagated
  through the joint solve by Monte Carlo; ``SE_G`` the standard deviation of those solutions. The
  input and sensor jackknives see only the part of a geometry error that differs between inputs
  or sensors; a common part (every triax turned the same way, a registration offset) is in
  ``SE_G`` alone.
- **Over lines**: ``SE_L = std_l(p_l) / sqrt(n_eff)``; adjacent lines of a smooth FRF are not
  independent, so ``n_eff`` is the number of lines divided by the integrated autocorrelation time
  of the per-line estimates (at least 1 line per effective sample).

Leave-one-out solves that are rank deficient (an input or sensor node the others cannot do
without) are counted (``n_rank_deficient``) and reported, not silently dropped.

Principal moments about the CG (a nonlinear function of all ten parameters) get their own standard
error from the same four sources: the principal moments of every input leave-out (or bootstrap
draw), sensor leave-out, geometry sample and line, combined like the parameters'
(:func:`principal_of_parameters`); ``Uncertainty.principal`` holds them.

The reported standard error is ``sqrt(SE_inputs² + SE_R² + SE_G² + SE_L²)`` (the line spread is largely included
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

from dimacq.errors import SetupError, SolverError
from dimacq.model.properties import vector_to_inertia
from dimacq.model.setup import PARAMETERS
from dimacq.pipeline._batched import cross3
from dimacq.pipeline._special import t_ppf
from dimacq.pipeline.dim import (
    DimResult,
    DimSystem,
    solve_gram_sums,
    solve_joint,
    solve_joint_many,
)
from dimacq.pipeline.rotations import rotvec_to_matrix

__all__ = [
    "GeometrySpread",
    "ParameterUncertainty",
    "Uncertainty",
    "effective_samples",
    "estimate_uncertainty",
    "geometry_spread",
    "joint_parameters_for_geometry",
    "principal_of_parameters",
]

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
    se_geometry: float = 0.0

    def to_json(self) -> dict[str, Any]:
        return {
            "value": self.value,
            "standard_error": self.standard_error,
            "ci95": list(self.ci95),
            "se_inputs": self.se_inputs,
            "se_lines": self.se_lines,
            "se_responses": self.se_responses,
            "se_geometry": self.se_geometry,
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
    n_rank_deficient : int
        Input resamplings and sensor leave-outs whose solve was rank deficient.
    components : tuple of str
        The sources included: ``inputs``, ``lines``, and ``responses`` / ``geometry`` when given.
    """

    parameters: dict[str, ParameterUncertainty]
    method: str
    n_inputs: int
    n_lines_effective: float
    samples: FloatArray
    n_rank_deficient: int = 0
    components: tuple[str, ...] = ("inputs", "lines")
    principal: tuple[ParameterUncertainty, ...] = ()

    def relative_se(self) -> dict[str, float]:
        """Relative standard errors ``SE / |value|`` of the mass (``m``) and of the principal
        moments (``I1 ≤ I2 ≤ I3``); NaN for a zero value."""
        items = [("m", self.parameters["m"])] if "m" in self.parameters else []
        items += [(f"I{k + 1}", u) for k, u in enumerate(self.principal)]
        return {
            k: (u.standard_error / abs(u.value) if u.value != 0 else float("nan")) for k, u in items
        }

    def to_json(self) -> dict[str, Any]:
        out: dict[str, Any] = {k: v.to_json() for k, v in self.parameters.items()}
        if self.principal:
            out["principal_moments"] = [u.to_json() for u in self.principal]
        out["method"] = self.method
        out["n_inputs"] = self.n_inputs
        out["n_lines_effective"] = self.n_lines_effective
        out["n_rank_deficient"] = self.n_rank_deficient
        out["components"] = list(self.components)
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


def principal_of_parameters(
    params: NDArray[np.floating], reference_point_m: NDArray[np.floating]
) -> FloatArray:
    """Principal moments about the CG of parameter vectors.

    ``I_CG = I_P − m (|d|² E − d dᵀ)`` with ``d = c − P`` (parallel axis theorem), then the
    eigenvalues of ``I_CG`` in ascending order.

    Parameters
    ----------
    params : ndarray, shape (..., 10)
        ``[m (kg), cx, cy, cz (GCS, m), Ixx, Ixy, Ixz, Iyy, Iyz, Izz (about P, kg·m²)]``.
    reference_point_m : ndarray, shape (3,)
        P in the GCS, m.

    Returns
    -------
    ndarray, shape (..., 3)
        kg·m², ascending.
    """
    p = np.asarray(params, float)
    d = p[..., 1:4] - np.asarray(reference_point_m, float)
    m = p[..., 0]
    shift = m[..., None, None] * (
        np.sum(d * d, axis=-1)[..., None, None] * np.eye(3) - d[..., :, None] * d[..., None, :]
    )
    out: FloatArray = np.linalg.eigvalsh(vector_to_inertia(p[..., 4:]) - shift)
    return out


def estimate_uncertainty(
    system: DimSystem,
    result: DimResult,
    *,
    known: Mapping[str, float] | None = None,
    method: Literal["jackknife", "bootstrap"] = "jackknife",
    n_bootstrap: int = 200,
    seed: int | None = 0,
    response_systems: Sequence[DimSystem] = (),
    geometry: GeometrySpread | None = None,
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
        jackknife over sensors); empty: no sensor term (then ``components`` says so).
    geometry : GeometrySpread, optional
        The stated geometry uncertainty propagated through the solve (:func:`geometry_spread`);
        None: no geometry term (``components`` says so; the analysis service always gives it).
    """
    n_in = system.K.shape[2]
    if n_in < 3:
        raise SetupError(
            f"{n_in} inputs are too few to estimate an uncertainty over inputs; give 3 or more"
        )
    samples: list[FloatArray] = []
    n_bad = 0
    if method == "jackknife":
        # every leave-one-out from the inputs' band sums (dimacq.pipeline.dim.solve_joint_many)
        loo, solved = solve_joint_many(system, 1.0 - np.eye(n_in), known=known)
        for j in range(n_in):
            if solved[j]:
                samples.append(loo[j])
            else:
                n_bad += 1
                log.warning(
                    "leave-one-out without input %s is rank deficient: the others cannot "
                    "determine every parameter without it",
                    system.inputs[j].name,
                )
        s = np.array(samples).reshape(-1, 10)
        n = s.shape[0]
        se_in = (
            np.sqrt((n_in - 1) / n_in * np.sum((s - s.mean(axis=0)) ** 2, axis=0))
            if n > 1
            else np.zeros(10)
        )
    elif method == "bootstrap":
        rng = np.random.default_rng(seed)
        for _ in range(n_bootstrap):
            w = np.bincount(rng.integers(0, n_in, n_in), minlength=n_in).astype(float)
            try:
                samples.append(solve_joint(system, known=known, input_weights=w))
            except SolverError:
                n_bad += 1
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
            rs.append(solve_joint(sy, known=known))
        except SolverError:
            n_bad += 1
            continue
    se_r = np.zeros(10)
    if len(rs) > 1:
        r_arr = np.array(rs)
        g = r_arr.shape[0]
        se_r = np.sqrt((g - 1) / g * np.sum((r_arr - r_arr.mean(axis=0)) ** 2, axis=0))
    se_g = np.zeros(10) if geometry is None else np.asarray(geometry.se, float)
    se = np.sqrt(se_in**2 + se_r**2 + se_g**2 + se_l**2)
    for k in known or {}:
        se[PARAMETERS.index(k)] = 0.0
    tq = t_ppf(0.975, max(n_in - 1, 1))  # stats.t.ppf to ~1e-14, without scipy
    p = result.parameters
    params = {
        name: ParameterUncertainty(
            float(p[i]),
            float(se[i]),
            (float(p[i] - tq * se[i]), float(p[i] + tq * se[i])),
            float(se_in[i]),
            float(se_l[i]),
            float(se_r[i]),
            float(se_g[i]) if PARAMETERS[i] not in (known or {}) else 0.0,
        )
        for i, name in enumerate(PARAMETERS)
    }
    principal = _principal_uncertainty(
        result, s, method, n_in, finite, n_eff, rs, geometry, known or {}, tq
    )
    comps: tuple[str, ...] = ("inputs", "lines")
    if response_systems:
        comps += ("responses",)
    if geometry is not None:
        comps += ("geometry",)
    return Uncertainty(params, method, n_in, n_eff, s, n_bad, comps, principal)


def _principal_uncertainty(
    result: DimResult,
    s_in: FloatArray,
    method: str,
    n_in: int,
    per_line: FloatArray,
    n_eff: float,
    rs: Sequence[FloatArray],
    geometry: GeometrySpread | None,
    known: Mapping[str, float],
    tq: float,
) -> tuple[ParameterUncertainty, ...]:
    """Standard error of the three principal moments from the samples of each source."""
    P = result.reference_point_m
    w0 = principal_of_parameters(result.parameters, P)
    if s_in.shape[0] > 1:
        w = principal_of_parameters(s_in, P)
        se_in = (
            np.sqrt((n_in - 1) / n_in * np.sum((w - w.mean(axis=0)) ** 2, axis=0))
            if method == "jackknife"
            else w.std(axis=0, ddof=1)
        )
    else:
        se_in = np.zeros(3)
    se_l = (
        principal_of_parameters(per_line, P).std(axis=0, ddof=1) / np.sqrt(n_eff)
        if per_line.shape[0] > 1
        else np.zeros(3)
    )
    se_r = np.zeros(3)
    if len(rs) > 1:
        wr = principal_of_parameters(np.asarray(rs), P)
        g = wr.shape[0]
        se_r = np.sqrt((g - 1) / g * np.sum((wr - wr.mean(axis=0)) ** 2, axis=0))
    se_g = np.zeros(3)
    if geometry is not None and geometry.samples.shape[0] > 1:
        se_g = principal_of_parameters(geometry.samples, P).std(axis=0, ddof=1)
    se = np.sqrt(se_in**2 + se_r**2 + se_g**2 + se_l**2)
    if all(k in known for k in PARAMETERS[4:]) and all(k in known for k in PARAMETERS[:4]):
        se = np.zeros(3)
    return tuple(
        ParameterUncertainty(
            float(w0[k]),
            float(se[k]),
            (float(w0[k] - tq * se[k]), float(w0[k] + tq * se[k])),
            float(se_in[k]),
            float(se_l[k]),
            float(se_r[k]),
            float(se_g[k]),
        )
        for k in range(3)
    )


# --------------------------------------------------------------------------------------------
# Geometry: the stated uncertainty of positions and directions propagated through the solve
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class GeometrySpread:
    """Spread of the joint DIM solution over the stated geometry uncertainty.

    Attributes
    ----------
    se : ndarray, shape (10,)
        Standard deviation of the parameters over the Monte Carlo samples (kg, m, kg·m²).
    se_linear : ndarray, shape (10,)
        The same by linearisation: ``sqrt(Σ_k (∂p/∂g_k · σ_k)²)`` over every geometry coordinate
        ``g_k`` (central differences of ±σ_k); a check on ``se``.
    samples : ndarray, shape (n_samples, 10)
    n_samples : int
    sigma : dict
        The 1σ values used (``sensor_position_m``, ``sensor_orientation_deg``,
        ``input_position_m``, ``line_of_action_deg``; registration residual added in quadrature
        to both positions).
    """

    se: FloatArray
    se_linear: FloatArray
    samples: FloatArray
    n_samples: int
    sigma: dict[str, float]


def band_sums(
    system: DimSystem, H_acc: NDArray[np.complexfloating]
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Sums over lines that make the joint normal equations a function of the geometry only.

    With ``K_l = M H_l`` (``M`` the 6×n condensation, over ``u``) and ``F_l = (Φ + R_l)/u``
    (``Φ`` the inputs' unit force vectors, ``R_l`` the load-cell reactions at P), the joint Gram
    matrices of :func:`dimacq.pipeline.dim.solver._gram_normal_equations` summed over lines are
    ``G = M P Mᵀ`` and ``C = M (S₁ Φᵀ + S₂)/u`` with ``P = Re Σ_l H̄_l H_lᵀ`` (n×n),
    ``S₁ = Re Σ_l H̄_l`` (n×J) and ``S₂ = Re Σ_l H̄_l R_lᵀ`` (n×6).
    """
    H = np.asarray(H_acc)
    u = system.unit_m
    R = system.F * u - system.phi[None].astype(complex)  # (L, 6, J): reactions at P
    Hm = np.moveaxis(H, 1, 0).reshape(H.shape[1], -1)  # (n, L·J)
    P = np.real(Hm.conj() @ Hm.T)
    S1 = np.real(H.conj().sum(axis=0))
    S2 = np.real(Hm.conj() @ np.moveaxis(R, 1, 0).reshape(R.shape[1], -1).T)
    return P, S1, S2


def joint_parameters_for_geometry(
    system: DimSystem,
    sums: tuple[FloatArray, FloatArray, FloatArray],
    positions_m: FloatArray,
    directions: FloatArray,
    weights: FloatArray,
    in_positions_m: FloatArray,
    in_directions: FloatArray,
    known: Mapping[str, float] | None = None,
) -> FloatArray:
    """Joint DIM parameters for a batch of geometries, vectorised over the batch.

    Parameters
    ----------
    system : DimSystem
        The assembled system (its load cells, reference point, unit and inputs).
    sums : from :func:`band_sums`
    positions_m, directions : ndarray, shape (S, n, 3)
        Response channel positions and unit directions (GCS, m) of each geometry sample.
    weights : ndarray, shape (n,)
        Channel weights (0 = excluded).
    in_positions_m, in_directions : ndarray, shape (S, J, 3)
    known : dict, optional

    Returns
    -------
    ndarray, shape (S, 10)
        ``[m, cx, cy, cz, Ixx..Izz]`` as :attr:`DimResult.parameters`.
    """
    P, S1, S2 = sums
    u = system.unit_m
    p = system.reference_point_m
    r = (positions_m - p) / u
    psi = np.concatenate([directions, cross3(r, directions)], axis=-1)  # (S, n, 6)
    wp = psi * weights[None, :, None]
    M = np.linalg.pinv(wp) * weights[None, None, :] / u  # (S, 6, n)
    ri = (in_positions_m - p) / u
    phi = np.concatenate([in_directions, cross3(ri, in_directions)], axis=-1)  # (S, J, 6)
    G = M @ P @ np.swapaxes(M, 1, 2)  # (S, 6, 6)
    C = M @ (S1 @ phi + S2) / u
    S = G.shape[0]
    out: FloatArray = solve_gram_sums(G.reshape(S, 36), C.reshape(S, 36), p, u, known=known)[0]
    return out


@dataclass(frozen=True, eq=False)
class _NominalGeometry:
    """The stated geometry that :func:`geometry_spread` perturbs, with the band's sums.

    ``positions``, ``directions`` (n, 3) of the channels, ``node_index`` (n,) the index of each
    channel's node, ``weights`` (n,), ``in_positions``, ``in_directions`` (J, 3) of the inputs.
    """

    system: DimSystem
    sums: tuple[FloatArray, FloatArray, FloatArray]
    positions: FloatArray
    directions: FloatArray
    node_index: NDArray[np.integer]
    weights: FloatArray
    in_positions: FloatArray
    in_directions: FloatArray
    known: Mapping[str, float] | None

    def parameters(
        self,
        dp_node: FloatArray,
        rv_node: FloatArray,
        dp_in: FloatArray,
        rv_in: FloatArray,
        eps_ch: FloatArray,
        eta: FloatArray,
    ) -> FloatArray:
        """Joint parameters (S, 10) of S perturbed geometries.

        Node ``g`` moves by ``dp_node`` (S, G, 3) and turns by ``R(rv_node)``; input ``j`` moves
        by ``dp_in`` (S, J, 3) and its line of action turns by ``R(rv⊥)``, ``rv⊥`` the part of
        ``rv_in`` normal to it; channel ``c``'s direction is scaled by ``1 + eps_ch`` (S, n), the
        input force vectors by ``1 + eta`` (S,).
        """
        inv, dir0, idir0 = self.node_index, self.directions, self.in_directions
        Rn = rotvec_to_matrix(rv_node)  # (S, G, 3, 3)
        pos = self.positions[None] + dp_node[:, inv]
        dirs = np.einsum("snij,nj->sni", Rn[:, inv], dir0) * (1.0 + eps_ch)[..., None]
        # line of action turns about axes normal to it: project the rotation vector
        rv = rv_in - np.einsum("sjk,jk->sj", rv_in, idir0)[..., None] * idir0[None]
        idir = np.einsum("sjik,jk->sji", rotvec_to_matrix(rv), idir0) * (1.0 + eta)[:, None, None]
        return joint_parameters_for_geometry(
            self.system,
            self.sums,
            pos,
            dirs,
            self.weights,
            self.in_positions[None] + dp_in,
            idir,
            self.known,
        )


def _central_difference_perturbations(
    G: int,
    J: int,
    n_ch: int,
    sigmas: tuple[float, float, float, float, float, float],
    in_directions: FloatArray,
) -> list[list[FloatArray]]:
    """The ``±σ_k`` steps along every geometry coordinate ``k``, in pairs (+ then −).

    Each step is the six arguments of :meth:`_NominalGeometry.parameters` for one geometry:
    node offsets and rotations (G, 3), input offsets and line-of-action rotations (J, 3; only
    the two directions normal to the line), channel gains (n_ch,) and the force gain (). A
    coordinate whose ``σ`` is zero has no step.
    """
    sp, so, ip, sl, sa, sf = sigmas

    def zero() -> list[FloatArray]:
        return [
            np.zeros((G, 3)),
            np.zeros((G, 3)),
            np.zeros((J, 3)),
            np.zeros((J, 3)),
            np.zeros(n_ch),
            np.zeros(()),
        ]

    blocks = [(0, G, sp), (1, G, so), (2, J, ip), (3, J, sl)]
    pert: list[list[FloatArray]] = []
    for b, count, sig in blocks:
        if sig == 0:
            continue
        for i in range(count):
            for k in range(3):
                if b == 3:  # only the two directions normal to the line of action
                    basis = np.linalg.svd(in_directions[i][None])[2][1:]
                    if k == 2:
                        continue
                    vec = basis[k]
                else:
                    vec = np.eye(3)[k]
                for sgn in (1.0, -1.0):
                    z = zero()
                    z[b][i] = sgn * sig * vec
                    pert.append(z)
    for c in range(n_ch if sa > 0 else 0):
        for sgn in (1.0, -1.0):
            z = zero()
            z[4][c] = sgn * sa
            pert.append(z)
    for sgn in (1.0, -1.0) if sf > 0 else ():
        z = zero()
        z[5] = np.asarray(sgn * sf)
        pert.append(z)
    return pert


def _linearised_se(
    nominal: _NominalGeometry,
    G: int,
    J: int,
    sigmas: tuple[float, float, float, float, float, float],
) -> FloatArray:
    """First-order spread ``sqrt(Σ_k (∂p/∂g_k · σ_k)²)`` (10,) by central differences.

    ``∂p/∂g_k · σ_k = (p(+σ_k) − p(−σ_k)) / 2`` over every coordinate of
    :func:`_central_difference_perturbations`, solved in one batch.
    """
    n_ch = nominal.positions.shape[0]
    pert = _central_difference_perturbations(G, J, n_ch, sigmas, nominal.in_directions)
    if not pert:
        return np.zeros(10)
    arr = [np.stack([p[k] for p in pert]) for k in range(6)]
    vals = nominal.parameters(*arr)
    d = (vals[0::2] - vals[1::2]) / 2.0
    out: FloatArray = np.sqrt(np.sum(d**2, axis=0))
    return out


def geometry_spread(
    system: DimSystem,
    H_acc: NDArray[np.complexfloating],
    positions_m: FloatArray,
    directions: FloatArray,
    nodes: NDArray[np.integer],
    weights: FloatArray,
    in_positions_m: FloatArray,
    in_directions: FloatArray,
    *,
    sensor_position_m: float,
    sensor_orientation_deg: float,
    input_position_m: float,
    line_of_action_deg: float,
    registration_rms_m: float | None = None,
    accel_sensitivity_rel: float = 0.0,
    force_sensitivity_rel: float = 0.0,
    known: Mapping[str, float] | None = None,
    n_samples: int = 400,
    seed: int | None = 0,
) -> GeometrySpread:
    """Propagate the stated geometry and transducer uncertainty through the joint DIM solve.

    Model (independent, 1σ): each sensor node (all its channels together) moves by
    ``N(0, σ_p² + σ_reg²)`` per coordinate and turns by a rotation vector ``N(0, σ_o)`` per axis;
    each input point moves by ``N(0, σ_ip² + σ_reg²)`` per coordinate and its line of action turns
    by ``N(0, σ_loa)`` about each of the two axes normal to it. Transducer calibration: a channel
    whose certificate sensitivity is off by ``ε_c ~ N(0, σ_a)`` reports ``(1 + ε_c) d_cᵀ u``, the
    same as solving with its row of Ψ scaled by ``(1 + ε_c)``; a force transducer off by
    ``η ~ N(0, σ_f)`` (one for all inputs) divides every acceleration and reaction FRF by
    ``(1 + η)``, and solving ``A(K/(1 + η)) x = φ + R/(1 + η)`` is solving
    ``A(K) x = (1 + η) φ + R``: the input force vectors are scaled by ``(1 + η)``. (Without
    measured reactions mass and inertia then scale by ``(1 + η)``; with them, by less.)
    Monte Carlo over ``n_samples``
    geometries (vectorised: :func:`joint_parameters_for_geometry`) gives ``se``; central differences
    over every coordinate give ``se_linear`` (first-order propagation), which the Monte Carlo must
    match while the geometry errors are small.

    Parameters
    ----------
    system : DimSystem
        Assembled on the band with the kept inputs.
    H_acc : ndarray, shape (n_lines, n, J)
        The band's acceleration FRFs of those inputs, channels in ``system.responses`` order.
    positions_m, directions : ndarray, shape (n, 3)
        Nominal channel positions (m) and unit directions (sign of the record applied).
    nodes : ndarray, shape (n,)
        Node of each channel (channels of a node move and turn together).
    weights : ndarray, shape (n,)
    in_positions_m, in_directions : ndarray, shape (J, 3)
    """
    rng = np.random.default_rng(seed)
    reg = float(registration_rms_m or 0.0)
    sp = float(np.hypot(sensor_position_m, reg))
    ip = float(np.hypot(input_position_m, reg))
    so = np.deg2rad(sensor_orientation_deg)
    sl = np.deg2rad(line_of_action_deg)
    uniq, inv = np.unique(nodes, return_inverse=True)
    nominal = _NominalGeometry(
        system,
        band_sums(system, H_acc),
        np.asarray(positions_m, float),
        np.asarray(directions, float),
        inv,
        np.asarray(weights, float),
        np.asarray(in_positions_m, float),
        np.asarray(in_directions, float),
        known,
    )
    G, J = uniq.size, in_positions_m.shape[0]
    n_ch = nominal.positions.shape[0]
    sa, sf = float(accel_sensitivity_rel), float(force_sensitivity_rel)

    S = int(n_samples)
    samples = nominal.parameters(
        rng.normal(scale=sp, size=(S, G, 3)),
        rng.normal(scale=so, size=(S, G, 3)),
        rng.normal(scale=ip, size=(S, J, 3)),
        rng.normal(scale=sl, size=(S, J, 3)),
        rng.normal(scale=sa, size=(S, n_ch)),
        rng.normal(scale=sf, size=S),
    )
    se = samples.std(axis=0, ddof=1) if S > 1 else np.zeros(10)
    se_lin = _linearised_se(nominal, G, J, (sp, so, ip, sl, sa, sf))
    return GeometrySpread(
        se=se,
        se_linear=se_lin,
        samples=samples,
        n_samples=S,
        sigma={
            "sensor_position_m": sp,
            "sensor_orientation_deg": float(sensor_orientation_deg),
            "input_position_m": ip,
            "line_of_action_deg": float(line_of_action_deg),
            "accel_sensitivity_rel": sa,
            "force_sensitivity_rel": sf,
        },
    )
