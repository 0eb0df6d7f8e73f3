"""Pre-test planning: the information a layout of triaxes and inputs gives on the ten inertia
parameters, and the choice of the layout (``dimacq plan``).

Model (method.md §4–6, free-free rigid body, frequency independent): with the 6×6 rigid-body mass
matrix ``M(x)`` about P, linear in ``x = [m, m·c, I6]`` (``M(x) K = A(K) x``, Eq. 33), the motion of
P per unit input j is ``K_j = M⁻¹ φ_j`` and channel c (unit direction ``d_c`` at ``r_c``) measures the
accelerance ``H_cj = ψ_cᵀ K_j``, ``ψ_c = [d_c; r_c × d_c]`` (a real number, the same on every line).

Noise model: complex Gaussian FRF noise, independent per line, channel and input (the
output-error estimator estimates its level per output and input), of standard deviation
``σ_cj = noise · s_cj``; each of ``n_lines`` lines gives ``H_cj`` with a real-part variance
``σ_cj²/2``. Two scales ``s_cj``:

- ``"channel"`` (default): the RMS of input j's FRFs over every candidate channel — the same
  noise on every channel of one strike, as an accelerometer's noise floor is (it does not shrink
  because the channel's signal is small);
- ``"relative"``: each FRF's own magnitude, what ``dimacq simulate --noise`` adds. It makes a
  small FRF as precise, relatively, as a large one, so that triaxes near the CG (small, precise
  rotational terms) look as good as far ones: not what an accelerometer does.

Nuisance parameters with Gaussian priors (the setup's ``[geometry_uncertainty]`` and
``[transducer_uncertainty]``, what the default solve refines): per triax a position offset δr (σ
``sensor_position_m``) and a small rotation δθ (σ ``sensor_orientation_deg``), per channel a
relative gain (σ ``accel_sensitivity_rel``), per input a position offset δp (σ
``input_position_m``) and a small rotation of its line of action δβ (σ ``line_of_action_deg``).
The derivatives of ``H_cj`` (u the motion at the triax, ``w = M⁻ᵀ ψ_c``)::

    ∂H/∂x   = −ψ_cᵀ M⁻¹ A(K_j)                     ∂H/∂δr = d_c × α_j
    ∂H/∂δθ  = d_c × (a_j + α_j × r_c)              ∂H/∂g  = H_cj
    ∂H/∂δp  = e_j × w_rot                          ∂H/∂δβ = e_j × (w_trans + w_rot × p_j)

The Bayesian Fisher information of all parameters is ``J = Σ_cj w_cj g_cj g_cjᵀ + P`` (``w_cj =
2 n_lines / (noise·H_cj)²``, P the priors' precision); the predicted covariance of x is the
``x`` block of ``J⁻¹`` (the nuisances marginalised, the gauge of the similarity transforms held by
their priors), plus the hammer's common scale ``σ_f² x xᵀ`` (a force sensitivity error scales
every FRF, hence every parameter of x; the CG not at all). The per-input nuisances appear only in
their input's rows, the per-triax ones only in their triax's rows: each is eliminated in closed
form (a Schur complement per input, or per triax), so the information of a layout is a sum over
its inputs (:func:`input_information`) or over its triaxes (:func:`triax_information`), which is
what makes greedy and exchange selection cheap.

Targets: mass, CG (GCS) and the principal moments about the CG; their covariance by first-order
propagation. A 95 % bound is the 95 % quantile of the absolute error (mass, %), of the largest
absolute CG component error (mm) and of the largest relative principal-moment error (%), under the
Gaussian of the predicted covariance (a fixed sample, deterministic): the statistics a Monte Carlo
of real solves gives. Selection minimises the A-optimal criterion on the scaled targets,
``(σ_m/m)² + Σ_k (σ_ck/ρ)² + Σ_k (σ_λk/λ_k)²`` (ρ the radius of gyration ``√(tr I_CG / 2m)``).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from dimacq.errors import SetupError
from dimacq.model.properties import RigidBodyProperties, vector_to_inertia
from dimacq.model.setup import PARAMETERS, TestSetup
from dimacq.pipeline.dim import design_matrices

__all__ = [
    "SOURCES",
    "Bounds",
    "Candidates",
    "ErrorModel",
    "Layout",
    "PlanModel",
    "build_model",
    "candidates_from_setup",
    "dense_information",
    "exchange_select",
    "input_information",
    "layout_covariance",
    "predicted_bounds",
    "random_layouts",
    "target_jacobian",
    "target_values",
    "triax_information",
    "x_covariance",
]

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.intp]

#: The error sources of the model, in the order of the error budget.
SOURCES = (
    "noise",
    "sensor_position",
    "sensor_orientation",
    "accel_gain",
    "input_position",
    "line_of_action",
    "force_gain",
)

#: Weak prior on the scaled parameters (σ = 10⁴ of their size): keeps a rank-deficient layout's
#: criterion finite (huge) so that greedy selection can start from one triax.
_X_RIDGE = 1e-8
#: Standard normal sample (fixed) for the quantiles of the largest component error.
_Z = np.random.default_rng(20261127).standard_normal((20000, 3))
_Q95 = 1.959963984540054


@dataclass(frozen=True)
class ErrorModel:
    """Standard uncertainties (1σ) of the test: FRF noise, geometry and transducers.

    ``noise`` is relative to each FRF's RMS magnitude (``dimacq simulate --noise``); ``n_lines`` the
    number of lines the solve uses.
    """

    noise: float = 0.01
    n_lines: int = 41
    noise_model: str = "channel"
    sensor_position_m: float = 0.002
    sensor_orientation_deg: float = 0.5
    accel_gain_rel: float = 0.005
    input_position_m: float = 0.002
    line_of_action_deg: float = 1.0
    force_gain_rel: float = 0.005

    @classmethod
    def from_setup(
        cls, setup: TestSetup, *, noise: float, n_lines: int, noise_model: str = "channel"
    ) -> ErrorModel:
        if noise_model not in ("channel", "relative"):
            raise SetupError(f"noise model {noise_model!r}: give channel or relative")
        g, t = setup.geometry_uncertainty, setup.transducer_uncertainty
        return cls(
            noise=noise,
            n_lines=n_lines,
            noise_model=noise_model,
            sensor_position_m=g.sensor_position_m,
            sensor_orientation_deg=g.sensor_orientation_deg,
            accel_gain_rel=t.accel_sensitivity_rel,
            input_position_m=g.input_position_m,
            line_of_action_deg=g.line_of_action_deg,
            force_gain_rel=t.force_sensitivity_rel,
        )

    def without(self, source: str) -> ErrorModel:
        """The same model with one source (a name of :data:`SOURCES`) set to zero; ``noise`` is
        never zeroed (it carries the data's information) — it is made 100 times smaller."""
        if source == "noise":
            return replace(self, noise=self.noise / 100)
        key = {
            "sensor_position": "sensor_position_m",
            "sensor_orientation": "sensor_orientation_deg",
            "accel_gain": "accel_gain_rel",
            "input_position": "input_position_m",
            "line_of_action": "line_of_action_deg",
            "force_gain": "force_gain_rel",
        }[source]
        zero: dict[str, Any] = {key: 0.0}
        return replace(self, **zero)

    def to_json(self) -> dict[str, Any]:
        return {
            "noise_rel": self.noise,
            "noise_model": self.noise_model,
            "n_lines": self.n_lines,
            "sensor_position_m": self.sensor_position_m,
            "sensor_orientation_deg": self.sensor_orientation_deg,
            "accel_sensitivity_rel": self.accel_gain_rel,
            "input_position_m": self.input_position_m,
            "line_of_action_deg": self.line_of_action_deg,
            "force_sensitivity_rel": self.force_gain_rel,
        }


@dataclass(frozen=True)
class Candidates:
    """Candidate triaxes (response nodes with their channels) and inputs of a setup.

    Attributes
    ----------
    nodes : tuple of int, length n_t
        Triax (response) nodes, in setup order.
    channel_triax : ndarray, shape (n_c,)
        Index in ``nodes`` of each response channel (setup order).
    directions, positions : ndarray, shape (n_c, 3)
        Channel unit directions and positions (GCS, m).
    input_nodes : tuple of (node, direction)
    input_directions, input_positions : ndarray, shape (n_in, 3)
    reference_point_m : ndarray, shape (3,)
    """

    nodes: tuple[int, ...]
    channel_triax: IntArray
    directions: FloatArray
    positions: FloatArray
    input_nodes: tuple[tuple[int, int], ...]
    input_directions: FloatArray
    input_positions: FloatArray
    reference_point_m: FloatArray

    @property
    def n_triaxes(self) -> int:
        return len(self.nodes)

    @property
    def n_inputs(self) -> int:
        return len(self.input_nodes)


def candidates_from_setup(setup: TestSetup) -> Candidates:
    """The candidates of a setup file: each response node is one candidate triax."""
    nodes: list[int] = []
    for c in setup.responses:
        if c.node not in nodes:
            nodes.append(c.node)
    if not setup.excitations:
        raise SetupError("the candidate setup lists no inputs; give [[inputs]] to choose from")
    return Candidates(
        nodes=tuple(nodes),
        channel_triax=np.array([nodes.index(c.node) for c in setup.responses], dtype=np.intp),
        directions=setup.response_directions,
        positions=setup.response_positions,
        input_nodes=tuple((e.node, e.direction) for e in setup.excitations),
        input_directions=setup.input_directions,
        input_positions=setup.input_positions,
        reference_point_m=setup.reference_point,
    )


def target_values(x: FloatArray) -> FloatArray:
    """``[m, cx, cy, cz (relative to P), λ1, λ2, λ3]`` (principal moments about the CG,
    ascending) of ``x = [m, m·c, I6 about P]``; shape (..., 10) → (..., 7)."""
    x = np.asarray(x, float)
    m = x[..., :1]
    c = x[..., 1:4] / m
    I = vector_to_inertia(x[..., 4:])
    cc = np.einsum("...i,...j->...ij", c, c)
    shift = m[..., None] * (np.einsum("...i,...i->...", c, c)[..., None, None] * np.eye(3) - cc)
    lam = np.linalg.eigvalsh(I - shift)
    return np.concatenate([m, c, lam], axis=-1)


@dataclass(frozen=True)
class PlanModel:
    """Derivatives of every candidate FRF, scaled: column ``k`` of a gradient is multiplied by the
    parameter's scale (x) or prior σ (nuisances) and each row by ``√w_cj``; the priors of the
    nuisances are then the identity.

    Attributes
    ----------
    gx : ndarray, shape (n_c, n_in, 10)
    gtri : ndarray, shape (n_c, n_in, 7)
        Triax position (3), rotation (3) and the channel's own gain (1).
    gin : ndarray, shape (n_c, n_in, 6)
        Input position (3) and line-of-action rotation (3).
    x0 : ndarray, shape (10,)
    x_scale : ndarray, shape (10,)
    """

    candidates: Candidates
    errors: ErrorModel
    properties: RigidBodyProperties
    gx: FloatArray
    gtri: FloatArray
    gin: FloatArray
    H: FloatArray
    x0: FloatArray
    x_scale: FloatArray
    radius_of_gyration_m: float

    def with_errors(self, errors: ErrorModel) -> PlanModel:
        return build_model(self.candidates, self.properties, errors)


def build_model(cand: Candidates, props: RigidBodyProperties, errors: ErrorModel) -> PlanModel:
    """Scaled derivatives of every candidate channel × input FRF (module docstring)."""
    if errors.noise <= 0 or errors.n_lines < 1:
        raise SetupError(
            f"noise {errors.noise}, {errors.n_lines} lines: give a positive noise level and at "
            "least one line (the FRF noise carries the data's information)"
        )
    P = cand.reference_point_m
    M = props.mass_matrix(P)
    Mi = np.linalg.inv(M)
    r = cand.positions - P
    d = cand.directions
    psi = np.concatenate([d, np.cross(r, d)], axis=1)  # (n_c, 6)
    e = cand.input_directions
    p = cand.input_positions - P
    phi = np.concatenate([e, np.cross(p, e)], axis=1).T  # (6, n_in)
    K = Mi @ phi  # (6, n_in)
    H = psi @ K  # (n_c, n_in)
    A = design_matrices(K)  # (n_in, 6, 10)
    gx = -np.einsum("ci,ij,njk->cnk", psi, Mi, A)
    a, al = K[:3].T, K[3:].T  # (n_in, 3)
    u = a[None, :, :] + np.cross(al[None, :, :], r[:, None, :])  # (n_c, n_in, 3)
    g_pos = np.cross(d[:, None, :], np.broadcast_to(al, (len(d), *al.shape)))
    g_rot = np.cross(np.broadcast_to(d[:, None, :], u.shape), u)
    w = psi @ Mi  # rows: w_cᵀ = ψ_cᵀ M⁻¹, i.e. w_c = M⁻ᵀ ψ_c
    w_t, w_r = w[:, :3], w[:, 3:]
    ee = np.broadcast_to(e[None], (len(d), *e.shape))
    g_ip = np.cross(ee, np.broadcast_to(w_r[:, None, :], ee.shape))
    z = w_t[:, None, :] + np.cross(
        np.broadcast_to(w_r[:, None, :], ee.shape), np.broadcast_to(p[None], ee.shape)
    )
    g_loa = np.cross(ee, z)
    x0 = props.parameter_vector(P)
    x0[1:4] *= x0[0]  # x = [m, m·c, I6]
    lam = np.linalg.eigvalsh(props.inertia_cg_kgm2)
    rho = float(np.sqrt(max(lam.sum(), 1e-300) / (2 * props.mass_kg)))
    m = props.mass_kg
    x_scale = np.array([m, m * rho, m * rho, m * rho, *([m * rho**2] * 6)])
    deg = np.pi / 180
    sw = np.sqrt(2.0 * errors.n_lines) / (errors.noise * noise_scale(H, errors.noise_model))
    gtri = np.concatenate(
        [
            g_pos * errors.sensor_position_m,
            g_rot * errors.sensor_orientation_deg * deg,
            H[..., None] * errors.accel_gain_rel,
        ],
        axis=2,
    )
    gin = np.concatenate(
        [g_ip * errors.input_position_m, g_loa * errors.line_of_action_deg * deg], axis=2
    )
    return PlanModel(
        candidates=cand,
        errors=errors,
        properties=props,
        gx=gx * x_scale * sw[..., None],
        gtri=gtri * sw[..., None],
        gin=gin * sw[..., None],
        H=H,
        x0=x0,
        x_scale=x_scale,
        radius_of_gyration_m=rho,
    )


def noise_scale(H: FloatArray, noise_model: str) -> FloatArray:
    """``s_cj`` of the noise model (module docstring) for the candidates' FRFs ``H`` (n_c, n_in)."""
    if noise_model == "relative":
        return np.asarray(np.maximum(np.abs(H), 1e-9 * np.abs(H).max()), dtype=np.float64)
    rms = np.sqrt(np.mean(H**2, axis=0, keepdims=True))
    return np.asarray(np.broadcast_to(rms, H.shape), dtype=np.float64)


# ---------------------------------------------------------------------------------------------
# Information of a layout
# ---------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Layout:
    """Chosen candidates: indices into :class:`Candidates` (sorted)."""

    triaxes: tuple[int, ...]
    inputs: tuple[int, ...]

    def to_json(self, cand: Candidates) -> dict[str, Any]:
        return {
            "responses": [int(cand.nodes[t]) for t in self.triaxes],
            "inputs": [int(cand.input_nodes[j][0]) for j in self.inputs],
            "input_channels": [
                {"node": int(cand.input_nodes[j][0]), "direction": int(cand.input_nodes[j][1])}
                for j in self.inputs
            ],
        }


def _channels(model: PlanModel, triaxes: Sequence[int]) -> tuple[IntArray, IntArray]:
    """Channel indices of the triaxes and each channel's slot (position in ``triaxes``)."""
    return _channels_of(model.candidates, triaxes)


def _channels_of(cand: Candidates, triaxes: Sequence[int]) -> tuple[IntArray, IntArray]:
    ct = cand.channel_triax
    pos = {t: k for k, t in enumerate(triaxes)}
    ch = np.array([c for c in range(ct.size) if int(ct[c]) in pos], dtype=np.intp)
    slot = np.array([pos[int(ct[c])] for c in ch], dtype=np.intp)
    return ch, slot


def input_information(model: PlanModel, triaxes: Sequence[int]) -> FloatArray:
    """Per candidate input, its information on ``[x (10), the triaxes' nuisances]`` with its own
    line-of-action and position nuisances eliminated (Schur complement); shape (n_in, p, p).

    The information of a layout of these triaxes is ``Σ_{j ∈ inputs} S_j + prior`` (additive over
    inputs)."""
    ch, slot = _channels(model, triaxes)
    sizes = [int(np.sum(model.candidates.channel_triax == t)) + 6 for t in triaxes]
    offs = np.concatenate([[0], np.cumsum(sizes)]).astype(np.intp)
    n_tp = int(offs[-1])
    n_in = model.gx.shape[1]
    Z = np.zeros((n_in, ch.size, 10 + n_tp))
    Z[:, :, :10] = np.swapaxes(model.gx[ch], 0, 1)
    gt = np.swapaxes(model.gtri[ch], 0, 1)  # (n_in, n_ch, 7)
    rows = np.arange(ch.size)
    rank = np.zeros(ch.size, dtype=np.intp)
    for s in range(len(triaxes)):
        idx = np.nonzero(slot == s)[0]
        rank[idx] = np.arange(idx.size)
    base = 10 + offs[slot]
    for k in range(6):
        Z[:, rows, base + k] = gt[:, :, k]
    Z[:, rows, base + 6 + rank] = gt[:, :, 6]
    Hh = np.swapaxes(model.gin[ch], 0, 1)  # (n_in, n_ch, 6)
    ZZ = np.einsum("jcp,jcq->jpq", Z, Z)
    ZH = np.einsum("jcp,jck->jpk", Z, Hh)
    HH = np.einsum("jck,jcl->jkl", Hh, Hh) + np.eye(6)
    return ZZ - ZH @ np.linalg.solve(HH, np.swapaxes(ZH, 1, 2))


def triax_information(model: PlanModel, inputs: Sequence[int]) -> FloatArray:
    """Per candidate triax, its information on ``[x (10), the inputs' nuisances (6 each)]`` with
    its own position, rotation and gain nuisances eliminated; shape (n_t, p, p). Additive over
    triaxes."""
    J = np.asarray(inputs, dtype=np.intp)
    nJ = J.size
    ct = model.candidates.channel_triax
    out = np.zeros((model.candidates.n_triaxes, 10 + 6 * nJ, 10 + 6 * nJ))
    for t in range(model.candidates.n_triaxes):
        ch = np.nonzero(ct == t)[0]
        nc = ch.size
        Z = np.zeros((nc, nJ, 10 + 6 * nJ))
        Z[:, :, :10] = model.gx[ch][:, J]
        gin = model.gin[ch][:, J]  # (nc, nJ, 6)
        for k in range(nJ):
            Z[:, k, 10 + 6 * k : 16 + 6 * k] = gin[:, k]
        L = np.zeros((nc, nJ, 6 + nc))
        gt = model.gtri[ch][:, J]
        L[:, :, :6] = gt[:, :, :6]
        L[np.arange(nc), :, 6 + np.arange(nc)] = gt[:, :, 6]
        Z2 = Z.reshape(nc * nJ, -1)
        L2 = L.reshape(nc * nJ, -1)
        ZL = Z2.T @ L2
        out[t] = Z2.T @ Z2 - ZL @ np.linalg.solve(L2.T @ L2 + np.eye(6 + nc), ZL.T)
    return out


def dense_information(model: PlanModel, layout: Layout) -> FloatArray:
    """The full information of a layout on ``[x, triax nuisances, input nuisances]`` with the
    priors, assembled row by row (no elimination): the reference the fast forms are tested
    against."""
    T, J = list(layout.triaxes), list(layout.inputs)
    ch, slot = _channels(model, T)
    sizes = [int(np.sum(model.candidates.channel_triax == t)) + 6 for t in T]
    offs = np.concatenate([[0], np.cumsum(sizes)]).astype(np.intp)
    n_tp = int(offs[-1])
    p = 10 + n_tp + 6 * len(J)
    info = np.zeros((p, p))
    rank: dict[int, int] = {}
    for i, c in enumerate(ch):
        s = int(slot[i])
        rk = rank.get(s, 0)
        rank[s] = rk + 1
        for k, j in enumerate(J):
            g = np.zeros(p)
            g[:10] = model.gx[c, j]
            o = 10 + int(offs[s])
            g[o : o + 6] = model.gtri[c, j, :6]
            g[o + 6 + rk] = model.gtri[c, j, 6]
            g[10 + n_tp + 6 * k : 16 + n_tp + 6 * k] = model.gin[c, j]
            info += np.outer(g, g)
    info[10:, 10:] += np.eye(p - 10)
    return info


def x_covariance(info: FloatArray, model: PlanModel) -> FloatArray:
    """``(J⁻¹)_xx`` in physical units plus the hammer's common scale."""
    from scipy.linalg import LinAlgError, cho_factor, cho_solve

    A = info[:10, :10] + _X_RIDGE * np.eye(10)
    try:  # Schur complement on the nuisances' block (positive definite: their priors)
        B = info[10:, :10]
        S = A - B.T @ cho_solve(cho_factor(info[10:, 10:]), B) if B.size else A
        cov_s = np.linalg.inv(S)
    except (LinAlgError, np.linalg.LinAlgError):
        full = info.copy()
        full[:10, :10] = A
        cov_s = np.linalg.pinv(full)[:10, :10]
    cov = cov_s * np.outer(model.x_scale, model.x_scale)
    f = model.errors.force_gain_rel
    return cov + f**2 * np.outer(model.x0, model.x0)


def layout_covariance(model: PlanModel, layout: Layout) -> FloatArray:
    """Predicted covariance of ``x = [m, m·c, I6 about P]`` for a layout, shape (10, 10)."""
    S = input_information(model, layout.triaxes)[list(layout.inputs)].sum(axis=0)
    S[10:, 10:] += np.eye(S.shape[0] - 10)
    return x_covariance(S, model)


def target_jacobian(model: PlanModel) -> FloatArray:
    """``∂t/∂x`` (7, 10) of the targets at ``model.x0``, by central differences
    ``(t(x + h e_i) − t(x − h e_i)) / 2h`` with ``h = 10⁻⁶ x_scale``."""
    x0 = model.x0
    h = 1e-6 * model.x_scale
    J = np.empty((7, 10))
    for i in range(10):
        e = np.zeros(10)
        e[i] = h[i]
        J[:, i] = (target_values(x0 + e) - target_values(x0 - e)) / (2 * h[i])
    return J


def _criterion_weights(model: PlanModel) -> FloatArray:
    t0 = target_values(model.x0)
    rho = model.radius_of_gyration_m
    return 1.0 / np.array([t0[0], rho, rho, rho, *t0[4:]]) ** 2


def _criterion(cov_x: FloatArray, jt: FloatArray, wt: FloatArray) -> float:
    ct = jt @ cov_x @ jt.T
    return float(np.sum(wt * np.diag(ct)))


@dataclass(frozen=True)
class Bounds:
    """Predicted 95 % bounds: ``mass_pct``, ``cg_mm`` (largest component), ``principal_pct``
    (largest relative principal-moment error), and the 1σ of each target."""

    mass_pct: float
    cg_mm: float
    principal_pct: float
    sigma: dict[str, Any] = field(default_factory=dict)

    def to_json(self) -> dict[str, Any]:
        return {
            "mass_pct": self.mass_pct,
            "cg_mm": self.cg_mm,
            "principal_pct": self.principal_pct,
        }


def predicted_bounds(model: PlanModel, cov_x: FloatArray) -> Bounds:
    """95 % bounds of the targets from the covariance of x (module docstring)."""
    jt = target_jacobian(model)
    ct = jt @ cov_x @ jt.T
    t0 = target_values(model.x0)
    mass = 100 * _Q95 * np.sqrt(max(ct[0, 0], 0.0)) / t0[0]
    cg = 1000 * _max_abs_q95(ct[1:4, 1:4])
    rel = ct[4:, 4:] / np.outer(t0[4:], t0[4:])
    pm = 100 * _max_abs_q95(rel)
    sig = np.sqrt(np.clip(np.diag(ct), 0, None))
    return Bounds(
        float(mass),
        float(cg),
        float(pm),
        {
            "mass_pct": float(100 * sig[0] / t0[0]),
            "cg_mm": (1000 * sig[1:4]).tolist(),
            "principal_pct": (100 * sig[4:] / t0[4:]).tolist(),
        },
    )


def _max_abs_q95(cov3: FloatArray) -> float:
    w, v = np.linalg.eigh(0.5 * (cov3 + cov3.T))
    L = v * np.sqrt(np.clip(w, 0, None))
    return float(np.quantile(np.abs(_Z @ L.T).max(axis=1), 0.95))


# ---------------------------------------------------------------------------------------------
# Selection
# ---------------------------------------------------------------------------------------------
def _pick(
    n: int,
    k: int,
    start: Sequence[int],
    cost: Any,
) -> list[int]:
    """Greedy from ``start`` to ``k`` items, then exchange (Fedorov) until no swap improves."""
    chosen = list(start)[:k]
    while len(chosen) < k:
        rest = [i for i in range(n) if i not in chosen]
        vals = [cost(chosen + [i]) for i in rest]
        chosen.append(rest[int(np.argmin(vals))])
    best = cost(chosen)
    improved = True
    while improved:
        improved = False
        for pos in range(len(chosen)):
            rest = [i for i in range(n) if i not in chosen]
            for i in rest:
                trial = chosen[:pos] + [i] + chosen[pos + 1 :]
                c = cost(trial)
                if c < best * (1 - 1e-9):
                    best, chosen, improved = c, trial, True
    return sorted(chosen)


def exchange_select(
    model: PlanModel, n_triaxes: int, n_inputs: int, *, max_rounds: int = 6
) -> Layout:
    """Greedy + exchange choice of ``n_triaxes`` triaxes and ``n_inputs`` inputs minimising the
    A-optimal criterion on the scaled targets (module docstring).

    Triaxes are chosen with every candidate input, then inputs for those triaxes, then both are
    exchanged in turn until neither changes.
    """
    cand = model.candidates
    if not 1 <= n_triaxes <= cand.n_triaxes:
        raise SetupError(
            f"--triaxes {n_triaxes}: the candidate setup has {cand.n_triaxes} triax nodes; "
            f"give 1 to {cand.n_triaxes}"
        )
    if not 1 <= n_inputs <= cand.n_inputs:
        raise SetupError(
            f"--inputs {n_inputs}: the candidate setup has {cand.n_inputs} inputs; give 1 to "
            f"{cand.n_inputs}"
        )
    jt = target_jacobian(model)
    wt = _criterion_weights(model)

    def triax_cost(info_t: FloatArray) -> Any:
        def cost(ts: list[int]) -> float:
            S = info_t[ts].sum(axis=0)
            S[10:, 10:] += np.eye(S.shape[0] - 10)
            return _criterion(x_covariance(S, model), jt, wt)

        return cost

    def input_cost(info_j: FloatArray) -> Any:
        def cost(js: list[int]) -> float:
            S = info_j[js].sum(axis=0)
            S[10:, 10:] += np.eye(S.shape[0] - 10)
            return _criterion(x_covariance(S, model), jt, wt)

        return cost

    inputs = list(range(cand.n_inputs))
    triaxes = _pick(cand.n_triaxes, n_triaxes, [], triax_cost(triax_information(model, inputs)))
    inputs = _pick(cand.n_inputs, n_inputs, [], input_cost(input_information(model, triaxes)))
    for _ in range(max_rounds):
        t_new = _pick(
            cand.n_triaxes, n_triaxes, triaxes, triax_cost(triax_information(model, inputs))
        )
        j_new = _pick(cand.n_inputs, n_inputs, inputs, input_cost(input_information(model, t_new)))
        if t_new == triaxes and j_new == inputs:
            break
        triaxes, inputs = t_new, j_new
    return Layout(tuple(triaxes), tuple(inputs))


def criterion(model: PlanModel, layout: Layout) -> float:
    """The selection criterion of a layout (smaller is better)."""
    return _criterion(
        layout_covariance(model, layout), target_jacobian(model), _criterion_weights(model)
    )


def random_layouts(
    n_candidates_t: int, n_candidates_in: int, k: int, m: int, n: int, seed: int | None
) -> list[Layout]:
    """``n`` layouts of ``k`` triaxes and ``m`` inputs drawn uniformly without replacement."""
    rng = np.random.default_rng(seed)
    return [
        Layout(
            tuple(sorted(int(i) for i in rng.choice(n_candidates_t, k, replace=False))),
            tuple(sorted(int(i) for i in rng.choice(n_candidates_in, m, replace=False))),
        )
        for _ in range(n)
    ]


def observability(model: PlanModel, layout: Layout) -> dict[str, Any]:
    """Condition number of the scaled information on x (nuisances marginalised) and the weak
    parameters: the components of its weakest direction, and each parameter's relative 1σ."""
    cov = layout_covariance(model, layout)
    f = model.errors.force_gain_rel
    cov_s = (cov - f**2 * np.outer(model.x0, model.x0)) / np.outer(model.x_scale, model.x_scale)
    w, v = np.linalg.eigh(0.5 * (cov_s + cov_s.T))
    info_w = 1.0 / np.clip(w, 1e-300, None)
    weak = v[:, -1]
    order = np.argsort(-np.abs(weak))
    names = ["m", "sx", "sy", "sz", *PARAMETERS[4:]]
    rel = np.sqrt(np.clip(np.diag(cov), 0, None)) / model.x_scale
    return {
        "condition_number": float(info_w.max() / info_w.min()),
        "weakest_direction": {names[i]: float(weak[i]) for i in order[:4]},
        "weak_parameters": [names[i] for i in order[:3] if abs(weak[i]) > 0.3],
        "relative_sigma": {n: float(r) for n, r in zip(names, rel, strict=True)},
        "note": "x = [m, m·c, I about P] scaled by m, m·ρ, m·ρ² (ρ the radius of gyration); "
        "relative_sigma is each one's 1σ over its scale",
    }


# ---------------------------------------------------------------------------------------------
# Simulated test of a layout (the Monte Carlo check)
# ---------------------------------------------------------------------------------------------
def _rotvecs(rng: np.random.Generator, n: int, sigma_deg: float) -> FloatArray:
    """Rotation matrices of rotation vectors with each component ~ N(0, σ), shape (n, 3, 3)."""
    from scipy.spatial.transform import Rotation

    v = rng.standard_normal((n, 3)) * np.deg2rad(sigma_deg)
    return np.asarray(Rotation.from_rotvec(v).as_matrix(), dtype=np.float64)


def simulated_frf(
    cand: Candidates,
    layout: Layout,
    props: RigidBodyProperties,
    errors: ErrorModel,
    n_lines: int,
    rng: np.random.Generator,
) -> tuple[NDArray[np.complex128], IntArray]:
    """FRFs of one simulated test of a layout: the true geometry is the candidates' (nominal)
    one with errors drawn from the error model, the transducers' gains likewise, and complex
    Gaussian noise of the error model's level is added on every line.

    Draws, in this order: per triax a position offset (each coordinate ~ N(0, σ_p)) and a rotation
    (rotation vector, each component ~ N(0, σ_o), as ``[geometry_uncertainty]`` defines it); per
    channel a relative gain ~ N(0, σ_a); per input a point offset and a rotation of its line of
    action (rotation vector ~ N(0, σ_loa) per component); one common hammer gain ~ N(0, σ_f); the
    noise.

    Returns
    -------
    H : ndarray, shape (n_lines, n_ch, n_in), complex
        Channels of the layout's triaxes in candidate order, its inputs in layout order.
    channels : ndarray, shape (n_ch,)
        Indices of those channels among the candidates'.
    """
    T = list(layout.triaxes)
    J = np.asarray(layout.inputs, dtype=np.intp)
    ch, slot = _channels_of(cand, T)
    P = cand.reference_point_m
    dpos = rng.standard_normal((len(T), 3)) * errors.sensor_position_m
    rot = _rotvecs(rng, len(T), errors.sensor_orientation_deg)
    gain = 1.0 + rng.standard_normal(ch.size) * errors.accel_gain_rel
    ipos = rng.standard_normal((J.size, 3)) * errors.input_position_m
    irot = _rotvecs(rng, J.size, errors.line_of_action_deg)
    fgain = 1.0 + rng.standard_normal() * errors.force_gain_rel
    r = cand.positions[ch] + dpos[slot] - P
    d = np.einsum("nij,nj->ni", rot[slot], cand.directions[ch])
    psi = np.concatenate([d, np.cross(r, d)], axis=1)
    e = np.einsum("nij,nj->ni", irot, cand.input_directions[J])
    p = cand.input_positions[J] + ipos - P
    phi = np.concatenate([e, np.cross(p, e)], axis=1).T
    H = gain[:, None] * (psi @ np.linalg.solve(props.mass_matrix(P), phi)) / fgain
    M = props.mass_matrix(P)
    d0, r0 = cand.directions, cand.positions - P
    e0, p0 = cand.input_directions[J], cand.input_positions[J] - P
    H0 = np.c_[d0, np.cross(r0, d0)] @ np.linalg.solve(M, np.c_[e0, np.cross(p0, e0)].T)
    rms = noise_scale(H0, errors.noise_model)[ch]
    z = rng.standard_normal((n_lines, *H.shape)) + 1j * rng.standard_normal((n_lines, *H.shape))
    out = H[None] + errors.noise * rms * z / np.sqrt(2)
    return np.asarray(out, dtype=np.complex128), ch


def trial_errors(
    estimate: FloatArray, props: RigidBodyProperties, point_m: FloatArray
) -> FloatArray:
    """Errors of one solve's ``x = [m, c (GCS), I6 about P]`` (``dimacq solve`` parameters):
    mass %, CG mm (3), principal moments % (3)."""
    est = np.asarray(estimate, float)
    P = np.asarray(point_m, float)
    xe = est.copy()
    xe[1:4] = (est[1:4] - P) * est[0]
    xt = props.parameter_vector(P)
    xt[1:4] *= xt[0]
    te, tt = target_values(xe), target_values(xt)
    return np.concatenate(
        [
            [100 * (te[0] - tt[0]) / tt[0]],
            1000 * (te[1:4] - tt[1:4]),
            100 * (te[4:] - tt[4:]) / tt[4:],
        ]
    )


def empirical_bounds(err: FloatArray) -> dict[str, float]:
    """95 % bounds of trial errors (rows: :func:`trial_errors`), the statistics
    :func:`predicted_bounds` predicts."""
    e = np.asarray(err, float)
    e = e[np.all(np.isfinite(e), axis=1)]
    if e.size == 0:
        return {"mass_pct": float("nan"), "cg_mm": float("nan"), "principal_pct": float("nan")}
    return {
        "mass_pct": float(np.quantile(np.abs(e[:, 0]), 0.95)),
        "cg_mm": float(np.quantile(np.abs(e[:, 1:4]).max(axis=1), 0.95)),
        "principal_pct": float(np.quantile(np.abs(e[:, 4:7]).max(axis=1), 0.95)),
    }
