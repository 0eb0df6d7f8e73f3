"""Batched products the pipeline repeats on every frequency line, as BLAS matrix products.

``np.einsum`` without ``optimize`` runs its own loop over every index; for a real geometry matrix
applied to complex FRFs over all lines and inputs that loop cost more than the rest of a solve
(0.7 s of ``dimacq solve``'s 1.3 s on an acquired 24 × 24 × 2048-line test). These
helpers give the same sums (to rounding: the order of the additions differs) through ``matmul``.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

__all__ = ["cross3", "real_apply"]


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


def cross3(a: NDArray[np.floating], b: NDArray[np.floating]) -> NDArray[np.float64]:
    """``np.cross(a, b)`` of 3-vectors on the last axis, broadcast, to the bit.

    ``a × b = (a₁b₂ − a₂b₁, a₂b₀ − a₀b₂, a₀b₁ − a₁b₀)``: the products and differences numpy's
    ``cross`` forms, in the same order, without its axis moves and checks (~0.2 ms of Python per
    call; the output-error fit calls it hundreds of times on a dozen vectors).
    """
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    out = np.empty((*np.broadcast_shapes(a0.shape, b0.shape), 3))
    np.subtract(a1 * b2, a2 * b1, out=out[..., 0])
    np.subtract(a2 * b0, a0 * b2, out=out[..., 1])
    np.subtract(a0 * b1, a1 * b0, out=out[..., 2])
    return out
