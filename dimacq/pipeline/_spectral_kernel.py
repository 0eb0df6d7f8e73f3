"""The FRF estimator's sums over averages for one block of outputs, in one pass (compiled).

For a block of output spectra ``Y[a, o, l]`` (averages ``a``, outputs ``o``, lines ``l``) and
the conjugated input spectra ``F̄[a, i, l]``:

    G_yf[o, i, l] = Σ_a Y[a, o, l] F̄[a, i, l]
    G_yy[o, l]    = Σ_a |Y[a, o, l]|²
    A[o, i, l]    = |G_yf[o, i, l]|² = Re² + Im²

(:mod:`dimacq.pipeline.frf_estimation` explains the estimators built from them). numpy does
this as one complex multiply and one add per average and input, then a sum of squares: three
passes over the block, 5 ms of a 17 ms H1 at 64 outputs x 10 averages x 8192 samples. The loop
below reads each spectrum value once (the block is in cache, just written by the FFT), with the
lines innermost so the compiler vectorises it; the additions run in the same order as numpy's
(average 0, 1, 2, …), so the sums are numpy's own to rounding (tests compare them to 1e-15).

Compiled by numba on first use, cached on disk beside this module (or in the user's cache when
that is not writable): the first call of a new install takes ~0.5 s, later processes load it in
~0.15 s. Imported lazily by the estimator, once a process has summed more than
:data:`~dimacq.pipeline.frf_estimation.NUMPY_SUMS_BUDGET` products with numpy's equivalent (the
same bits): commands that estimate few FRFs or none (``dimacq solve``, an impact test) do not
load numba. No fast-math, no fused multiply-add: NaN and infinity propagate as in numpy, which the
estimator's finite-sample check relies on.
"""

from __future__ import annotations

import numba
import numpy as np
from numpy.typing import NDArray

__all__ = ["block_sums"]


@numba.njit(cache=True, fastmath=False, boundscheck=False, error_model="numpy", nogil=True)
def _block_sums(
    y: NDArray[np.float64],
    fc: NDArray[np.float64],
    g: NDArray[np.float64],
    g_abs2: NDArray[np.float64],
    g_yy: NDArray[np.float64],
) -> None:  # pragma: no cover - compiled; exercised through block_sums
    n_avg, n_out, n_pairs = y.shape
    n_in = fc.shape[1]
    n_lines = n_pairs // 2
    for o in range(n_out):
        yy = g_yy[o]
        for line in range(n_lines):
            yy[line] = 0.0
        for i in range(n_in):
            gi = g[o, i]
            for k in range(n_pairs):
                gi[k] = 0.0
        for a in range(n_avg):
            s = y[a, o]
            for line in range(n_lines):
                yr = s[2 * line]
                yi = s[2 * line + 1]
                yy[line] += yr * yr + yi * yi
            for i in range(n_in):
                f = fc[a, i]
                gi = g[o, i]
                for line in range(n_lines):
                    yr = s[2 * line]
                    yi = s[2 * line + 1]
                    fr = f[2 * line]
                    fi = f[2 * line + 1]
                    gi[2 * line] += yr * fr - yi * fi
                    gi[2 * line + 1] += yr * fi + yi * fr
        for i in range(n_in):
            gi = g[o, i]
            ai = g_abs2[o, i]
            for line in range(n_lines):
                re = gi[2 * line]
                im = gi[2 * line + 1]
                ai[line] = re * re + im * im


def block_sums(
    spectra: NDArray[np.complex128],
    inputs_conj: NDArray[np.complex128],
    g: NDArray[np.complex128],
    g_abs2: NDArray[np.float64],
    g_yy: NDArray[np.float64],
) -> None:
    """Fill ``g``, ``g_abs2`` and ``g_yy`` with the block's sums (module docstring), in place.

    Parameters
    ----------
    spectra : ndarray, shape (n_averages, n_outputs, n_lines), complex
        ``Y``; each (average, output) row contiguous.
    inputs_conj : ndarray, shape (n_averages, n_inputs, n_lines), complex
        ``F̄``, contiguous.
    g : ndarray, shape (n_outputs, n_inputs, n_lines), complex
        Out: ``G_yf``; rows contiguous.
    g_abs2 : ndarray, shape (n_outputs, n_inputs, n_lines)
        Out: ``|G_yf|²``.
    g_yy : ndarray, shape (n_outputs, n_lines)
        Out: ``G_yy``.
    """
    _block_sums(
        spectra.view(np.float64),
        inputs_conj.view(np.float64),
        g.view(np.float64),
        g_abs2,
        g_yy,
    )
