"""FRF estimation from time records: H1, H2, Hv, multiple inputs, coherence, windows, Welch.

Notation (one frequency line ω, averages a = 1..n_a, column vectors):
``F_a`` input spectra, shape (n_inputs,); ``Y_a`` output spectra, shape (n_outputs,). The
averaged cross-spectral matrices are

    G_ff = Σ_a F_a F_aᴴ            shape (n_inputs, n_inputs)
    G_yf = Σ_a Y_a F_aᴴ            shape (n_outputs, n_inputs)
    G_yy = Σ_a |Y_a|²              shape (n_outputs,)   (diagonal only)

(the common scale factor 1/(n_a · Σw²) of a one-sided spectral density cancels in every FRF and
coherence, so it is left out). The estimators:

- **H1** (noise on the outputs): ``H1 = G_yf G_ff⁻¹``; for one input ``H1 = G_yf / G_ff``.
  With several inputs this is the multiple-input estimator (Bendat & Piersol, ch. 7); the inputs
  must be partially uncorrelated, which the condition number of ``G_ff`` per line reports.
- **H2** (noise on the input, one input only): ``H2 = G_yy / G_fy`` with ``G_fy = conj(G_yf)``.
- **Hv** (total least squares, equal noise weighting on inputs and outputs): for each output the
  Hermitian matrix ``G_c = Σ_a z_a z_aᴴ`` with ``z_a = [F_a; Y_a,o]`` is built; its eigenvector
  ``v`` of the smallest eigenvalue gives ``H_o = −conj(v[:n_in]) / conj(v[n_in])`` (the row
  ``r = [H_o, −1]`` minimising ``Σ_a |r z_a|² / |r|²``). For one input this is the classic
  ``Hv = (G_yy − G_ff + sqrt((G_ff − G_yy)² + 4|G_fy|²)) / (2 G_fy)``.
- **Ordinary coherence** ``γ²_oj = |G_yf,oj|² / (G_yy,o G_ff,jj)``; **multiple coherence**
  ``γ²_o = (G_yf G_ff⁻¹ G_fy)_oo / G_yy,o = Re(Σ_j H1_oj conj(G_yf,oj)) / G_yy,o``. With one input
  they are equal.
- **Too few averages**: with ``n_averages ≤ n_inputs`` the spectral matrices have rank
  ``n_averages`` and the multiple coherence is 1 identically (one average: ``|Y F̄|² = |Y|²|F|²``),
  whatever the noise; it then carries no information and is returned as NaN (ordinary coherence
  likewise with one average), never as 1.

Windows for impact testing (:func:`force_window`, :func:`exponential_window`) and Welch's
overlapped segments for random excitation (:func:`welch_segments`) prepare the records; the
estimator itself (:func:`estimate_frf`) is vectorised over averages, outputs, inputs and lines.

Exponential window and damping
------------------------------
Multiplying a free decay ``e^{−σ t}`` (``σ = ζ ω_n``) by ``w(t) = e^{−t/τ}`` gives a decay with
``σ' = σ + 1/τ``: every mode looks more damped. A modal parameter estimated from the windowed FRF
is corrected by ``σ = σ' − 1/τ`` at unchanged damped frequency, ``ζ ≈ ζ' − 1/(τ ω_n)``
(:func:`exponential_window_damping_correction` does it exactly). More precisely, when the same
window multiplies input and output (``y·w = (h·w) * (f·w)`` because
``e^{−t/τ} = e^{−(t−s)/τ} e^{−s/τ}``), the estimate is the true FRF evaluated off the axis:
``H_w(iω) = H(iω + 1/τ)``: poles shift by ``−1/τ``, residues are unchanged. A rigid body's
accelerance (a constant mass line) is therefore unchanged; the suspension and elastic modes
around the DIM band are only more damped, which is why DIM can use windowed impact FRFs.
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from dataclasses import dataclass
from typing import Literal

import ducc0
import numpy as np
from numpy.typing import ArrayLike, NDArray

from dimacq.errors import DataError, SetupError

__all__ = [
    "FrfEstimate",
    "double_hit_mask",
    "estimate_frf",
    "exponential_window",
    "exponential_window_damping_correction",
    "force_window",
    "welch_segments",
]

Estimator = Literal["H1", "H2", "Hv"]


@dataclass(frozen=True, eq=False)
class FrfEstimate:
    """FRFs estimated from averaged records, with their quality measures.

    Attributes
    ----------
    frequencies_hz : ndarray, shape (n_lines,)
        ``k · fs / n_samples`` for ``k = 0 .. n_samples // 2``.
    H : ndarray, shape (n_lines, n_outputs, n_inputs), complex
        FRF output/input in the records' engineering units (e.g. (m/s²)/N).
    coherence : ndarray, shape (n_lines, n_outputs)
        Multiple coherence of each output on all inputs (equals the ordinary coherence for one
        input). 1 means a noise-free linear relation; NaN where ``G_yy = 0`` and everywhere when
        ``n_averages ≤ n_inputs`` (it would be 1 identically).
    ordinary_coherence : ndarray, shape (n_lines, n_outputs, n_inputs)
    input_condition : ndarray, shape (n_lines,)
        2-norm condition number of ``G_ff`` per line (1 for one input): large values mean the
        inputs are correlated and the multiple-input H1 is ill-determined.
    g_ff : ndarray, shape (n_lines, n_inputs, n_inputs), complex
        Summed input cross-spectra (unscaled, see module docstring).
    g_yy : ndarray, shape (n_lines, n_outputs)
        Summed output autospectra (unscaled).
    n_averages : int
    estimator : {"H1", "H2", "Hv"}

    Notes
    -----
    ``H`` (H1, H2), ``g_yy`` and ``ordinary_coherence`` are views of one buffer (the estimator
    computes them in place): keeping one keeps the others' memory.
    """

    frequencies_hz: NDArray[np.float64]
    H: NDArray[np.complex128]
    coherence: NDArray[np.float64]
    ordinary_coherence: NDArray[np.float64]
    input_condition: NDArray[np.float64]
    g_ff: NDArray[np.complex128]
    g_yy: NDArray[np.float64]
    n_averages: int
    estimator: str


def _as_records(name: str, data: ArrayLike) -> NDArray[np.float64]:
    arr = np.asarray(data, dtype=float)
    if arr.ndim == 2:
        arr = arr[None]
    if arr.ndim != 3:
        raise DataError(
            f"{name} has shape {arr.shape}; give (n_averages, n_channels, n_samples) "
            "or (n_channels, n_samples) for one average"
        )
    return arr


def _check_finite(name: str, arr: NDArray[np.float64]) -> None:
    if not np.all(np.isfinite(arr)):
        raise DataError(f"{name} contains NaN or infinite samples; reject that average first")


def _check_request(
    x: NDArray[np.float64],
    y: NDArray[np.float64],
    sample_rate_hz: float,
    estimator: str,
    workers: int,
) -> None:
    """Refuse records and settings :func:`estimate_frf` cannot use, naming the fix."""
    if x.shape[0] != y.shape[0] or x.shape[2] != y.shape[2]:
        raise DataError(
            f"inputs {x.shape} and outputs {y.shape} must share n_averages and n_samples"
        )
    if sample_rate_hz <= 0:
        raise SetupError(f"sample_rate_hz = {sample_rate_hz}; give a positive sample rate")
    n_avg, n_in, _n_s = x.shape
    if estimator not in ("H1", "H2", "Hv"):
        raise SetupError(f"estimator {estimator!r} is unknown; use 'H1', 'H2' or 'Hv'")
    if estimator == "H2" and n_in != 1:
        raise SetupError(
            f"estimator 'H2' needs one input, got {n_in}; use 'H1' or 'Hv' for multiple inputs"
        )
    if n_in > 1 and n_avg < n_in:
        raise DataError(
            f"{n_in} inputs need at least {n_in} averages for the multiple-input estimator, "
            f"got {n_avg}; acquire more averages"
        )
    if workers < 1:
        raise SetupError(f"workers = {workers}; give 1 or more FFT threads")


def _estimates(
    g_ff: NDArray[np.complex128],
    g_yf: NDArray[np.complex128],
    g_yy: NDArray[np.float64],
    g_yf_abs2: NDArray[np.float64],
    estimator: str,
    fused: str | None,
) -> tuple[NDArray[np.complex128], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """FRF, ordinary and multiple coherence and cond(G_ff) from the summed spectra.

    ``γ²_yf = |G_yf|² / (G_yy G_ff)`` (written over ``g_yf_abs2``);
    ``H1 = G_yf G_ff⁻¹``, multiple coherence ``Re Σ_f H1 Ḡ_yf / G_yy`` clipped to [0, 1]; ``Hv``
    by :func:`_hv`. With ``fused`` (one input, H1 or H2) :func:`_spectral_sums` has already
    turned ``g_yf`` into the FRF and ``g_yf_abs2`` into the coherence, block by block while
    each block was in cache; multiple and ordinary coherence are equal for one input (module
    docstring) and share that memory.
    """
    g_ff_diag = np.real(np.diagonal(g_ff, axis1=1, axis2=2))  # (L, n_in)
    n_in = g_ff.shape[1]
    with np.errstate(divide="ignore", invalid="ignore"):
        if fused is not None:
            h = g_yf
            ordinary = g_yf_abs2
            multiple = g_yf_abs2[:, :, 0]
            cond = np.ones(g_ff.shape[0])
        else:
            if n_in == 1:
                cond = np.ones(g_ff.shape[0])
            else:
                s = np.linalg.svd(g_ff, compute_uv=False)
                cond = s[:, 0] / s[:, -1]
            ordinary = np.divide(g_yf_abs2, g_yy[:, :, None] * g_ff_diag[:, None, :], out=g_yf_abs2)
            if estimator == "Hv":
                h = _hv(g_ff, g_yf, g_yy)
            if n_in == 1:
                multiple = ordinary[:, :, 0].copy()
            else:
                # H1 = G_yf G_ff⁻¹  ⇔  G_ffᵀ H1ᵀ = G_yfᵀ (G_ff Hermitian), batched over lines.
                h1 = np.asarray(
                    np.linalg.solve(g_ff.transpose(0, 2, 1), g_yf.transpose(0, 2, 1)).transpose(
                        0, 2, 1
                    ),
                    dtype=np.complex128,
                )
                multiple = np.real(np.sum(h1 * g_yf.conj(), axis=2)) / g_yy
                if estimator == "H1":
                    h = h1
            np.clip(multiple, 0.0, 1.0, where=np.isfinite(multiple), out=multiple)
    return h, ordinary, multiple, cond


def estimate_frf(
    inputs: ArrayLike,
    outputs: ArrayLike,
    sample_rate_hz: float,
    *,
    estimator: Estimator = "H1",
    input_window: ArrayLike | None = None,
    output_window: ArrayLike | None = None,
    workers: int = 1,
) -> FrfEstimate:
    """Estimate FRFs (outputs per input) from averaged time records.

    Parameters
    ----------
    inputs : array_like, shape (n_averages, n_inputs, n_samples)
        Excitation records (forces, N), one per average; a 2-D array is one average.
    outputs : array_like, shape (n_averages, n_outputs, n_samples)
        Response records taken at the same samples.
    sample_rate_hz : float
    estimator : {"H1", "H2", "Hv"}
        H2 needs exactly one input.
    input_window, output_window : array_like, shape (n_samples,), optional
        Time windows multiplied into the input and output records (e.g. ``force_window(...) *
        exponential_window(...)`` for the hammer and ``exponential_window(...)`` for responses;
        a Hann window for random data). Default: rectangular.
    workers : int
        Threads of the FFTs (ducc0's own, like BLAS's; the sums run on one). Default 1: the
        acquisition calls this while its devices stream; a caller with idle cores may give more.

    Returns
    -------
    FrfEstimate
        ``H`` of shape (n_lines, n_outputs, n_inputs) with ``n_lines = n_samples // 2 + 1``.

    Raises
    ------
    DataError
        Mismatched shapes, NaNs, or fewer averages than inputs for the multiple-input H1.
    SetupError
        Unknown estimator, H2 with several inputs.
    """
    x = _as_records("inputs", inputs)
    y = _as_records("outputs", outputs)
    _check_request(x, y, sample_rate_hz, estimator, workers)
    n_avg, n_in, n_s = x.shape
    wx = None if input_window is None else _window("input_window", input_window, n_s)
    wy = None if output_window is None else _window("output_window", output_window, n_s)

    fused = estimator if n_in == 1 and estimator != "Hv" else None
    g_ff, g_yf, g_yy, g_yf_abs2 = _spectral_sums(x, y, wx, wy, workers, fused)
    # A NaN or infinite sample makes its channel's spectral sums NaN or infinite: checking the
    # small sums instead of every sample saves a pass over the records; the records are looked
    # at only to say which side is wrong.
    if not (np.all(np.isfinite(g_yy)) and np.all(np.isfinite(g_ff))):
        _check_finite("inputs", x)
        _check_finite("outputs", y)
    h, ordinary, multiple, cond = _estimates(g_ff, g_yf, g_yy, g_yf_abs2, estimator, fused)
    if n_avg <= n_in:  # identically 1: no information (module docstring)
        multiple[...] = np.nan
    if n_avg == 1:
        ordinary[...] = np.nan
    freqs = np.arange(n_s // 2 + 1) * (sample_rate_hz / n_s)
    return FrfEstimate(
        frequencies_hz=freqs,
        H=h,
        coherence=multiple,
        ordinary_coherence=ordinary,
        input_condition=cond,
        g_ff=g_ff,
        g_yy=g_yy,
        n_averages=n_avg,
        estimator=estimator,
    )


#: Bytes of output spectra transformed and summed at a time: small enough to stay in a core's
#: cache between the FFT that writes them and the two sums that read them (four outputs of ten
#: 8192-sample averages: 2.6 MB; blocks of 1–8 outputs measured within 10 % of each other).
_BLOCK_BYTES = 3 << 20


def _spectral_sums(
    x: NDArray[np.float64],
    y: NDArray[np.float64],
    wx: NDArray[np.float64] | None = None,
    wy: NDArray[np.float64] | None = None,
    workers: int = 1,
    fused: Estimator | None = None,
) -> tuple[
    NDArray[np.complex128], NDArray[np.complex128], NDArray[np.float64], NDArray[np.float64]
]:
    """``G_ff``, ``G_yf``, ``G_yy`` summed over averages (module docstring) and ``|G_yf|²``.

    With one input and ``fused`` = "H1" or "H2", each block of outputs is finished while it is
    in cache: ``G_yf`` becomes the FRF (``H1 = G_yf · (1/G_ff)``, ``H2 = G_yf · G_yy/|G_yf|²``,
    module docstring) and ``|G_yf|²`` the coherence ``min(|G_yf|² / (G_yy G_ff), 1)`` (≤ 1 by
    Cauchy–Schwarz but for rounding; NaN where ``G_yy G_ff = 0``): the same products as passes
    over whole arrays afterwards, which took 1–2 ms of a 17 ms H1 in strided memory traffic.

    One real FFT per channel and average (ducc0's, which transforms several records at once in
    SIMD lanes: 1.9x numpy's pocketfft on 640 records of 8192 samples, equal to 4e-16), of the
    records times the windows ``wx``, ``wy`` when given. The outputs go in blocks of about
    ``_BLOCK_BYTES`` of spectra, written into one reused buffer: the sums over averages read them
    from cache, and no block asks the kernel for fresh pages (a new 42 MB spectrum array costs
    ~6 ms of page faults, a quarter of an H1). The sums run along the FFT's layout (lines last)
    and so do ``G_yy`` and ``|G_yf|² = Re² + Im²``, taken from each block while it is in cache
    (the same passes over whole (lines, outputs) arrays took 3.5 ms more, a fifth of an H1,
    most of it in strided reads and writes); the results are returned as lines-first views of
    that layout, not copies.

    Returns
    -------
    g_ff : ndarray, shape (n_lines, n_inputs, n_inputs), complex
    g_yf : ndarray, shape (n_lines, n_outputs, n_inputs), complex
    g_yy : ndarray, shape (n_lines, n_outputs)
    g_yf_abs2 : ndarray, shape (n_lines, n_outputs, n_inputs)
        ``|G_yf|²``, as ``Re(G_yf)² + Im(G_yf)²``.
    """
    n_avg, n_in, n_s = x.shape
    n_out = y.shape[1]
    n_lines = n_s // 2 + 1
    fx = ducc0.fft.r2c(x if wx is None else x * wx, axes=(2,), nthreads=workers)
    fxc = fx.conj()  # (n_avg, n_in, L)
    g_ff = np.einsum("ajl,ail->lji", fx, fxc)
    gff = inv2 = None
    if fused is not None:
        if n_in != 1 or fused not in ("H1", "H2"):
            raise SetupError(f"fused = {fused!r} needs one input and 'H1' or 'H2'")
        gff = np.ascontiguousarray(np.real(g_ff[:, 0, 0]))
        with np.errstate(divide="ignore"):
            inv2 = np.repeat(1.0 / gff, 2) if fused == "H1" else None
    # One allocation holds the three results, returned as views of it (they keep it alive
    # together): numpy asks the kernel for huge pages for arrays of 4 MB and more (madvise),
    # where three separate arrays of 2-4 MB were first touched page by page. 100 calls in a row
    # at 64 outputs x 8192 samples (perf stat): ~2,900 page faults per call became ~40, and
    # 26-34 ms of CPU per call 21-23 ms.
    n_pl = n_out * n_lines
    arena = np.empty(n_pl * (3 * n_in + 1))
    g = arena[: 2 * n_in * n_pl].view(np.complex128).reshape(n_out, n_in, n_lines)
    g_abs2 = arena[2 * n_in * n_pl : 3 * n_in * n_pl].reshape(n_out, n_in, n_lines)
    g_yy = arena[3 * n_in * n_pl :].reshape(n_out, n_lines)
    block = max(1, min(n_out, _BLOCK_BYTES // (n_avg * n_lines * 16)))
    spectra = np.empty(n_avg * block * n_lines, dtype=np.complex128)
    scratch = np.empty((block, n_lines))
    windowed = None if wy is None else np.empty((n_avg, block, n_s))
    block_sums = _block_sums_for(n_avg * n_out * n_in * n_lines)
    for o0 in range(0, n_out, block):
        o1 = min(o0 + block, n_out)
        nb = o1 - o0
        yb = y[:, o0:o1]
        if windowed is not None and wy is not None:
            yb = np.multiply(yb, wy, out=windowed[:, :nb])
        fy = spectra[: n_avg * nb * n_lines].reshape(n_avg, nb, n_lines)  # contiguous
        ducc0.fft.r2c(yb, axes=(2,), out=fy, nthreads=workers)
        # Σ_a Y_a F̄_a, Σ_a |Y_a|² and |G_yf|² over the block while it is in cache (compiled:
        # _spectral_kernel, or numpy's: _numpy_block_sums). A NaN or infinite sample is reported
        # by the caller from the sums.
        block_sums(fy, fxc, g[o0:o1], g_abs2[o0:o1], g_yy[o0:o1])
        if gff is not None:
            _finish_block(g[o0:o1, 0], g_abs2[o0:o1, 0], g_yy[o0:o1], gff, inv2, scratch[:nb])
    return g_ff, g.transpose(2, 0, 1), g_yy.T, g_abs2.transpose(2, 0, 1)


#: Products ``Y F̄`` (averages x outputs x inputs x lines) a process sums with numpy
#: (:func:`_numpy_block_sums`) before it loads the compiled sums
#: (:mod:`dimacq.pipeline._spectral_kernel`). Loading numba and the cached kernel costs about
#: 0.5 s of CPU and 100 MB of memory; numpy's sums take about 11 ns per product more. A process
#: that sums fewer (an impact test's FRFs: 30 outputs x 5 averages x 2049 lines per input, a
#: few million in all) never loads numba; one that sums more (a live stream) switches after
#: spending about numba's load time. Both give the same bits.
NUMPY_SUMS_BUDGET = 50_000_000


class _SumsChoice:
    """How many products this process has summed with numpy (:data:`NUMPY_SUMS_BUDGET`)."""

    numpy_products = 0


def _block_sums_for(n_products: int) -> Callable[..., None]:
    """The sums for a call of ``n_products`` products: numpy's while the process is within
    :data:`NUMPY_SUMS_BUDGET` and numba is not loaded, the compiled ones after."""
    kernel = "dimacq.pipeline._spectral_kernel"
    if kernel not in sys.modules and _SumsChoice.numpy_products < NUMPY_SUMS_BUDGET:
        _SumsChoice.numpy_products += n_products
        return _numpy_block_sums
    from dimacq.pipeline._spectral_kernel import block_sums

    return block_sums


def _numpy_block_sums(
    spectra: NDArray[np.complex128],
    inputs_conj: NDArray[np.complex128],
    g: NDArray[np.complex128],
    g_abs2: NDArray[np.float64],
    g_yy: NDArray[np.float64],
) -> None:
    """:func:`dimacq.pipeline._spectral_kernel.block_sums` in numpy, bit for bit.

    With ``Y = y_r + i y_i`` and ``F̄ = f_r + i f_i``, summed over averages ``a = 0, 1, …`` in
    that order from zero::

        Re G_yf += y_r f_r − y_i f_i      Im G_yf += y_r f_i + y_i f_r
        G_yy    += y_r² + y_i²            |G_yf|² = (Re G_yf)² + (Im G_yf)²

    each product and sum rounded on its own, as the compiled loop does (numpy's complex
    multiply fuses them, FMA, and differs in the last bit). Same arguments and shapes.
    """
    n_avg, n_out, n_lines = spectra.shape
    n_in = inputs_conj.shape[1]
    y = spectra.view(np.float64)
    f = inputs_conj.view(np.float64)
    gv = g.view(np.float64)
    y_r, y_i = y[..., 0::2], y[..., 1::2]
    f_r, f_i = f[..., 0::2], f[..., 1::2]
    g_r, g_i = gv[..., 0::2], gv[..., 1::2]
    gv[...] = 0.0
    g_yy[...] = 0.0
    with np.errstate(invalid="ignore", over="ignore"):  # NaN and inf kept, as compiled
        t = np.empty((n_out, n_lines))
        u = np.empty((n_out, n_lines))
        for a in range(n_avg):
            np.multiply(y_r[a], y_r[a], out=t)
            np.multiply(y_i[a], y_i[a], out=u)
            t += u
            g_yy += t
            for i in range(n_in):
                np.multiply(y_r[a], f_r[a, i], out=t)
                np.multiply(y_i[a], f_i[a, i], out=u)
                t -= u
                g_r[:, i] += t
                np.multiply(y_r[a], f_i[a, i], out=t)
                np.multiply(y_i[a], f_r[a, i], out=u)
                t += u
                g_i[:, i] += t
        for i in range(n_in):
            np.multiply(g_r[:, i], g_r[:, i], out=g_abs2[:, i])
            np.multiply(g_i[:, i], g_i[:, i], out=t)
            g_abs2[:, i] += t


def _finish_block(
    g: NDArray[np.complex128],
    abs2: NDArray[np.float64],
    yy: NDArray[np.float64],
    gff: NDArray[np.float64],
    inv2: NDArray[np.float64] | None,
    scratch: NDArray[np.float64],
) -> None:
    """One input's block of (outputs, lines) sums made into FRFs and coherence, in place.

    ``g`` holds ``G_yf`` and becomes H1 (``inv2`` given: ``1/G_ff`` repeated for the (re, im)
    pairs) or H2 (``inv2`` None); ``abs2`` holds ``|G_yf|²`` and becomes the coherence
    (``_spectral_sums``); ``scratch`` is a float buffer of the block's shape. A real
    factor scales the (re, im) pairs as rows, not broadcast over the pairs' axis of 2 (5–7x
    slower): H1's ``1/G_ff`` interleaved, H2's ``G_yy/|G_yf|²`` as a complex product with a real
    (the same values: x·r − y·0 = x·r).
    """
    with np.errstate(divide="ignore", invalid="ignore"):
        if inv2 is not None:
            flat = g.view(np.float64)  # (nb, 2L), the same memory
            np.multiply(flat, inv2, out=flat)
        else:  # H2 = G_yy / conj(G_yf) = G_yf · G_yy / |G_yf|²
            np.divide(yy, abs2, out=scratch)
            np.multiply(g, scratch, out=g)
        np.multiply(yy, gff, out=scratch)
        np.divide(abs2, scratch, out=abs2)
        np.minimum(abs2, 1.0, out=abs2)


def _hv(
    g_ff: NDArray[np.complex128], g_yf: NDArray[np.complex128], g_yy: NDArray[np.float64]
) -> NDArray[np.complex128]:
    """Total-least-squares (Hv) FRFs, batched over lines and outputs (see module docstring)."""
    n_l, n_out, n_in = g_yf.shape
    gc = np.empty((n_l, n_out, n_in + 1, n_in + 1), dtype=complex)
    gc[:, :, :n_in, :n_in] = g_ff[:, None]
    gc[:, :, n_in, :n_in] = g_yf
    gc[:, :, :n_in, n_in] = g_yf.conj()
    gc[:, :, n_in, n_in] = g_yy
    _, vecs = np.linalg.eigh(gc)
    v = vecs[..., 0]  # eigenvector of the smallest eigenvalue, (L, n_out, n_in + 1)
    return np.asarray(-v[..., :n_in].conj() / v[..., n_in : n_in + 1].conj())


def _window(name: str, w: ArrayLike, n: int) -> NDArray[np.float64]:
    arr = np.asarray(w, dtype=float)
    if arr.shape != (n,):
        raise DataError(f"{name} has shape {arr.shape}; it must be ({n},) like the records")
    if not np.all(np.isfinite(arr)):
        raise DataError(f"{name} holds NaN or infinite values; give finite window weights")
    return arr


def force_window(
    n_samples: int, end_sample: int, *, taper_samples: int = 0, start_sample: int = 0
) -> NDArray[np.float64]:
    """Force (transient) window for the hammer channel.

    ``w[n] = 1`` for ``start_sample ≤ n < end_sample``, a half-cosine fall to 0 over the next
    ``taper_samples`` samples, 0 elsewhere. It keeps the pulse and removes the noise the force
    channel records after it.

    Returns
    -------
    ndarray, shape (n_samples,)
    """
    if not 0 <= start_sample < end_sample <= n_samples:
        raise SetupError(
            f"force window [{start_sample}, {end_sample}) does not fit {n_samples} samples; "
            "choose 0 ≤ start < end ≤ n_samples"
        )
    w = np.zeros(n_samples)
    w[start_sample:end_sample] = 1.0
    taper = min(taper_samples, n_samples - end_sample)
    if taper > 0:
        k = np.arange(1, taper + 1)
        w[end_sample : end_sample + taper] = 0.5 * (1.0 + np.cos(np.pi * k / (taper + 1)))
    return w


def exponential_window(
    n_samples: int, sample_rate_hz: float, tau_s: float, *, start_sample: int = 0
) -> NDArray[np.float64]:
    """Exponential window ``w(t) = exp(−(t − t0)/τ)`` for ``t ≥ t0``, 1 before ``t0``.

    ``t0 = start_sample / fs`` is the trigger point (the end of the pre-trigger). Apply it to the
    force and the responses alike; see the module docstring for the damping it adds
    (``σ' = σ + 1/τ``) and :func:`exponential_window_damping_correction`.

    Returns
    -------
    ndarray, shape (n_samples,)
    """
    if tau_s <= 0:
        raise SetupError(f"tau_s = {tau_s}; the exponential window needs a positive time constant")
    t = (np.arange(n_samples) - start_sample) / sample_rate_hz
    return np.exp(-np.clip(t, 0.0, None) / tau_s)


def exponential_window_damping_correction(
    zeta_measured: ArrayLike, natural_frequency_hz: ArrayLike, tau_s: float
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Remove the damping an exponential window adds to an identified pole.

    The window moves every pole ``p = −σ ± iω_d`` to ``p' = −(σ + 1/τ) ± iω_d``. From the
    measured (windowed) pole, ``σ' = ζ' ω_n'`` and ``ω_d = ω_n' sqrt(1 − ζ'²)``, the true pole is
    ``σ = σ' − 1/τ``, ``ω_n = sqrt(σ² + ω_d²)``, ``ζ = σ / ω_n``; for light damping this is
    ``ζ ≈ ζ' − 1/(τ ω_n)``.

    Parameters
    ----------
    zeta_measured : array_like
        Damping ratios identified from FRFs estimated with the window.
    natural_frequency_hz : array_like
        Natural frequencies identified with them (of the windowed poles), Hz.
    tau_s : float
        The window's time constant.

    Returns
    -------
    zeta, natural_frequency_hz : ndarray
        The corrected damping ratios and natural frequencies.
    """
    zeta_m = np.asarray(zeta_measured, dtype=float)
    wn_m = 2.0 * np.pi * np.asarray(natural_frequency_hz, dtype=float)
    sigma = zeta_m * wn_m - 1.0 / tau_s
    wd = wn_m * np.sqrt(1.0 - zeta_m**2)
    wn = np.hypot(sigma, wd)
    return sigma / wn, wn / (2.0 * np.pi)


def welch_segments(
    records: ArrayLike, nperseg: int, noverlap: int | None = None
) -> NDArray[np.float64]:
    """Cut continuous records into overlapped segments (Welch averages) without copying.

    Parameters
    ----------
    records : array_like, shape (n_channels, n_samples)
    nperseg : int
        Segment length.
    noverlap : int, optional
        Overlap in samples, default ``nperseg // 2`` (50 %, the usual choice with a Hann window).

    Returns
    -------
    ndarray, shape (n_segments, n_channels, nperseg)
        A read-only strided view; pass it with the same segmentation for inputs and outputs to
        :func:`estimate_frf` together with ``scipy.signal.get_window("hann", nperseg)``.
    """
    arr = np.asarray(records, dtype=float)
    if arr.ndim != 2:
        raise DataError(f"records have shape {arr.shape}; give (n_channels, n_samples)")
    noverlap = nperseg // 2 if noverlap is None else noverlap
    if not 0 <= noverlap < nperseg <= arr.shape[1]:
        raise SetupError(
            f"nperseg={nperseg}, noverlap={noverlap} do not fit {arr.shape[1]} samples; "
            "choose 0 ≤ noverlap < nperseg ≤ n_samples"
        )
    step = nperseg - noverlap
    view = np.lib.stride_tricks.sliding_window_view(arr, nperseg, axis=1)[:, ::step]
    return view.transpose(1, 0, 2)


def double_hit_mask(
    force: ArrayLike,
    *,
    threshold: float = 0.1,
    min_gap_samples: int = 3,
) -> NDArray[np.bool_]:
    """Flag impact records whose force shows more than one separate pulse.

    A pulse is a run of samples with ``|f| > threshold · max|f|`` (per record); runs separated
    by fewer than ``min_gap_samples`` samples below the threshold count as one pulse (ringing).

    Parameters
    ----------
    force : array_like, shape (n_records, n_samples)

    Returns
    -------
    ndarray of bool, shape (n_records,)
        True where a second pulse follows the first.
    """
    f = np.abs(np.asarray(force, dtype=float))
    if f.ndim == 1:
        f = f[None]
    above = f > threshold * f.max(axis=1, keepdims=True)
    out = np.zeros(f.shape[0], dtype=bool)
    for r in range(f.shape[0]):
        idx = np.flatnonzero(above[r])
        if idx.size > 1:
            out[r] = bool(np.any(np.diff(idx) > min_gap_samples))
    return out
