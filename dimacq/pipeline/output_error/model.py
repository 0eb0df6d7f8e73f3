"""The output-error model: prediction, reduced statistics, residual and Jacobian.

Holds the rigid mass matrix of the ten properties (:func:`mass_matrix`) and how they follow the
gauge modes of the instrumentation (:func:`gauge_property_jacobian`), the problem of one fit
(:class:`Problem`: the geometry for corrections ``g``, the stacked residual with its analytic
Jacobian, the gauge basis) and the reduced statistics it is built from (:func:`reduced_statistics`).
The package's docstring (:mod:`dimacq.pipeline.output_error`) says why; the noise model is in
:mod:`.noise`, the gauge in :mod:`.fit`.

Model
-----
For input ``j`` at line ``ω`` the rigid-body motion of the reference point P and the accelerance of
accelerometer channel ``c`` (unit direction ``d_c`` at ``r_c``, both relative to P) are

    [a_j; α_j](ω) = M(x)⁻¹ ( φ_j(g) + Σ_k A_k(g) B_k(g) R_jk(ω) )
    Ĥ_cj(ω)       = ψ_c(g)ᵀ [a_j; α_j](ω) + Σ_k G_cjk b_k(ω),   ψ_c = [d_c; r_c × d_c]

with ``M(x) = [[m E, −m[c]x], [m[c]x, I_P]]`` the rigid mass matrix of the ten properties
(``c`` the CG relative to P, ``I_P`` about P), ``φ_j = [d_j; r_j × d_j]`` the unit input, ``R_jk`` the
measured reactions of load cell ``k`` mapped to P through its stated pose, and — with residual flexibility — free real coefficients
``G`` on the basis ``b(ω) = [(ω/ω_hi)², (ω/ω_hi)⁴]``: the stiffness-line share of elastic modes above
the band (``−ω²/(ω_r² − ω²) = −(ω/ω_r)² − (ω/ω_r)⁴ − …`` per mode) and below nothing else. The
estimate minimises

    Σ_jcω |Ĥ_cj − H_cj|² / σ_cj²  +  Σ_g (δg / σ_g)²

(a MAP / bundle-adjustment cost). ``σ_cj`` is the FRF noise (below); ``δg`` the geometry corrections
with their stated 1σ (:class:`~dimacq.model.setup.GeometryUncertainty`):

- each sensor node (triax): a small rotation ``δθ_n`` (3, rad; prior ``sensor_orientation_deg`` per
  axis) and a position offset ``δp_n`` (3, m; prior ``sensor_position_m``): ``d_c = exp([δθ_n]x) d_c⁰``,
  ``r_c = r_c⁰ + δp_n``;
- each input: its line of action turned about the two axes ``e₁, e₂`` normal to it (2, rad; prior
  ``line_of_action_deg``) and its point moved along ``e₁, e₂`` (2, m; prior ``input_position_m``; a
  move along the line of action changes nothing and is not a parameter);
- each load cell ``k`` at ``r_k`` (rel P) with stated local-to-global rotation ``Q⁰_k``: a small
  rotation ``δθ_k`` (3, rad; prior ``load_cell_orientation_deg``), an offset ``δp_k`` of its point
  (3, m; prior ``load_cell_position_m``) and relative gains ``γ_k`` of its three moment outputs
  (3; prior ``loadcell_matrix_rel``). With ``Q = exp([δθ_k]x)`` a stated reaction at P,
  ``[f; m_P] = [f; r_k × f + m_k]``, becomes ``[Q f; (r_k + δp_k) × Q f + Q m_k]``:

      A_k = [[Q, 0], [[r_k + δp_k]x Q − Q [r_k]x, Q]],   B_k = T_k diag(1, 1, 1, 1 + γ_k) T_k⁻¹

  with ``T_k = [[Q⁰, 0], [[r_k]x Q⁰, Q⁰]]`` the stated map of the cell's local outputs to P. The
  pose makes the translations and rotations of the whole instrumentation (sensors, inputs *and*
  cells) exact symmetries of the model again, and the scale one with the cells' moment gains
  moved alike (``γ_k = s``); the gauge's scale mode moves the cells' points but not their gains,
  so the lengths keep the stated scale and the gains take a moment-channel error (with the gains
  in it, the inner constraint shared the scale between lengths and gains by their priors: −0.5 %
  on the principal moments of an acquired Net F/T set with the default priors). So the
  fixed gauge (:func:`~dimacq.pipeline.output_error.fit.gauge_constraint`) holds what the data
  cannot see; with the cells exact, the reactions alone tie the scale of the sensors against the
  inputs', and an error in the reactions moved the principal moments through it. The moment
  gains take the error of a cell's moment channels (its calibration, its chain's response at
  the band's top), which otherwise went into that scale. The force gains are not refined: they
  trade with the mass and with the hammer's certificate where a cell carries much of the force
  (near the support modes, where the rigid model is least adequate), and a cell's force gain
  went 6 σ on an X-38 with the realistic geometry errors (model FRFs, exact cells); their
  certificate stays in the line weights (:func:`~dimacq.pipeline.output_error.noise.line_weights`).

Sufficient statistics (why it is fast)
--------------------------------------
With ``z_j(ω) = [1; R_j1(ω); …; R_jK(ω); b(ω); H_:j(ω)/σ_:j]`` the cost of input ``j`` is a quadratic form in the
real second-moment matrix ``S_j = Σ_ω Re(z_j z_jᴴ)`` (all lines of the band), so the number of lines
enters once. The free residual coefficients ``G`` are eliminated exactly by the Schur complement of
``S_j`` on the ``b`` block (variable projection). With ``S'_j = L_j L_jᵀ`` (eigen-factor, numerical
rank columns) the cost is ``‖L_jʰ − W_j Ψ M⁻¹ [φ_j, E] L_jʸ‖²_F``: a residual of ``n_ch × rank``
entries per input, whatever the number of lines (``E`` is ``[A_1 B_1, …, A_K B_K]`` with cells). Gauss–Newton / Levenberg–Marquardt on that
residual and the prior residuals with the analytic Jacobian:

- ``∂/∂x_k``: ``W Ψ M⁻¹ M_k G_j`` with ``G_j = M⁻¹ Y_j L_jʸ`` (``∂M⁻¹ = −M⁻¹ ∂M M⁻¹``);
- sensor node: ``−W_jc (∂ψ_c)ᵀ G_j``, ``∂ψ_c/∂δθ_i = [e_i × d_c; r_c × (e_i × d_c)]``,
  ``∂ψ_c/∂δp_i = [0; e_i × d_c]``;
- input: ``−W_j Ψ M⁻¹ ∂φ_j (L_jʸ)₀``, ``∂φ/∂β_i = [e_i × d; r × (e_i × d)]``, ``∂φ/∂γ_i = [0; e_i × d]``;
- load cell ``k``: ``−W_j Ψ M⁻¹ ∂(A_k B_k) (L_jʸ)_k`` on its rows of ``L_jʸ``:
  ``∂A/∂δθ_i = [[S, 0], [[r_k + δp_k]x S − S [r_k]x, S]]`` with ``S = [J_l e_i]x Q``,
  ``∂A/∂δp_i = [[0, 0], [[e_i]x Q, 0]]``, ``∂B/∂γ_o = T e_o e_oᵀ T⁻¹``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property
from typing import Any

import numpy as np
from numpy.typing import NDArray

from dimacq.pipeline._batched import cross3
from dimacq.pipeline.rigid_body import load_cell_transform, skew
from dimacq.pipeline.rotations import apply_rotvec, rotvec_to_matrix

FloatArray = NDArray[np.float64]
ComplexArray = NDArray[np.complex128]


EYE3 = np.eye(3)
#: Directions of the (bias-compensated) regressor moments below this fraction of the largest are
#: dropped (numerically null: no reaction in that direction).
_EIG_KEEP = 1e-12
#: Corrections per load cell in ``g``: rotation (3, rad), offset (3, m), relative gains of its three
#: local moment outputs Mx, My, Mz (3)
CELL_PARAMS = 9
#: Weight of the gauge constraint rows (whitened units: × the prior's unit weight); large enough
#: to hold the constraint to ~1e-6 of a prior σ against the data's pull.
_GAUGE_WEIGHT = 1e3


def _left_jacobian(rv: FloatArray) -> FloatArray:
    """Left Jacobian of SO(3), ``J_l(θ) = E + ½[θ]x + ⅙[θ]x²`` (series to second order; the
    corrections are small angles), shape (..., 3, 3)."""
    k = skew(rv)
    return np.asarray(EYE3 + 0.5 * k + (k @ k) / 6.0, float)


# ------------------------------------------------------------------------------------------
# Mass matrix of the ten properties
# ------------------------------------------------------------------------------------------
_IDX6 = ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))


def mass_matrix(x: FloatArray) -> tuple[FloatArray, FloatArray]:
    """``M(x)`` and its derivatives ``∂M/∂x_k``.

    Parameters
    ----------
    x : ndarray, shape (10,)
        ``[m, cx, cy, cz, Ixx, Ixy, Ixz, Iyy, Iyz, Izz]``, CG relative to P (m), inertia about P.

    Returns
    -------
    M : ndarray, shape (6, 6)
        ``[[m E, −m[c]x], [m[c]x, I_P]]``.
    dM : ndarray, shape (10, 6, 6)
    """
    m, c = x[0], x[1:4]
    M = np.zeros((6, 6))
    M[:3, :3] = m * EYE3
    M[:3, 3:] = -m * skew(c)
    M[3:, :3] = m * skew(c)
    dM = np.zeros((10, 6, 6))
    dM[0, :3, :3] = EYE3
    dM[0, :3, 3:] = -skew(c)
    dM[0, 3:, :3] = skew(c)
    for i in range(3):
        s = skew(EYE3[i])
        dM[1 + i, :3, 3:] = -m * s
        dM[1 + i, 3:, :3] = m * s
    for k, (a, b) in enumerate(_IDX6):
        M[3 + a, 3 + b] = M[3 + b, 3 + a] = x[4 + k]
        dM[4 + k, 3 + a, 3 + b] = dM[4 + k, 3 + b, 3 + a] = 1.0
    return M, dM


def gauge_property_jacobian(x: FloatArray) -> FloatArray:
    """How the ten properties follow the gauge modes of :meth:`Problem.gauge_basis`.

    Parameters
    ----------
    x : ndarray, shape (10,)
        ``[m, c (rel P, m), I_P (kg·m²)]``.

    Returns
    -------
    ndarray, shape (10, 8)
        ``∂x/∂(t, ω, s, g)``: a translation moves the CG, ``δc = t``, and the tensor about P by
        the parallel-axis term ``δI_P = m (2 c·t E − t cᵀ − c tᵀ)``; a rotation turns both,
        ``δc = ω × c``, ``δI_P = [ω]x I_P − I_P [ω]x``; a scale ``s`` of lengths with the same
        FRFs gives ``δc = s c``, ``δI_P = 2 s I_P`` (moment arms ×(1+s), angular accelerations
        ÷(1+s)); a common gain ``g`` on every accelerometer's prediction ``(1+g) ψ M⁻¹ φ`` is
        undone by ``M → (1+g) M``: ``δm = g m``, ``δI_P = g I_P``.
    """
    m, c = float(x[0]), np.asarray(x[1:4], float)
    M, _ = mass_matrix(np.asarray(x, float))
    Ip = M[3:, 3:]
    out = np.zeros((10, 8))

    def put(col: int, dc: FloatArray, dI: FloatArray, dm: float = 0.0) -> None:
        out[0, col] = dm
        out[1:4, col] = dc
        out[4:, col] = [dI[a, b] for a, b in _IDX6]

    for i in range(3):
        t = EYE3[i]
        put(i, t, m * (2 * (c @ t) * EYE3 - np.outer(t, c) - np.outer(c, t)))
        w = skew(EYE3[i])
        put(3 + i, cross3(EYE3[i], c), w @ Ip - Ip @ w)
    put(6, c, 2 * Ip)
    put(7, np.zeros(3), Ip, m)
    return out


# ------------------------------------------------------------------------------------------
# Problem
# ------------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class _Linearisation:
    """What the Jacobian of :meth:`Problem.residual` is taken at: the corrections ``g``, the
    channel (C, 3) and input (J, 3) positions and directions they give, Ψ (C, 6), the weights
    ``wt`` (J, C, 1), ``W Ψ A⁻¹`` (J, C, 6), ``G = A⁻¹ Y L_y`` (J, 6, k) and the cells' maps
    (:meth:`Problem.cell_maps`; None without load cells)."""

    g: FloatArray
    r: FloatArray
    d: FloatArray
    rin: FloatArray
    din: FloatArray
    psi: FloatArray
    wt: FloatArray
    WPA: FloatArray
    G: FloatArray
    cells: tuple[FloatArray, FloatArray, FloatArray, FloatArray] | None


class _Columns:
    """The data rows of a Jacobian, ``D`` (J, C, k, n_columns), and where each geometry item's
    column is: ``n_x`` + its place among the free items, or none (a fixed item has no column).

    Each writer takes an item's ``∂E/∂g`` and writes ``∂E/∂g · σ_g`` into its column, on the
    rows the item moves: one item per channel (:meth:`channels`), per input (:meth:`inputs`) or
    one item on every row (:meth:`dense`).
    """

    def __init__(self, D: FloatArray, prob: Problem, n_x: int) -> None:
        self.D = D
        self.sigma = prob.sigma_g
        self.col = np.full(prob.sigma_g.size, -1, np.intp)
        self.col[prob.free_g] = n_x + np.arange(prob.free_g.size)

    def free(self, item: int) -> bool:
        return bool(self.col[item] >= 0)

    def channels(self, items: NDArray[np.intp], sens: FloatArray) -> None:
        """Channel ``c``'s item ``items[c]`` moves rows (·, c, ·): ``sens`` (J, C, k)."""
        c = np.nonzero(self.col[items] >= 0)[0]
        it = items[c]
        self.D[:, c, :, self.col[it]] = np.moveaxis(
            sens[:, c] * self.sigma[it][None, :, None], 1, 0
        )

    def inputs(self, items: NDArray[np.intp], sens: FloatArray) -> None:
        """Input ``j``'s item ``items[j]`` moves rows (j, ·, ·): ``sens`` (J, C, k)."""
        j = np.nonzero(self.col[items] >= 0)[0]
        it = items[j]
        self.D[j, :, :, self.col[it]] = sens[j] * self.sigma[it][:, None, None]

    def dense(self, item: int, sens: FloatArray) -> None:
        """``item`` moves every row: ``sens`` (J, C, k)."""
        self.D[..., self.col[item]] = sens * self.sigma[item]


