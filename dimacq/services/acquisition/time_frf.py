"""FRFs of a test from time data in files (:mod:`dimacq.io.time_data`: UFF 58 time records,
TDMS), through the same estimator and windows as an acquisition
(:func:`dimacq.pipeline.frf_estimation.estimate_frf`, the force and exponential windows of
:class:`~dimacq.services.acquisition.session.ImpactSession`) and the same conversion to
:class:`~dimacq.model.frf.FrfData` (:func:`~dimacq.services.acquisition.impact_result.impact_frf`)."""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Mapping, Sequence

import numpy as np
from numpy.typing import NDArray

from dimacq.errors import DataError
from dimacq.io.time_data import TimeRecord
from dimacq.model.channels import axis_name
from dimacq.model.frf import FrfData
from dimacq.model.setup import TestSetup
from dimacq.pipeline.frf_estimation import (
    Estimator,
    estimate_frf,
    exponential_window,
    force_window,
)
from dimacq.services.acquisition.impact_result import ImpactResult, impact_frf

__all__ = ["frf_from_time", "time_records"]


def time_records(
    setup: TestSetup,
    kept: Sequence[Sequence[Mapping[str, NDArray[np.float64]]]],
    fs: float,
) -> list[TimeRecord]:
    """An acquisition's kept records as time records (the export :func:`frf_from_time` and
    other systems read back): per input of ``setup`` and per accepted average, the force
    record (N) then each response (m/s², node and direction of the setup) and each load cell's
    six loads (N, N·m), exactly the samples that entered the live FRFs (before windows).

    ``kept``: per input its records as :data:`~dimacq.services.acquisition.impact_result.AverageCallback`
    gives them (``"force"`` (1, n), ``"outputs"`` (n_outputs, n)); ``fs`` the sample rate, Hz.

    Raises
    ------
    DataError
        ``kept`` does not match the setup's inputs or outputs.
    """
    chans = [("acceleration", c.node, c.direction) for c in setup.responses]
    for lc in setup.load_cells:
        chans += [("reaction", lc.node, d) for d in range(1, 7)]
    if len(kept) != len(setup.excitations):
        raise DataError(f"{len(kept)} inputs of records for {len(setup.excitations)} of the setup")
    out: list[TimeRecord] = []
    dt = 1.0 / fs
    for e, averages in zip(setup.excitations, kept, strict=True):
        for rec in averages:
            y = np.asarray(rec["outputs"], dtype=float)
            if y.shape[0] != len(chans):
                raise DataError(
                    f"input {axis_name(e.node, e.direction)}: {y.shape[0]} outputs per record, "
                    f"the setup has {len(chans)} (responses, then 6 loads per load cell)"
                )
            force = np.asarray(rec["force"], dtype=float).reshape(-1)
            out.append(TimeRecord(e.node, e.direction, e.node, e.direction, "force", dt, force))
            for (kind, node, d), row in zip(chans, y, strict=True):
                out.append(TimeRecord(node, d, e.node, e.direction, kind, dt, row))  # type: ignore[arg-type]
    return out


