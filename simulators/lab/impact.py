"""A simulated roving-hammer impact test on the virtual lab, straight from its sample source.

The virtual operator strikes each input of a scenario ``averages`` times on the lab's sample
clock (:class:`~dimacq.simulators.lab.timedomain.VirtualLab`, the same ``SampleSource`` the DAQ and
load cell simulators stream); each record (``record_samples``, ``pretrigger_samples`` before the
strike) of the hammer force, every accelerometer axis and every load cell's 12 gauges is read,
the gauges are turned into the cell's local loads by the calibration matrix ``C = S⁺`` (the
amplifier's ``F = C g``), records with a double hit are rejected and struck again, and the FRFs
are estimated by :func:`dimacq.pipeline.frf_estimation.estimate_frf` (H1, force window on the
hammer, exponential window on everything).

With an exponential window ``e^{−t/τ}`` on input and output the estimate converges to
``H(iω + 1/τ)`` (:meth:`ForwardModel.transfer`), not to ``H(iω)``: the rigid-body mass line is
unchanged, modes look more damped. Between strikes the operator waits ``acquisition.settle_s`` so the
previous response has decayed, plus a random part of a record (a human rhythm): what has not
decayed then arrives at a random phase, uncorrelated with the next hit, and lowers the coherence
near the lightly damped suspension modes, as in a real test (with strikes at a fixed rhythm the
leftover would repeat in every average and bias the FRF without lowering the coherence).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from dimacq.errors import SetupError
from dimacq.model.channels import gauge_names
from dimacq.model.frf import FrfData
from dimacq.pipeline.frf_estimation import (
    double_hit_mask,
    estimate_frf,
    exponential_window,
    force_window,
)
from dimacq.simulators.lab.bridge import strain_gauge_cell
from dimacq.simulators.lab.scenarios import BuiltScenario
from dimacq.simulators.lab.timedomain import Hammer, LabNoise, VirtualLab

__all__ = ["ImpactRun", "impact_test", "virtual_lab"]

log = logging.getLogger(__name__)

FloatArray = NDArray[np.float64]


@dataclass(frozen=True, eq=False)
class ImpactRun:
    """FRFs from simulated time data, with what it took.

    Attributes
    ----------
    frf : FrfData
        Setup channel order (accelerometers, then 6 loads per cell); ``coherence`` is the
        ordinary coherence, shape (n_lines, n_outputs, n_inputs).
    exponential_tau_s : float or None
        The window's time constant: compare ``frf`` with ``model.transfer(iω + 1/τ)``.
    n_strikes : int
        Strikes made (accepted averages plus rejected double hits).
    n_rejected : int
    samples : int
        Samples of the lab's clock used.
    """

    frf: FrfData
    exponential_tau_s: float | None
    n_strikes: int
    n_rejected: int
    samples: int


def virtual_lab(
    built: BuiltScenario,
    *,
    rigid_only: bool = False,
    noise_scale: float = 1.0,
    n_shakers: int = 0,
    cache_blocks: int = 4096,
    hammer_noise: bool = True,
) -> VirtualLab:
    """The scenario's sample source: the true article, its transducers, its hammer and
    ``n_shakers`` shakers (channels ``shaker1`` ..; internal rate factor ``shaker.oversample``).

    ``noise_scale`` multiplies the scenario's noise and drift levels (0: noise-free);
    ``hammer_noise=False`` leaves the hammer force channel noise-free (the inertial calibration
    bench transmits the true hammer force to the cell:
    :class:`~dimacq.simulators.loadcell.bench.SupportSideBench`).
    """
    if noise_scale < 0:
        raise SetupError(f"noise scale {noise_scale}; give a factor ≥ 0")
    spec = built.spec
    tr, hm, acq = spec.transducers, spec.hammer, spec.acquisition
    noise = LabNoise(
        accel_noise_ms2=tr.accel_noise_ms2 * noise_scale,
        force_noise_n=tr.force_noise_n * noise_scale if hammer_noise else 0.0,
        gauge_noise_v=tr.gauge_noise_v * noise_scale,
        gauge_drift_v_per_s=tr.gauge_drift_v_per_s * noise_scale,
        sensitivity_error=tr.sensitivity_error,
        cross_axis=tr.cross_axis,
    )
    hammer = Hammer(
        peak_n=hm.peak_n,
        sigma_s=None if hm.pulse_sigma_ms is None else hm.pulse_sigma_ms * 1e-3,
        double_hit_probability=hm.double_hit_probability,
        double_hit_delay_s=hm.double_hit_delay_ms * 1e-3,
        double_hit_ratio=hm.double_hit_ratio,
        line_of_action_error_deg=hm.line_of_action_error_deg,
    )
    bridges = None
    lc = spec.loadcell
    if lc.kind == "strain-gauge":
        bridges = {
            s.node: strain_gauge_cell(
                s.node,
                rated_scale=lc.rated_scale,
                excitation_v=lc.excitation_v,
                noise_uv=lc.noise_uv * noise_scale,
                nonlinearity=lc.nonlinearity_pct_fs / 100,
                hysteresis=lc.hysteresis_pct_fs / 100,
            )
            for s in built.model.supports
        }
    try:
        return VirtualLab(
            built.article(rigid_only),
            sample_rate_hz=acq.sample_rate_hz,
            hammer=hammer,
            noise=noise,
            seed=built.seed,
            block_samples=512,
            n_shakers=n_shakers,
            oversample=spec.shaker.oversample,
            cache_blocks=cache_blocks,
            bridges=bridges,
        )
    except ValueError as err:
        raise SetupError(f"scenario {spec.name}: {err}") from err


def impact_test(
    built: BuiltScenario,
    *,
    rigid_only: bool = False,
    noise_scale: float = 1.0,
    averages: int | None = None,
    settle_samples: int | None = None,
    max_hz: float | None = None,
) -> ImpactRun:
    """Strike every input ``averages`` times and estimate the FRFs (see the module docstring).

    Parameters
    ----------
    built : BuiltScenario
    rigid_only : bool
        Drop the elastic modes.
    noise_scale : float
        Factor on the scenario's noise levels (0: noise-free time data).
    averages : int, optional
        Accepted averages per input (default: the scenario's).
    settle_samples : int, optional
        Wait after each record before the next strike (default: ``acquisition.settle_s``).
    max_hz : float, optional
        Keep lines up to this frequency (default: the scenario's ``frequency_axis.max_hz``).
    """
    spec = built.spec
    acq = spec.acquisition
    n_avg = acq.averages if averages is None else int(averages)
    if n_avg < 1:
        raise SetupError(f"averages = {n_avg}; give at least 1")
    lab = virtual_lab(built, rigid_only=rigid_only, noise_scale=noise_scale)
    fs, N, pre = lab.sample_rate_hz, acq.record_samples, acq.pretrigger_samples
    settle = round(acq.settle_s * fs) if settle_samples is None else int(settle_samples)
    setup = built.setup
    n_acc = len(setup.responses)
    hammer_ch = lab.channel_index("hammer")
    gauge_ch: list[int] = []
    calib: list[FloatArray] = []
    for lc in setup.load_cells:
        gauge_ch += [lab.channel_index(n) for n in gauge_names(lc.node)]
        calib.append(np.asarray(np.linalg.pinv(lab.gauge_matrix(lc.node)), dtype=np.float64))
    channels = np.array([hammer_ch, *range(n_acc), *gauge_ch], dtype=np.intp)
    # DC-coupled bridges carry a zero and the static load: tare them before the first strike,
    # as the amplifier does (AC-coupled gauges read zero at rest).
    tare = np.zeros(len(gauge_ch))
    dc = np.array([lab.channel_units[c] == "mV/V" for c in gauge_ch], dtype=bool)
    if dc.any():
        tare[dc] = lab.read(np.array(gauge_ch, dtype=np.intp)[dc], 0, lab.block_samples).mean(1)

    # Windows: the pulse peaks 6σ after the strike and is over 6σ later.
    pulse_end = pre + int(np.ceil(12 * lab.sigma_s * fs)) + 2
    tau = acq.exponential_tau_s
    w_exp = np.ones(N) if tau is None else exponential_window(N, fs, tau, start_sample=pre)
    w_force = force_window(N, min(pulse_end, N), taper_samples=4) * w_exp

    n_in = len(setup.excitations)
    n_out = n_acc + 6 * len(setup.load_cells)
    inputs = np.empty((n_in, n_avg, 1, N))
    outputs = np.empty((n_in, n_avg, n_out, N))
    rng = np.random.default_rng([built.seed, 41])
    cursor, strikes, rejected = lab.block_samples if dc.any() else 0, 0, 0
    for j in range(n_in):
        got = 0
        while got < n_avg:
            if strikes > 3 * n_in * n_avg + 10:
                raise SetupError(
                    f"scenario {spec.name}: too many double hits to collect {n_avg} averages; "
                    "lower hammer.double_hit_probability"
                )
            lab.excite(j, cursor + pre)
            strikes += 1
            rec = lab.read(channels, cursor, N)
            cursor += N + settle + int(rng.integers(0, N))  # a human operator's rhythm
            if double_hit_mask(rec[0:1])[0]:
                rejected += 1
                continue
            inputs[j, got, 0] = rec[0]
            outputs[j, got, :n_acc] = rec[1 : 1 + n_acc]
            for c, C in enumerate(calib):
                g = rec[1 + n_acc + 12 * c : 1 + n_acc + 12 * (c + 1)]
                g = g - tare[12 * c : 12 * (c + 1), None]
                outputs[j, got, n_acc + 6 * c : n_acc + 6 * (c + 1)] = C @ g
            got += 1
    H_cols, coh_cols = [], []
    for j in range(n_in):
        est = estimate_frf(
            inputs[j], outputs[j], fs, estimator="H1", input_window=w_force, output_window=w_exp
        )
        H_cols.append(est.H[:, :, 0])
        coh_cols.append(est.ordinary_coherence[:, :, 0])
    freqs = est.frequencies_hz
    top = spec.frequency_axis.max_hz if max_hz is None else max_hz
    keep = (freqs > 0) & (freqs <= top)
    H = np.stack(H_cols, axis=2)[keep]
    coh = np.nan_to_num(np.stack(coh_cols, axis=2)[keep], nan=0.0)
    model_frf = built.model_frf(rigid_only=rigid_only, frequencies_hz=freqs[keep])
    frf = model_frf.replace(
        H=H,
        coherence=coh,
        meta={
            "source": f"dimacq simulate {spec.name} --time-domain",
            "estimator": "H1",
            "exponential_tau_s": "" if tau is None else f"{tau:g}",
            "averages": str(n_avg),
        },
    )
    log.info(
        "impact test %s: %d strikes (%d double hits rejected), %d samples",
        spec.name,
        strikes,
        rejected,
        cursor,
    )
    return ImpactRun(frf, tau, strikes, rejected, cursor)
