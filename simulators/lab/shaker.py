"""A simulated shaker test on the virtual lab: multiple-input H1 from the lab's sample source.

``n_shakers`` shakers drive a group of the scenario's inputs at once, each with its own signal
(:class:`~dimacq.simulators.lab.timedomain.ShakerSignal`); after ``settle_s`` of driving the
records of every shaker's force, every accelerometer axis and every load cell's 12 gauges
(turned into the cell's loads by ``C = S⁺``) are read, and the FRF columns of the group are
estimated by :func:`dimacq.pipeline.frf_estimation.estimate_frf` (multiple-input H1,
``H1 = G_yf G_ff⁻¹`` per line). The shakers then move on to the next group of inputs, until
every input (or the scenario's ``shaker.inputs``) has its column, as when a test moves its
shakers between runs.

Excitations (``shaker.kind``):

- ``random``: independent Gaussian signals per shaker, continuous, band-limited to
  ``f_lo_hz``–``f_hi_hz`` (default: half the DIM band's lower edge to the highest line, so
  suspension modes are hardly driven and cannot leak into the band); Welch averaging of Hann-windowed
  segments with ``overlap`` (leakage bias small where the FRF varies slowly over a few lines);
- ``burst-random``: a random burst over the first ``burst_fraction`` of each record, then silence so
  the response decays inside the record; rectangular window;
- ``swept-sine``: one linear or logarithmic chirp per record; several shakers sweep together with
  polarities from the rows of a Hadamard matrix (record ``r`` of shaker ``k`` has sign
  ``H[r mod h, k]``), so ``G_ff`` is well conditioned after ``h`` records; rectangular window. In
  steady state the records are periodic per polarity pattern up to the change of sign.

The FRF's ``coherence`` is the multiple coherence of each output on the run's inputs, repeated for
each input column of the run.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from typing import Literal, cast

import numpy as np
from numpy.typing import NDArray
from scipy.linalg import hadamard
from scipy.signal import get_window

from dimacq.errors import SetupError
from dimacq.model.channels import gauge_names
from dimacq.model.frf import FrfData
from dimacq.pipeline.frf_estimation import estimate_frf, welch_segments
from dimacq.simulators.lab.impact import virtual_lab
from dimacq.simulators.lab.scenarios import BuiltScenario
from dimacq.simulators.lab.timedomain import ShakerSignal, VirtualLab

__all__ = ["EXCITATIONS", "ShakerRun", "shaker_test"]

log = logging.getLogger(__name__)

FloatArray = NDArray[np.float64]
Excitation = Literal["random", "burst-random", "swept-sine"]
EXCITATIONS: tuple[str, ...] = ("random", "burst-random", "swept-sine")


@dataclass(frozen=True, eq=False)
class ShakerRun:
    """FRFs of a simulated shaker test, with what it took.

    Attributes
    ----------
    frf : FrfData
        Setup channel order (accelerometers, then 6 loads per cell); ``coherence`` is the
        multiple coherence, shape (n_lines, n_outputs, n_inputs).
    excitation : str
    n_shakers : int
        Shakers driving at once.
    groups : tuple of tuple of int
        Input indices driven together in each run.
    averages : int
        Averages per run (Welch segments or records).
    input_condition : ndarray, shape (n_lines, n_runs)
        Condition number of ``G_ff`` per line and run (1 for one shaker).
    samples : int
        Samples of the lab's clock used.
    """

    frf: FrfData
    excitation: str
    n_shakers: int
    groups: tuple[tuple[int, ...], ...]
    averages: int
    input_condition: FloatArray
    samples: int


def _checked_plan(
    built: BuiltScenario,
    excitation: str | None,
    n_shakers: int | None,
    averages: int | None,
) -> tuple[Excitation, int, list[int], int]:
    """The excitation, shakers at once, inputs driven and averages per run of a shaker test
    (the scenario's ``shaker`` values unless given), refused when they cannot work."""
    spec = built.spec
    sh = spec.shaker
    requested = sh.kind if excitation is None else excitation
    if requested not in EXCITATIONS:
        raise SetupError(
            f"excitation {requested!r} is unknown; use one of {', '.join(EXCITATIONS)}"
        )
    kind = cast(Excitation, requested)
    n_sh = sh.shakers if n_shakers is None else int(n_shakers)
    n_in = len(built.setup.excitations)
    inputs = list(sh.inputs) if sh.inputs else list(range(n_in))
    bad = [j for j in inputs if not 0 <= j < n_in]
    if bad:
        raise SetupError(
            f"scenario {spec.name}: shaker.inputs {bad} out of range; give indices 0..{n_in - 1}"
        )
    if not 1 <= n_sh <= min(8, len(inputs)):
        raise SetupError(
            f"{n_sh} shakers for {len(inputs)} inputs; give 1 to {min(8, len(inputs))} shakers"
        )
    n_avg = sh.averages if averages is None else int(averages)
    if n_avg < n_sh:
        raise SetupError(
            f"{n_avg} averages for {n_sh} shakers; the multiple-input H1 needs at least as many "
            "averages as shakers (more: 10 per shaker or so)"
        )
    return kind, n_sh, inputs, n_avg


def _outputs(
    rec: FloatArray, n_acc: int, calib: list[FloatArray], cell_units: list[str]
) -> FloatArray:
    """The FRF outputs (n_acc + 6 per cell, n_samples): the accelerometers, then each cell's
    loads ``C g`` from its 12 gauges (``rec`` rows after the accelerometers) by its calibration
    ``C``; a DC-coupled bridge (``mV/V``) loses its mean, its zero and static load not being
    part of the response."""
    out = np.empty((n_acc + 6 * len(calib), rec.shape[1]))
    out[:n_acc] = rec[:n_acc]
    for c, C in enumerate(calib):
        gg = rec[n_acc + 12 * c : n_acc + 12 * (c + 1)]
        if cell_units[c] == "mV/V":
            gg = gg - gg.mean(axis=1, keepdims=True)
        out[n_acc + 6 * c : n_acc + 6 * (c + 1)] = C @ gg
    return out


def _drive(
    lab: VirtualLab,
    built: BuiltScenario,
    kind: Excitation,
    signs: FloatArray,
    band_hz: tuple[float, float],
    N: int,
    run: int,
    group: tuple[int, ...],
    span: tuple[int, int],
) -> None:
    """Shaker ``k`` of run ``run`` drives input ``group[k]`` from sample ``span[0]`` to
    ``span[1]``: the scenario's signal in ``band_hz``, polarity column ``k`` of the Hadamard
    ``signs`` for a swept sine, its own seed."""
    sh = built.spec.shaker
    for k, j in enumerate(group):
        signal = ShakerSignal(
            kind=kind,
            level_n=sh.level_n,
            record_samples=N,
            burst_fraction=sh.burst_fraction,
            f_lo_hz=band_hz[0],
            f_hi_hz=band_hz[1],
            sweep=sh.sweep,
            polarity=tuple(signs[:, k]) if kind == "swept-sine" else (1.0,),
            seed=int(np.random.SeedSequence([built.seed, 71, run, k]).generate_state(1)[0]),
            band_limited=sh.band_limited,
        )
        lab.drive(k, j, signal, span[0], span[1])


def _shaker_frf(
    built: BuiltScenario,
    freqs: FloatArray,
    keep: NDArray[np.bool_],
    H: NDArray[np.complex128],
    coh: FloatArray,
    inputs: list[int],
    rigid_only: bool,
    kind: str,
    n_sh: int,
    n_avg: int,
) -> FrfData:
    """The estimated ``H`` and coherence on the lines ``freqs[keep]`` as :class:`FrfData` in
    the scenario's channel order, restricted to the ``inputs`` driven, with how they were
    taken."""
    spec = built.spec
    n_in = len(built.setup.excitations)
    model_frf = built.model_frf(rigid_only=rigid_only, frequencies_hz=freqs[keep])
    if inputs != list(range(n_in)):
        H, coh = H[:, :, inputs], coh[:, :, inputs]
        model_frf = model_frf.replace(
            H=model_frf.H[:, :, inputs], inputs=tuple(model_frf.inputs[j] for j in inputs)
        )
    return model_frf.replace(
        H=H[keep],
        coherence=coh[keep],
        meta={
            "source": f"dimacq simulate {spec.name} --time-domain --excitation {kind}",
            "estimator": "H1 (multiple-input)" if n_sh > 1 else "H1",
            "excitation": kind,
            "shakers": str(n_sh),
            "averages": str(n_avg),
        },
    )


def shaker_test(
    built: BuiltScenario,
    *,
    excitation: str | None = None,
    n_shakers: int | None = None,
    averages: int | None = None,
    rigid_only: bool = False,
    noise_scale: float = 1.0,
    max_hz: float | None = None,
) -> ShakerRun:
    """Drive the scenario's inputs with shakers and estimate the FRFs (see the module docstring).

    Parameters
    ----------
    built : BuiltScenario
    excitation : {"random", "burst-random", "swept-sine"}, optional
        Default: the scenario's ``shaker.kind``.
    n_shakers : int, optional
        Shakers at once (default ``shaker.shakers``).
    averages : int, optional
        Averages per run (default ``shaker.averages``; swept sine rounds up to whole Hadamard
        cycles).
    rigid_only, noise_scale, max_hz
        As in :func:`~dimacq.simulators.lab.impact.impact_test`.

    Raises
    ------
    SetupError
        Unknown excitation, too few averages for the shakers, input indices out of range.
    """
    spec = built.spec
    sh, acq = spec.shaker, spec.acquisition
    kind, n_sh, inputs, n_avg = _checked_plan(built, excitation, n_shakers, averages)
    n_in = len(built.setup.excitations)
    lab = virtual_lab(
        built, rigid_only=rigid_only, noise_scale=noise_scale, n_shakers=n_sh, cache_blocks=64
    )
    fs = lab.sample_rate_hz
    N = sh.record_samples or acq.record_samples
    ax = spec.frequency_axis
    f_lo = spec.band.lo_hz / 2 if sh.f_lo_hz is None else sh.f_lo_hz
    f_hi = ax.max_hz if sh.f_hi_hz is None else sh.f_hi_hz
    h = 1
    if kind == "swept-sine" and n_sh > 1:
        h = 1 << math.ceil(math.log2(n_sh))
        n_avg = -(-n_avg // h) * h
    signs = hadamard(h).astype(float)
    if kind == "random":
        step = N - round(sh.overlap * N)
        n_read = N + (n_avg - 1) * step
        window: FloatArray | None = get_window("hann", N)
    else:
        step, n_read, window = N, n_avg * N, None
    settle_records = max(1, math.ceil(sh.settle_s * fs / N))
    setup = built.setup
    n_acc = len(setup.responses)
    gauge_ch: list[int] = []
    calib: list[FloatArray] = []
    for lc in setup.load_cells:
        gauge_ch += [lab.channel_index(n) for n in gauge_names(lc.node)]
        calib.append(np.asarray(np.linalg.pinv(lab.gauge_matrix(lc.node)), dtype=np.float64))
    n_out = n_acc + 6 * len(setup.load_cells)
    groups = [tuple(inputs[i : i + n_sh]) for i in range(0, len(inputs), n_sh)]
    n_lines = N // 2 + 1
    H = np.zeros((n_lines, n_out, n_in), complex)
    coh = np.zeros((n_lines, n_out, n_in))
    cond = np.ones((n_lines, len(groups)))
    cursor = 0
    for run, group in enumerate(groups):
        start = cursor
        first = start + settle_records * N  # records of the signal start at start + r·N
        until = first + n_read
        _drive(lab, built, kind, signs, (f_lo, f_hi), N, run, group, (start, until))
        g = len(group)
        channels = np.array(
            [*(lab.channel_index(f"shaker{k + 1}") for k in range(g)), *range(n_acc), *gauge_ch],
            dtype=np.intp,
        )
        rec = lab.read(channels, first, n_read)
        cursor = until
        out = _outputs(rec[g:], n_acc, calib, [lab.channel_units[c] for c in gauge_ch[::12]])
        if kind == "random":
            x = welch_segments(rec[:g], N, N - step)
            y = welch_segments(out, N, N - step)
        else:
            x = rec[:g].reshape(g, n_avg, N).transpose(1, 0, 2)
            y = out.reshape(n_out, n_avg, N).transpose(1, 0, 2)
        est = estimate_frf(x, y, fs, estimator="H1", input_window=window, output_window=window)
        H[:, :, list(group)] = est.H
        coh[:, :, list(group)] = np.nan_to_num(est.coherence, nan=0.0)[:, :, None]
        cond[:, run] = est.input_condition
        log.info(
            "shaker run %d/%d: inputs %s, %d averages, median cond(G_ff) %.3g",
            run + 1,
            len(groups),
            group,
            est.n_averages,
            float(np.median(est.input_condition[1:])),
        )
    freqs = est.frequencies_hz
    top = spec.frequency_axis.max_hz if max_hz is None else max_hz
    keep = (freqs > 0) & (freqs <= top)
    frf = _shaker_frf(built, freqs, keep, H, coh, inputs, rigid_only, kind, n_sh, n_avg)
    return ShakerRun(frf, kind, n_sh, tuple(groups), n_avg, cond[keep], cursor)
