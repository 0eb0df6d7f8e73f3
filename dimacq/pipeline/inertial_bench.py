"""The accelerometers of the inertial bench: their relative gains, and what they do to ``C``.

Why it matters
--------------
The inertial calibration (:func:`~dimacq.pipeline.loadcell_calibration.inertial_calibration`)
computes the cell's loads from the calibration mass's motion, ``F_L = T_c⁻¹ M_rb a_P`` with
``a_P = T_q H`` condensed from the accelerometers. A channel read with a certificate off by
``δ_i`` (measured ``(1 + δ_i)`` times the truth) changes the loads by

    ``δF_L = K(δ) F_L,    K(δ) = T_c⁻¹ M_rb T_q diag(δ) Ψ M_rb⁻¹ T_c``        (6×6)

so the fitted matrix becomes ``(E + K(δ)) C``. A common scale ``δ_i = s`` gives ``K = s E``
(``T_q Ψ = E``): the matrix is ``s`` off, no more. The *differences* between channels are
amplified: a load through the cell turns the mass about the cell far more than it translates it
(on the thesis mass, 1 N at the cell gives 1.6 rad/s² but 0.055 m/s²), so its force is the small
difference of large rotational terms ``m(ü_P − [c]× θ̈)``, and 0.5 % certificates scattered over 24
axes put 0.85 % into ``C`` — not the ``0.5 %/√24`` of an average.

Relative gains from the rigid body
----------------------------------
On the bench the calibration mass is a rigid body: with correction gains ``g`` (true = ``g_i`` ×
measured) every FRF column ``h`` (one line, one input) satisfies ``Q diag(h) g = 0``,
``Q = E − Ψ Ψ⁺`` the projector off the rigid-body motions. The gains minimising the rigid-body
residual over all lines and inputs, ``Σ‖Q diag(h) g‖²``, are the eigenvector of the smallest
eigenvalue ``λ₁`` of

    ``N = Q ⊙ Re Σ h̄ hᵀ``        (n_ch × n_ch, ⊙ element-wise: ``diag(h̄) Q diag(h) = Q ⊙ h̄hᵀ``)

determined up to one common scale (the data cannot see it: every channel ×(1+s) is still a rigid
motion). For a general array ``λ₁`` is the only small eigenvalue; ``λ₁/λ₂`` tells how well the
gains are identified, and the scale is fixed by the certificates: the weighted mean of the
log-gains is that of the certificates, ``Σ w_i ln g_i = 0`` with ``w_i = 1/σ_i²``, whose error is
the weighted mean of the certificate errors, standard uncertainty ``u_s = (Σ w_i)^(-1/2)``
(0.1 % for 24 axes at 0.5 %). The data's part of the gains' covariance is the homogeneous least
squares one, ``σ_r² N_⊥⁺`` with ``σ_r² = λ₁ / (n_eq − n_ch + 1)``; the scale adds ``u_s² 11ᵀ``.

Where the gains are not identified (``λ₁/λ₂`` above :data:`MAX_SEPARATION`: too few inputs or a
degenerate array) they stay at the certificates (``g = 1``) and the covariance is the
certificates' own, ``diag(σ²)``: the matrix's uncertainty then shows the amplification.

The matrix's uncertainty
------------------------
From the gains: ``δC = Σ_i δ_i J_i``, ``J_i = (T_c⁻¹ M_rb t_i)(ψ_iᵀ M_rb⁻¹ T_c C)`` (``t_i``
column ``i`` of ``T_q``), so ``Var C_ab = Σ_ij J_i[ab] Cov_ij J_j[ab]``
(:func:`matrix_gain_variance`). From the fit: the jackknife over inputs
(:func:`jackknife_matrix_variance`: ``C`` re-fitted with each input left out,
``Var = (n−1)/n Σ (C_(j) − C̄)²``). The fit's residuals are not independent noise (neighbouring
lines share their errors, the gauges' hysteresis is systematic), and inputs on two faces only
leave a load combination weakly excited: with 12 of the 24 thesis inputs (two faces) the matrix
is 0.4 % off where the residuals' formula says 0.01 %; the jackknife says 0.7–0.9 %.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from dimacq.errors import DataError
from dimacq.pipeline.loadcell_calibration import inertial_loads

__all__ = [
    "MAX_SEPARATION",
    "ChannelGains",
    "jackknife_matrix_variance",
    "matrix_gain_variance",
    "rigid_body_gains",
]

FloatArray = NDArray[np.float64]

#: ``λ₁/λ₂`` above this: the rigid-body residual does not single out the gains.
MAX_SEPARATION = 0.05


@dataclass(frozen=True, eq=False)
class ChannelGains:
    """Correction gains of the response channels (true = gain × measured).

    Attributes
    ----------
    gains : ndarray, shape (n_ch,)
        Weighted log-mean 1 (the certificates' scale).
    covariance : ndarray, shape (n_ch, n_ch)
        Of the relative gain errors: the data's part plus the scale's ``u_s² 11ᵀ`` (or the
        certificates' ``diag(σ²)`` when not identified).
    scale_std : float
        ``u_s``: standard uncertainty of the common scale, relative.
    separation : float
        ``λ₁/λ₂`` (small: gains well identified).
    residual_rel : float
        rms rigid-body residual after correction, relative to the corrected responses.
    identified : bool
        False: ``separation`` above :data:`MAX_SEPARATION`, gains left at 1.
    """

    gains: FloatArray
    covariance: FloatArray
    scale_std: float
    separation: float
    residual_rel: float
    identified: bool

    @property
    def relative_std(self) -> FloatArray:
        """Standard uncertainty of each gain, relative (scale included)."""
        return np.sqrt(np.diag(self.covariance))


def rigid_body_gains(
    accel_frf: ArrayLike,
    psi: ArrayLike,
    certificate_rel: float | ArrayLike,
) -> ChannelGains:
    """Relative gains of the response channels from the rigid-body residual (module docstring).

    Parameters
    ----------
    accel_frf : array_like, shape (n_lines, n_ch, n_inputs), complex
        Accelerances of a rigid body over the lines used (any consistent unit).
    psi : array_like, shape (n_ch, 6)
        Rigid-body response matrix ``Ψ`` (:func:`~dimacq.pipeline.rigid_body.response_matrix`).
    certificate_rel : float or array_like, shape (n_ch,)
        1σ relative uncertainty of each channel's certificate sensitivity.

    Returns
    -------
    ChannelGains
    """
    H = np.asarray(accel_frf)
    Psi = np.asarray(psi, dtype=float)
    if H.ndim != 3 or Psi.ndim != 2 or H.shape[1] != Psi.shape[0] or Psi.shape[1] != 6:
        raise DataError(
            f"accel_frf {H.shape} and psi {Psi.shape}: give (n_lines, n_ch, n_inputs) FRFs and "
            "the (n_ch, 6) rigid-body matrix of the same channels"
        )
    n = Psi.shape[0]
    sig = np.broadcast_to(np.asarray(certificate_rel, dtype=float), (n,)).copy()
    if np.any(sig <= 0):
        raise DataError("certificate_rel: give a positive relative uncertainty per channel")
    if not np.all(np.isfinite(H)):
        raise DataError("accel_frf contains NaN/inf; drop the lines or inputs with lost samples")
    w = 1.0 / sig**2
    Q = np.eye(n) - Psi @ np.linalg.pinv(Psi)
    # Σ h̄ hᵀ over lines and inputs, in real arithmetic: Re(h̄hᵀ) = Re h Re hᵀ + Im h Im hᵀ
    re = H.real.transpose(1, 0, 2).reshape(n, -1)
    im = H.imag.transpose(1, 0, 2).reshape(n, -1)
    S = re @ re.T + im @ im.T
    N = Q * S
    lam, V = np.linalg.eigh(N)
    lam = np.maximum(lam, 0.0)
    sep = float(lam[0] / lam[1]) if lam[1] > 0 else np.inf
    scale_var = 1.0 / float(w.sum())
    n_eq = 2 * re.shape[1] * (n - 6)
    if n <= 6 or not sep <= MAX_SEPARATION or n_eq <= n:
        g = np.ones(n)
        return ChannelGains(
            g, np.diag(sig**2), float(np.sqrt(scale_var)), sep, _residual(N, S, g), False
        )
    v = V[:, 0] * np.sign(V[:, 0].sum())  # unit eigenvector, ∝ g
    if np.any(v <= 0):
        raise DataError(
            "the rigid-body fit gives a channel a negative gain: a sensor's polarity or direction "
            "in the setup is wrong; check the response directions"
        )
    g = v / np.exp(np.sum(w * np.log(v)) / w.sum())
    # the data's covariance of ln g: the jackknife over inputs (each left out in turn: N is a
    # sum over inputs), which also sees residuals that are not white noise (the geometry, the
    # body's flexibility); with fewer than 4 inputs the homogeneous least squares one,
    # Cov δv = σ_r² N_⊥⁺ (δv = Σ_k≥2 v_k v_kᵀ δN v / (λ₁ − λ_k)), δ ln g_i = δv_i / v_i
    n_in = H.shape[2]
    if n_in >= 4:
        re3 = np.ascontiguousarray(H.real.transpose(2, 1, 0))  # (n_inputs, n_ch, n_lines)
        im3 = np.ascontiguousarray(H.imag.transpose(2, 1, 0))
        S_j = re3 @ re3.transpose(0, 2, 1) + im3 @ im3.transpose(0, 2, 1)
        logs = np.empty((n_in, n))
        for j in range(n_in):
            vj = np.linalg.eigh(Q * (S - S_j[j]))[1][:, 0]
            logs[j] = np.log(np.abs(vj) / np.exp(np.sum(w * np.log(np.abs(vj))) / w.sum()))
        d = logs - logs.mean(axis=0)
        cov_log = (n_in - 1) / n_in * d.T @ d
    else:
        sigma_r2 = lam[0] / (n_eq - n + 1)
        Vp = V[:, 1:]
        cov_log = sigma_r2 * ((Vp / lam[1:]) @ Vp.T) / np.outer(v, v)
    P = np.eye(n) - np.outer(np.ones(n), w) / w.sum()
    cov = P @ cov_log @ P.T + scale_var * np.ones((n, n))
    return ChannelGains(g, cov, float(np.sqrt(scale_var)), sep, _residual(N, S, g), True)


def _residual(N: FloatArray, S: FloatArray, g: FloatArray) -> float:
    """``√(gᵀNg / gᵀSg)``: rms rigid-body residual relative to the corrected responses."""
    return float(np.sqrt(max(float(g @ N @ g), 0.0) / max(float(g @ S @ g), np.finfo(float).tiny)))


def matrix_gain_variance(
    matrix: ArrayLike,
    gain_covariance: ArrayLike,
    transform: ArrayLike,
    psi: ArrayLike,
    mass_matrix: ArrayLike,
    cell_transform: ArrayLike,
) -> FloatArray:
    """Variance of each element of ``C`` from the response channels' gain errors.

    ``Var C_ab = Σ_ij J_i[ab] Cov_ij J_j[ab]``, ``J_i = u_i v_iᵀ``, ``u_i = T_c⁻¹ M_rb t_i``,
    ``v_i = Cᵀ T_cᵀ M_rb⁻ᵀ ψ_i`` (module docstring).

    Parameters
    ----------
    matrix : array_like, shape (6, 12)
        ``C``.
    gain_covariance : array_like, shape (n_ch, n_ch)
        Of the relative gain errors (:attr:`ChannelGains.covariance`).
    transform : array_like, shape (6, n_ch)
        ``T_q`` used to condense (with the gains applied or not: first order alike).
    psi : array_like, shape (n_ch, 6)
    mass_matrix : array_like, shape (6, 6)
        ``M_rb`` about P.
    cell_transform : array_like, shape (6, 6)
        ``s T_c`` (:func:`~dimacq.pipeline.rigid_body.load_cell_transform`).

    Returns
    -------
    ndarray, shape (6, 12)
    """
    C = np.asarray(matrix, dtype=float)
    Cov = np.asarray(gain_covariance, dtype=float)
    Tq = np.asarray(transform, dtype=float)
    Psi = np.asarray(psi, dtype=float)
    M = np.asarray(mass_matrix, dtype=float)
    T = np.asarray(cell_transform, dtype=float)
    U = np.linalg.solve(T, M) @ Tq  # (6, n_ch): u_i as columns
    Vv = Psi @ np.linalg.solve(M, T) @ C  # (n_ch, 12): v_iᵀ as rows
    X = U.T[:, :, None] * Vv[:, None, :]  # (n_ch, 6, 12)
    return np.asarray(np.einsum("iab,ij,jab->ab", X, Cov, X))


def jackknife_matrix_variance(
    gauge_frf: ArrayLike,
    accel_p: ArrayLike,
    mass_matrix: ArrayLike,
    cell_position_m: ArrayLike,
    cell_rotation: ArrayLike,
    reference_point_m: ArrayLike,
    *,
    sign: float = 1.0,
    rank: int = 6,
) -> FloatArray | None:
    """Jackknife variance over inputs of the inertial calibration's ``C``.

    ``C_(j)`` is :func:`~dimacq.pipeline.loadcell_calibration.inertial_calibration` without
    input ``j`` (rank ``rank``), computed from the inputs' Gram matrices (12×12 per input, no
    refit over the lines); ``Var C_ab = (n − 1)/n Σ_j (C_(j),ab − C̄_ab)²``.

    Parameters
    ----------
    gauge_frf : array_like, shape (n_lines, 12, n_inputs), complex
    accel_p : array_like, shape (n_lines, 6, n_inputs), complex
    mass_matrix, cell_position_m, cell_rotation, reference_point_m, sign
        As :func:`~dimacq.pipeline.loadcell_calibration.inertial_calibration`.

    Returns
    -------
    ndarray, shape (6, 12), or None with fewer than 4 inputs (nothing to leave out).
    """
    g = np.asarray(gauge_frf)
    n = g.shape[2]
    if n < 4:
        return None
    F = inertial_loads(
        accel_p, mass_matrix, cell_position_m, cell_rotation, reference_point_m, sign
    )
    # C G = F stacks real and imaginary parts over lines and inputs; the rank-6 solution
    # C = F V₆ Σ₆⁻¹ U₆ᵀ = (F Gᵀ) U₆ Σ₆⁻² U₆ᵀ needs only the sums over inputs of
    # A_j = G_j G_jᵀ and B_j = F_j G_jᵀ: leaving input j out subtracts its terms
    gr = np.ascontiguousarray(g.real.transpose(2, 1, 0))  # (n, 12, n_lines)
    gi = np.ascontiguousarray(g.imag.transpose(2, 1, 0))
    fr = np.ascontiguousarray(F.real.transpose(2, 1, 0))  # (n, 6, n_lines)
    fi = np.ascontiguousarray(F.imag.transpose(2, 1, 0))
    A_j = gr @ gr.transpose(0, 2, 1) + gi @ gi.transpose(0, 2, 1)  # (n, 12, 12)
    B_j = fr @ gr.transpose(0, 2, 1) + fi @ gi.transpose(0, 2, 1)  # (n, 6, 12)
    A = A_j.sum(axis=0) - A_j
    B = B_j.sum(axis=0) - B_j
    lam, U = np.linalg.eigh(A)  # ascending
    U6 = U[:, :, -rank:]
    P = (U6 / lam[:, None, -rank:]) @ U6.transpose(0, 2, 1)  # U₆ Σ₆⁻² U₆ᵀ
    Cs = B @ P
    d = Cs - Cs.mean(axis=0)
    return np.asarray((n - 1) / n * np.sum(d**2, axis=0))