@dataclass(eq=False)
class Problem:
    """Everything the cost needs, in SI units relative to P."""

    r0: FloatArray  # (C, 3) channel positions rel P
    d0: FloatArray  # (C, 3) channel directions
    node_of: NDArray[np.intp]  # (C,) index of the channel's node
    nodes: NDArray[np.int64]  # (Nn,)
    rin0: FloatArray  # (J, 3)
    din0: FloatArray  # (J, 3)
    ebasis: FloatArray  # (J, 2, 3) unit vectors normal to each line of action
    w: FloatArray  # (C, J) 1/σ
    Ly: FloatArray  # (J, 1 + 6K, k)
    Lh: FloatArray  # (J, C, k)  (already weighted by 1/σ)
    free_x: NDArray[np.intp]
    x_fixed: FloatArray  # (10,)
    free_g: NDArray[np.intp]  # indices into the full geometry vector
    sigma_g: FloatArray  # (n_geom_full,) prior σ
    #: gauge constraint rows on the free geometry (k, n_free_g), whitened units; empty: none
    gauge_rows: FloatArray = field(default_factory=lambda: np.zeros((0, 0)))
    #: the fixed modes as combinations of the live gauge columns (n_live, k)
    gauge_modes: FloatArray = field(default_factory=lambda: np.zeros((0, 0)))
    gauge_live: NDArray[np.bool_] = field(default_factory=lambda: np.zeros(8, bool))
    gauge_information_ratio: FloatArray = field(default_factory=lambda: np.zeros(0))
    #: (K, 3) the load cells' stated points rel P and (K, 3, 3) their stated local-to-global
    #: rotations; their corrections (rotation 3, offset 3, gains of the three local moment
    #: outputs 3 per cell: :data:`CELL_PARAMS`) sit between the inputs' and the channel gains'
    #: in ``g``
    cell_r0: FloatArray = field(default_factory=lambda: np.zeros((0, 3)))
    cell_rot0: FloatArray = field(default_factory=lambda: np.zeros((0, 3, 3)))
    #: the last :func:`line_residual` (its key, the arrays it was computed from, the residual,
    #: then its sum of squares once :func:`weighted_direct_cost` formed it): the variance factor, the
    #: geometry test and χ² ask for the same one
    line_residual_memo: tuple[Any, ...] | None = field(default=None, repr=False)

    @property
    def n_nodes(self) -> int:
        return int(self.nodes.size)

    @property
    def n_cells(self) -> int:
        return int(self.cell_r0.shape[0])

    @property
    def cell_base(self) -> int:
        """Index in ``g`` of the first load cell's first correction."""
        return 6 * self.n_nodes + 4 * int(self.rin0.shape[0])

    @property
    def gain_base(self) -> int:
        """Index in ``g`` of the first channel gain."""
        return self.cell_base + CELL_PARAMS * self.n_cells

    @cached_property
    def _cell_local(self) -> tuple[FloatArray, FloatArray]:
        """``T_k`` and ``T_k⁻¹`` (K, 6, 6): the stated map of cell ``k``'s local outputs to P
        (:func:`~dimacq.pipeline.rigid_body.load_cell_transform` without the cell's sign, which
        cancels in ``T D T⁻¹``); the stated geometry's, so computed once."""
        T = np.array(
            [
                load_cell_transform(r, q, np.zeros(3))
                for r, q in zip(self.cell_r0, self.cell_rot0, strict=True)
            ]
        ).reshape(-1, 6, 6)
        # its inverse [[Qᵀ, 0], [−Qᵀ[r]x, Qᵀ]] in closed form
        Q0t = np.swapaxes(self.cell_rot0, 1, 2)
        Ti = np.zeros_like(T)
        Ti[:, :3, :3] = Ti[:, 3:, 3:] = Q0t
        Ti[:, 3:, :3] = -Q0t @ skew(self.cell_r0)
        return T, Ti

    def cell_maps(self, g: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
        """``A_k B_k`` (K, 6, 6): cell ``k``'s reactions at P as stated, ``R_k = [f; m_P]``, to
        those of the cell turned by ``δθ_k``, moved by ``δp_k`` and with its three local moment
        outputs scaled by ``1 + γ_k`` (module docstring); ``A_k``,
        ``B_k = T_k diag(1, 1, 1, 1 + γ_k) T_k⁻¹`` and the rotations ``Q_k = exp([δθ_k]x)``
        (K, 3, 3)."""
        K = self.n_cells
        gc = g[self.cell_base : self.gain_base].reshape(K, CELL_PARAMS)
        Q = rotvec_to_matrix(gc[:, :3]).reshape(K, 3, 3)
        r = self.cell_r0
        A = np.zeros((K, 6, 6))
        A[:, :3, :3] = Q
        A[:, 3:, 3:] = Q
        A[:, 3:, :3] = skew(r + gc[:, 3:6]) @ Q - Q @ skew(r)
        T, Ti = self._cell_local
        gains = np.concatenate([np.zeros((K, 3)), gc[:, 6:9]], axis=1)  # forces: as calibrated
        B = (T * (1.0 + gains[:, None, :])) @ Ti
        return A @ B, A, B, Q

    def reactions_at_p(self, g: FloatArray, R: ComplexArray) -> ComplexArray:
        """``Σ_k A_k R_k`` (L, 6, J) from the cells' stacked reactions ``R`` (L, 6K, J)."""
        K = self.n_cells
        if not K:
            return np.zeros((R.shape[0], 6, R.shape[2]), complex)
        A = self.cell_maps(g)[0]
        Rk = R.reshape(R.shape[0], K, 6, R.shape[2])
        return np.asarray(np.einsum("kab,lkbj->laj", A, Rk), complex)

    def geometry(self, g: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
        """Channel positions/directions and input positions/directions for corrections ``g``."""
        nn = self.n_nodes
        gs = g[: 6 * nn].reshape(nn, 6)
        gi = g[6 * nn : 6 * nn + 4 * self.rin0.shape[0]].reshape(-1, 4)
        d = apply_rotvec(gs[self.node_of, :3], self.d0)
        r = self.r0 + gs[self.node_of, 3:]
        axis = np.einsum("ji,jik->jk", gi[:, :2], self.ebasis)
        din = apply_rotvec(axis, self.din0)
        rin = self.rin0 + np.einsum("ji,jik->jk", gi[:, 2:], self.ebasis)
        return r, d, rin, din

    def full_x(self, theta: FloatArray) -> FloatArray:
        x = self.x_fixed.copy()
        x[self.free_x] = theta[: self.free_x.size]
        return x

    def full_g(self, theta: FloatArray) -> FloatArray:
        g = np.zeros(self.sigma_g.size)
        g[self.free_g] = theta[self.free_x.size :] * self.sigma_g[self.free_g]
        return g

    def residual(
        self, theta: FloatArray, jacobian: bool = True
    ) -> tuple[FloatArray, FloatArray | None]:
        """Stacked residual (data then prior) and, optionally, its Jacobian in θ.

        θ = [free properties; free geometry corrections / their prior σ].
        """
        x = self.full_x(theta)
        g = self.full_g(theta)
        r, d, rin, din = self.geometry(g)
        M, dM = mass_matrix(x)
        A = np.linalg.inv(M)
        psi = np.concatenate([d, cross3(r, d)], axis=1)  # (C, 6)
        phi = np.concatenate([din, cross3(rin, din)], axis=1)  # (J, 6)
        cells = self.cell_maps(g) if self.n_cells else None
        Ycell = np.concatenate(list(cells[0]), axis=1) if cells is not None else np.zeros((6, 0))
        Y = np.concatenate(
            [phi[:, :, None], np.broadcast_to(Ycell, (phi.shape[0], 6, Ycell.shape[1]))], 2
        )
        G = A @ (Y @ self.Ly)  # (J, 6, k)
        C0 = psi.shape[0]
        gain = 1.0 + g[g.size - C0 :]
        wt = self.w.T[:, :, None] * np.reshape(gain, (1, -1, 1))  # (J, C, 1): 1/σ × channel gain
        pred = wt * (psi @ G)  # (J, C, k)
        E = self.Lh - pred  # (J, C, k)
        n_data = E.size
        prior = theta[self.free_x.size :]
        n_c = self.gauge_rows.shape[0] if prior.size else 0
        gauge = _GAUGE_WEIGHT * (self.gauge_rows @ prior) if n_c else np.zeros(0)
        res = np.concatenate([E.ravel(), prior, gauge])
        if not jacobian:
            return res, None
        n_x, n_g = self.free_x.size, self.free_g.size
        Jac = np.zeros((n_data + n_g + n_c, n_x + n_g))
        # properties
        WPA = wt * (psi @ A)[None]  # (J, C, 6)
        for col, k in enumerate(self.free_x):
            Jac[:n_data, col] = ((WPA @ dM[k]) @ G).ravel()
        if n_g:
            lin = _Linearisation(g, r, d, rin, din, psi, wt, WPA, G, cells)
            self._geometry_jacobian(Jac, E.shape, n_c, lin)
        return res, Jac

    def _geometry_jacobian(
        self, Jac: FloatArray, shape: tuple[int, ...], n_c: int, lin: _Linearisation
    ) -> None:
        """Write the geometry columns of the Jacobian ``Jac`` (data rows of ``shape`` (J, C, k),
        then the prior's identity and the ``n_c`` gauge rows), in whitened units ``g / σ_g``.

        The sensitivities ``∂E/∂g`` of every geometry item (sensor nodes, inputs, load cells,
        channel gains) are scaled by ``σ_g`` and written straight into the columns of the free
        items (:class:`_Columns`): an item touches only its own rows (a sensor node those of its
        channels, an input its own, a gain its channel's), and nothing is formed over the full
        geometry vector.
        """
        J_, C_, k_ = shape
        n_data = J_ * C_ * k_
        n_x, n_g = self.free_x.size, self.free_g.size
        cols = _Columns(Jac[:n_data].reshape(J_, C_, k_, Jac.shape[1]), self, n_x)
        self._node_sensitivities(cols, lin)
        self._input_sensitivities(cols, lin)
        if lin.cells is not None:
            self._cell_sensitivities(cols, lin)
        if self.sigma_g.size > self.gain_base:  # channel gains (relative)
            cols.channels(
                self.gain_base + np.arange(C_), -(self.w.T[:, :, None] * (lin.psi @ lin.G))
            )
        Jac[n_data : n_data + n_g, n_x:] = np.eye(n_g)
        if n_c:
            Jac[n_data + n_g :, n_x:] = _GAUGE_WEIGHT * self.gauge_rows

    def _node_sensitivities(self, cols: _Columns, lin: _Linearisation) -> None:
        """``∂E/∂g`` of each sensor node's rotation (3) and offset (3):
        ``−W_jc dψ_c[p]ᵀ G_j``, with ``∂(exp([θ]x) d⁰)/∂θ_i = (J_l(θ) e_i) × d`` and
        ``J_l`` the left Jacobian of SO(3)."""
        nn = self.n_nodes
        r, d = lin.r, lin.d
        C_ = r.shape[0]
        rv = lin.g[: 6 * nn].reshape(nn, 6)[:, :3]
        jl = _left_jacobian(rv)[self.node_of]  # (C, 3, 3), columns J_l e_i
        ex_d = cross3(np.swapaxes(jl, 1, 2), d[:, None, :])  # (C, 3, 3): (J_l e_i) × d_c
        dpsi = np.zeros((C_, 6, 6))
        dpsi[:, :3, :3] = ex_d
        dpsi[:, :3, 3:] = cross3(r[:, None, :], ex_d)
        dpsi[:, 3:, 3:] = cross3(EYE3[None, :, :], d[:, None, :])  # e_i × d_c (offsets)
        for p in range(6):  # each channel belongs to one node: no two writes collide
            cols.channels(6 * self.node_of + p, -lin.wt * (dpsi[:, p, :] @ lin.G))

    def _input_sensitivities(self, cols: _Columns, lin: _Linearisation) -> None:
        """``∂E/∂g`` of each input's line-of-action turns ``β`` (2) and point offsets ``γ`` (2)
        along the two normals ``e_ji``: ``∂φ_j`` through ``(J_l e_i) × d_j``, on the input's
        column of ``L_jʸ``."""
        nn = self.n_nodes
        rin, din = lin.rin, lin.din
        J_ = rin.shape[0]
        gi = lin.g[6 * nn : 6 * nn + 4 * self.rin0.shape[0]].reshape(-1, 4)
        ax = np.einsum("ji,jik->jk", gi[:, :2], self.ebasis)
        jli = _left_jacobian(ax)  # (J, 3, 3)
        eb_l = np.einsum("jab,jib->jia", jli, self.ebasis)  # J_l e_i for the two normals
        exd = cross3(eb_l, din[:, None, :])  # (J, 2, 3)
        dphi = np.zeros((J_, 4, 6))
        dphi[:, :2, :3] = exd
        dphi[:, :2, 3:] = cross3(rin[:, None, :], exd)
        dphi[:, 2:, 3:] = exd
        base = 6 * nn + 4 * np.arange(J_)
        ly0 = self.Ly[:, None, 0, :]  # (J, 1, k)
        for p in range(4):
            cols.inputs(base + p, -(lin.WPA @ dphi[:, p, :, None]) * ly0)

    def _cell_sensitivities(self, cols: _Columns, lin: _Linearisation) -> None:
        """``∂E/∂g`` of load cell ``k``'s rotation (3), offset (3) and moment gains (3):
        ``−W ψ A⁻¹ ∂(A_k B_k) L_kʸ`` on its block of ``L_jʸ``, with
        ``∂B/∂γ_o = T e_o e_oᵀ T⁻¹`` for the local outputs ``o = Mx, My, Mz``."""
        assert lin.cells is not None
        _ABc, Ac, Bc, Qc = lin.cells
        K = self.n_cells
        gc = lin.g[self.cell_base : self.gain_base].reshape(K, CELL_PARAMS)
        jlc = _left_jacobian(gc[:, :3])  # (K, 3, 3)
        rk = self.cell_r0 + gc[:, 3:6]
        T, Ti = self._cell_local
        for k in range(K):
            lyk = self.Ly[:, 1 + 6 * k : 7 + 6 * k, :]  # (J, 6, k)
            for i in range(CELL_PARAMS):
                item = self.cell_base + CELL_PARAMS * k + i
                if not cols.free(item):
                    continue
                dA = np.zeros((6, 6))
                if i < 3:
                    dQ = skew(jlc[k][:, i]) @ Qc[k]
                    dA[:3, :3] = dQ
                    dA[3:, 3:] = dQ
                    dA[3:, :3] = skew(rk[k]) @ dQ - dQ @ skew(self.cell_r0[k])
                    dAB = dA @ Bc[k]
                elif i < 6:
                    dA[3:, :3] = skew(EYE3[i - 3]) @ Qc[k]
                    dAB = dA @ Bc[k]
                else:  # ∂B/∂γ = T e_o e_oᵀ T⁻¹, local output o = Mx, My, Mz
                    o = i - 3
                    dAB = Ac[k] @ np.outer(T[k][:, o], Ti[k][o])
                cols.dense(item, -(lin.WPA @ (dAB @ lyk)))

    def gauge_basis(self) -> FloatArray:
        """The similarity of the whole instrumentation and the common accelerometer gain, as
        directions in the full geometry vector ``g`` (n_geom_full, 8), load cells included.

        Columns: translation ``t`` (3), rotation ``ω`` about P (3), scale ``s`` of the positions
        about P (1), common relative gain of every accelerometer channel (1). A sensor node at
        ``r_n`` moves by ``δp_n = t + ω × r_n + s r_n`` and turns by ``δθ_n = ω``; an input at
        ``r_j`` with normals ``e_ji`` gets ``β_ji = ω · e_ji`` and ``γ_ji = (t + ω × r_j +
        s r_j) · e_ji``. With the body's properties moved alike (:func:`gauge_property_jacobian`)
        the FRFs do not change, except through the load cells' reactions (taken as exact).
        """
        nn, J = self.n_nodes, self.rin0.shape[0]
        G = np.zeros((self.sigma_g.size, 8))
        rn = np.zeros((nn, 3))
        np.add.at(rn, self.node_of, self.r0)
        rn /= np.bincount(self.node_of, minlength=nn)[:, None]
        Gn = G[: 6 * nn].reshape(nn, 6, 8)  # rows of sensor node n: δp (3), δθ (3)
        Gj = G[6 * nn : 6 * nn + 4 * J].reshape(J, 4, 8)  # rows of input k: β (2), γ (2)
        eb = np.asarray(self.ebasis)  # (J, 2, 3)
        for i in range(3):  # over the three axes; nodes and inputs at once (same bits as per item)
            e = EYE3[i]
            Gn[:, 3:6, i] = e
            Gn[:, i, 3 + i] = 1.0
            Gn[:, 3:6, 3 + i] = cross3(e, rn)
            be = eb @ e  # (J, 2)
            Gj[:, 2:4, i] = be
            Gj[:, 0:2, 3 + i] = be
            Gj[:, 2:4, 3 + i] = (eb @ cross3(e, self.rin0)[:, :, None])[:, :, 0]
        Gn[:, 3:6, 6] = rn
        Gj[:, 2:4, 6] = (eb @ np.asarray(self.rin0)[:, :, None])[:, :, 0]
        # load cell k at r_k: δθ_k = ω, δp_k = t + ω × r_k + s r_k. Under the scale the cell's own
        # moments would need γ_k = s too for an exact symmetry; the gains are left out of the
        # mode on purpose (model.py, module docstring): fixed with them, the inner constraint
        # shares the scale between the lengths and the gains by their priors, and a cell's
        # moment-channel error (1–2 % on the acquired Net F/T sets) moved the lengths' scale and
        # the principal moments (−0.5 % with the default 2 mm priors); without them the lengths
        # keep the stated scale and the gains take the cell's error
        Gc = G[self.cell_base : self.gain_base].reshape(self.n_cells, CELL_PARAMS, 8)
        for i in range(3):
            e = EYE3[i]
            Gc[:, 3:6, i] = e
            Gc[:, i, 3 + i] = 1.0
            Gc[:, 3:6, 3 + i] = cross3(e, self.cell_r0)
        Gc[:, 3:6, 6] = self.cell_r0
        G[self.gain_base :, 7] = 1.0
        return G


def reduced_statistics(
    H: ComplexArray,
    R: ComplexArray,
    sigma: FloatArray,
    cov_R: FloatArray,
    basis: ComplexArray | None,
    lw: FloatArray | None = None,
) -> tuple[FloatArray, FloatArray, float]:
    """Factors ``L_jʸ`` (J, n_y, k) and ``T_j`` (J, C, k) of the reduced statistics (module
    docstring), and the part of the cost that no parameter changes (for χ²).

    ``lw`` (L, J): line weights (:func:`line_weights`); the residual of line ``ℓ`` and input
    ``j`` is ``w_ℓj (H − Ĥ)/σ``, so ``z_j`` is scaled by ``w_ℓj`` (its prediction is linear in
    ``z_j``) and the statistics keep their form. The reactions' noise compensation is scaled by
    the mean ``w²`` of the input."""
    L, C, J = H.shape
    if lw is not None:
        cov_R = cov_R * np.mean(lw**2, axis=0)[:, None, None]
    nb = 0 if basis is None else basis.shape[1]
    ny = 1 + R.shape[1]  # [1; R_j]: the unit input and each load cell's six reactions
    # z_j = [w; w R_j; b; w H_:j/σ] (w = 1 without line weights), written straight into its real
    # and imaginary parts as (J, n, L) arrays: the products of Σ_ω Re(z zᴴ) = Zr Zrᵀ + Zi Ziᵀ.
    # The numbers are those of the complex expressions (w·(1+0i), R·w, H/σ = H·(1/σ) in numpy's
    # complex division, H·(w/σ)) up to the sign of a zero, which no product or sum sees.
    n = ny + nb + C
    zr = np.empty((J, n, L))
    zi = np.empty((J, n, L))
    w = None if lw is None else lw.T[:, None, :]  # (J, 1, L)
    zr[:, 0:1] = 1.0 if w is None else w
    zi[:, 0:1] = 0.0
    Rt = np.transpose(R, (2, 1, 0))  # (J, 6, L), complex view
    zr[:, 1:ny] = Rt.real if w is None else Rt.real * w
    zi[:, 1:ny] = Rt.imag if w is None else Rt.imag * w
    if basis is not None:
        zr[:, ny : ny + nb] = basis.real.T[None]
        zi[:, ny : ny + nb] = basis.imag.T[None]
    scale = (1.0 / sigma).T[:, :, None] if w is None else w / sigma.T[:, :, None]  # (J, C, L)
    Ht = np.transpose(H, (2, 1, 0))  # (J, C, L)
    np.multiply(Ht.real, scale, out=zr[:, ny + nb :])
    np.multiply(Ht.imag, scale, out=zi[:, ny + nb :])
    S = zr @ np.swapaxes(zr, 1, 2) + zi @ np.swapaxes(zi, 1, 2)  # Σ_ω Re(z zᴴ), (J, n, n)
    dsc = np.sqrt(np.clip(np.einsum("jii->ji", S), 1e-300, None))  # equilibration (raw S)
    S[:, 1:ny, 1:ny] -= cov_R  # bias compensation of the noisy reactions (already × n_ω or rank)
    if nb:
        a = np.r_[0:ny, ny + nb : ny + nb + C]
        b = np.arange(ny, ny + nb)
        Sab = S[:, a][:, :, b]
        Sbb = S[:, b][:, :, b]
        S = S[:, a][:, :, a] - Sab @ np.linalg.solve(Sbb, np.swapaxes(Sab, 1, 2))
        dsc = dsc[:, a]
    # cost_j = tr(S_hh) − 2 tr(B S_yh) + tr(B S_yy Bᵀ) = ‖B L_y − T‖² + tr(S_hh) − ‖T‖²
    # with S_yy = L_y L_yᵀ (n_y × k) and T = S_hy L_y⁺ᵀ: n_y columns per channel, whatever n_ω.
    d = dsc[:, :ny]
    lam, V = np.linalg.eigh(S[:, :ny, :ny] / (d[:, :, None] * d[:, None, :]))
    keep = lam > np.clip(lam.max(axis=1, keepdims=True), 0, None) * _EIG_KEEP
    sq = np.sqrt(np.where(keep, lam, 1.0))
    Ly = np.where(keep[:, None, :], d[:, :, None] * V * sq[:, None, :], 0.0)
    T = np.where(keep[:, None, :], (S[:, ny:, :ny] / d[:, None, :]) @ V / sq[:, None, :], 0.0)
    const = np.einsum("jii->j", S[:, ny:, ny:]) - np.einsum("jck,jck->j", T, T)
    return Ly, T, float(np.sum(const))
