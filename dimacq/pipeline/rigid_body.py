"""Rigid-body condensation of responses and summation of forces at a reference point P.

Kinematics (method.md §4, thesis Eq. 23–26): a point at ``r`` (relative to P) of a rigid body
moves by ``u = u_P + θ × r``, so a channel measuring along unit ``d`` sees

    q = dᵀ u_P + (r × d)ᵀ θ,    i.e. row ``[dᵀ, (r × d)ᵀ]`` of Ψ (n_channels × 6),

and the motion of P is ``K = [ü_P; θ̈] = Ψ⁺ q`` (least squares; rank Ψ = 6 needed).

Forces (method.md §5, Eq. 27–29): a force ``f`` along unit ``d`` at ``r`` is ``F_P = f [d; r × d]``;
a 6-DOF load cell at ``r_c`` with local-to-global rotation ``R`` that reads ``[f_L; m_L]`` about its
own origin contributes ``F_P = s [R f_L; R m_L + r_c × R f_L]`` with ``s = +1`` for loads on the
structure and ``−1`` for loads on the support. All forces on the structure are summed.

Perimeter filtering (Eq. 30–31): with a 0/1 (or any non-negative) diagonal weight W,
``q_f = Ψ (WΨ)⁺ W q_m``, and the rigid-body error of channel i is ``|q_m,i − q_f,i| / |q_f,i|``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from dimacq.errors import SetupError
from dimacq.model.properties import skew
from dimacq.pipeline._batched import cross3

__all__ = [
    "Condensation",
    "condense",
    "filtered_responses",
    "force_vectors",
    "load_cell_transform",
    "response_matrix",
    "skew",
]

FloatArray = NDArray[np.float64]


def response_matrix(
    positions: NDArray[np.floating],
    directions: NDArray[np.floating],
    reference_point: NDArray[np.floating],
) -> FloatArray:
    """Rigid-body shape matrix Ψ, shape (n_channels, 6): rows ``[dᵀ, ((r − P) × d)ᵀ]``.

    Parameters
    ----------
    positions : ndarray, shape (n_channels, 3)
    directions : ndarray, shape (n_channels, 3), unit vectors
    reference_point : ndarray, shape (3,)
    """
    r = np.asarray(positions, float) - np.asarray(reference_point, float)
    d = np.asarray(directions, float)
    return np.concatenate([d, cross3(r, d)], axis=1)


def force_vectors(
    positions: NDArray[np.floating],
    directions: NDArray[np.floating],
    reference_point: NDArray[np.floating],
) -> FloatArray:
    """Unit 6-DOF force vectors at P of the inputs, shape (6, n_inputs): columns ``[d; (r − P) × d]``."""
    r = np.asarray(positions, float) - np.asarray(reference_point, float)
    d = np.asarray(directions, float)
    return np.concatenate([d, cross3(r, d)], axis=1).T


def load_cell_transform(
    position: NDArray[np.floating],
    rotation: NDArray[np.floating],
    reference_point: NDArray[np.floating],
    sign: float = 1.0,
) -> FloatArray:
    """6×6 map from a load cell's local ``[f_L; m_L]`` to the load at P: ``s [[R, 0], [[r]x R, R]]``."""
    r = np.asarray(position, float) - np.asarray(reference_point, float)
    R = np.asarray(rotation, float)
    t = np.zeros((6, 6))
    t[:3, :3] = R
    t[3:, 3:] = R
    t[3:, :3] = skew(r) @ R
    return sign * t


@dataclass(frozen=True)
class Condensation:
    """Least-squares condensation of responses to the 6 rigid-body DOFs of P.

    Attributes
    ----------
    psi : ndarray, shape (n_channels, 6)
    transform : ndarray, shape (6, n_channels)
        ``(WΨ)⁺ W``: maps measured responses to ``[ü_P; θ̈]``.
    rank : int
    condition_number : float
        Of the weighted Ψ (in the working length unit).
    """

    psi: FloatArray
    transform: FloatArray
    rank: int
    condition_number: float
    singular_values: FloatArray


def condense(
    psi: NDArray[np.floating],
    weights: NDArray[np.floating] | None = None,
    names: list[str] | None = None,
) -> Condensation:
    """Build the condensation ``T = (WΨ)⁺ W`` and refuse a response set of rank < 6.

    Parameters
    ----------
    psi : ndarray, shape (n_channels, 6)
    weights : ndarray, shape (n_channels,), optional
        Non-negative channel weights (0 drops a channel).
    """
    psi_f: FloatArray = np.asarray(psi, dtype=np.float64)
    psi = psi_f
    w = np.ones(psi.shape[0]) if weights is None else np.asarray(weights, float)
    wp = psi * w[:, None]
    u, s, vt = np.linalg.svd(wp, full_matrices=False)
    tol = s.max(initial=0.0) * max(wp.shape) * np.finfo(float).eps * 10
    rank = int(np.sum(s > tol))
    if rank < 6:
        used = int(np.sum(w > 0))
        null = vt[-1]
        dof = ("x", "y", "z", "rx", "ry", "rz")[int(np.argmax(np.abs(null)))]
        raise SetupError(
            f"the response set ({used} channels) has rigid-body rank {rank} < 6: motion along "
            f"'{dof}' of the reference point cannot be seen; add channels in other directions or at "
            "points off the lines they measure along (at least 3 per global direction, not collinear)"
        )
    transform = (vt.T / s) @ u.T * w[None, :]
    return Condensation(psi_f, transform, rank, float(s[0] / s[-1]), s)


def filtered_responses(
    psi: NDArray[np.floating],
    q: NDArray[np.complexfloating],
    weights: NDArray[np.floating] | None = None,
) -> NDArray[np.complex128]:
    """Rigid-body filtered responses ``q_f = Ψ (WΨ)⁺ W q`` (Eq. 30).

    Parameters
    ----------
    psi : ndarray, shape (n_channels, 6)
    q : ndarray, shape (n_lines, n_channels, n_inputs)
    """
    c = condense(psi, weights)
    return np.asarray(np.einsum("ck,lkj->lcj", c.psi @ c.transform, q), dtype=complex)