def frf_from_time(
    records: Sequence[TimeRecord],
    setup: TestSetup,
    *,
    pretrigger_samples: int = 0,
    force_window_samples: int | None = None,
    exponential_tau_s: float | None = None,
    estimator: Estimator = "H1",
    source: str = "time data",
    fft_threads: int = 1,
) -> FrfData:
    """FRFs of ``setup`` (its responses, then each load cell's six loads, per excitation) from
    time records.

    Per input (the setup's excitations, matched by node and direction), average ``a`` is the
    ``a``-th record of each channel struck at that input; the force window (``pretrigger +
    force_window_samples``) and the exponential window (``exponential_tau_s`` from the
    pretrigger) are applied as in an acquisition (None: rectangular). ``fft_threads``: threads of
    the estimator's FFTs (``estimate_frf(workers=...)``; the CLI gives the machine's cores, the
    live acquisition one, next to its streams).

    Raises
    ------
    DataError
        A setup input or channel without records, unequal averages or lengths, or sample
        intervals that differ.
    """
    by: dict[tuple[int, int], dict[tuple[str, int, int], list[NDArray[np.float64]]]] = defaultdict(
        lambda: defaultdict(list)
    )
    dts = set()
    for r in records:
        key = (r.kind, r.node, abs(r.direction) if r.kind != "reaction" else r.direction)
        sign = -1.0 if (r.kind != "reaction" and r.direction < 0) else 1.0
        by[(r.ref_node, abs(r.ref_direction))][key].append(sign * r.data)
        dts.add(round(r.dt_s, 15))
    if len(dts) != 1:
        raise DataError(f"time records have different sample intervals {sorted(dts)}; one rate")
    fs = 1.0 / dts.pop()
    keys = [("acceleration", c.node, abs(c.direction)) for c in setup.responses]
    signs = [1.0 if c.direction > 0 else -1.0 for c in setup.responses]
    for lc in setup.load_cells:
        keys += [("reaction", lc.node, d) for d in range(1, 7)]
        signs += [1.0] * 6
    H_all = coh_all = freqs = None
    names = []
    n_acc = []
    for j, e in enumerate(setup.excitations):
        name = axis_name(e.node, e.direction)
        chans = by.get((e.node, abs(e.direction)))
        if chans is None:
            raise DataError(f"input {name}: no time records struck there; give them or drop it")
        force = chans.get(("force", e.node, abs(e.direction)))
        if not force:
            raise DataError(f"input {name}: no force record (ordinate 13 / channel 'force')")
        missing = [f"{k[0]} {k[1]}:{k[2]}" for k in keys if not chans.get(k)]
        if missing:
            raise DataError(f"input {name}: no records of {', '.join(missing)}")
        n_avg = len(force)
        if any(len(chans[k]) != n_avg for k in keys):
            raise DataError(f"input {name}: channels have different numbers of averages")
        try:
            x = np.stack(force)[:, None, :] * (1.0 if e.direction > 0 else -1.0)
            y = np.stack(
                [np.stack([s * a for a in chans[k]]) for k, s in zip(keys, signs, strict=True)],
                axis=1,
            )
        except ValueError as err:
            raise DataError(f"input {name}: records of different lengths ({err})") from err
        n = x.shape[2]
        w_out = (
            exponential_window(n, fs, exponential_tau_s, start_sample=pretrigger_samples)
            if exponential_tau_s
            else np.ones(n)
        )
        w_in = w_out.copy()
        if force_window_samples:
            w_in *= force_window(n, min(n, pretrigger_samples + force_window_samples))
        est = estimate_frf(
            x,
            y,
            fs,
            estimator=estimator,
            input_window=w_in,
            output_window=w_out,
            workers=fft_threads,
        )
        if H_all is None:
            freqs = est.frequencies_hz
            H_all = np.zeros((*est.H.shape[:2], len(setup.excitations)), dtype=complex)
            coh_all = np.zeros(H_all.shape)
        elif est.H.shape[0] != H_all.shape[0]:
            raise DataError(f"input {name}: records of another length than the first input's")
        assert coh_all is not None
        H_all[:, :, j] = est.H[:, :, 0]
        coh_all[:, :, j] = est.ordinary_coherence[:, :, 0]
        names.append(name)
        n_acc.append(n_avg)
    assert H_all is not None and coh_all is not None and freqs is not None
    result = ImpactResult(
        frequencies_hz=freqs,
        H=H_all,
        coherence=coh_all,
        output_names=tuple(f"{k[0]} {k[1]}:{k[2]}" for k in keys),
        input_names=tuple(names),
        averages=(),
        n_accepted=tuple(n_acc),
        input_indices=tuple(range(len(names))),
        min_averages=min(n_acc),
    )
    return impact_frf(result, setup, meta={"source": source})
