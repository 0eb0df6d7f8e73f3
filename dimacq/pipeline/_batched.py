"""Batched products the pipeline repeats on every frequency line, as BLAS matrix products.

``np.einsum`` without ``optimize`` runs its own loop over every index; for a real geometry matrix
applied to complex FRFs over all lines and inputs that loop cost more than the rest of a solve
(issue #27: 0.7 s of ``dimacq solve``'s 1.3 s on an acquired 24 × 24 × 2048-line test). These
helpers give the same sums (to rounding: the order of the additions differs) through ``matmul``.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

__all__ = ["real_apply"]


def real_apply(B: NDArray[np.floating], F: NDArray[np.complexfloating]) -> NDArray[np.complex128]:
    """``B F`` for a real ``B`` and complex ``F``, batched over ``F``'s leading axes.

    ``out[..., c, j] = Σ_k B[..., c, k] F[..., k, j]`` (``np.einsum("ck,lkj->lcj", B, F)``).
    A real matrix times a complex one is two real products, ``B Re F + i B Im F``; viewing ``F``'s
    last axis as interleaved (re, im) pairs makes them one real ``matmul``.

    Parameters
    ----------
    B : ndarray, shape (..., c, k), real
    F : ndarray, shape (..., k, J), complex

    Returns
    -------
    ndarray, shape (..., c, J), complex128
    """
    Fc = np.ascontiguousarray(F, dtype=np.complex128)
    out = np.matmul(np.asarray(B, dtype=np.float64), Fc.view(np.float64))
    return np.ascontiguousarray(out).view(np.complex128)
