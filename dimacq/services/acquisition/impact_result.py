"""What an impact session reports: its progress, each average's verdict, the operator's decisions,
the result (:class:`ImpactResult`), and its FRFs as :class:`~dimacq.model.frf.FrfData`
(:func:`impact_frf`, the one conversion). Used by :mod:`dimacq.services.acquisition.session` and re-exported
there."""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from dimacq.errors import DataError
from dimacq.model.channels import input_name
from dimacq.model.frf import Channel, FrfData, OutputKind
from dimacq.model.impact import ImpactSettings
from dimacq.model.setup import TestSetup
from dimacq.pipeline.frf_estimation import estimate_frf, exponential_window, force_window

__all__ = [
    "OPERATOR_OVERRIDE",
    "OPERATOR_REDO",
    "OPERATOR_REJECT",
    "AverageCallback",
    "AverageRecord",
    "Decision",
    "ImpactResult",
    "Progress",
    "ReviewCallback",
    "impact_frf",
    "input_frf",
    "records_frf",
    "unusable_reasons",
]

#: ``on_average(input_index, average_index, accepted, reasons, blocks)``: ``average_index`` counts
#: every decided average of the session from 0 (accepted and rejected); ``blocks`` holds
#: ``"force"`` (1, n) N and ``"outputs"`` (n_outputs, n) in engineering units (responses, then
#: the load cells' rows), the record exactly as it enters (or would have entered) the FRFs.
AverageCallback = Callable[
    [int, int, bool, tuple[str, ...], Mapping[str, NDArray[np.float64]]], None
]

#: The operator's decision on one hit (see :class:`ImpactSession`); ``"override"``: accept a
#: hit the checks rejected, knowingly (never one with samples lost: :func:`unusable_reasons`).
Decision = Literal["accept", "reject", "redo", "override"]

#: ``review(input_index, average_index, reasons, blocks, wait_s) -> Decision | None``:
#: ``reasons`` are the automatic checks' (empty: passed), ``blocks`` as in
#: :data:`AverageCallback`. It waits at most ``wait_s`` seconds for the operator and answers None
#: when no decision came yet: the session then reads the DAQ's next block (the stream keeps
#: flowing, nothing overflows while the operator looks) and asks again with the same hit.
ReviewCallback = Callable[
    [int, int, tuple[str, ...], Mapping[str, NDArray[np.float64]], float], Decision | None
]

#: Reason of a hit the operator rejected.
OPERATOR_REJECT = "rejected by the operator"
#: Reason of a hit (and of the averages accepted before it) dropped by "redo this input".
OPERATOR_REDO = "input redone by the operator"
#: Reason kept with a hit the checks rejected and the operator accepted over them.
OPERATOR_OVERRIDE = "accepted by the operator over the checks"


def unusable_reasons(reasons: Sequence[str]) -> list[str]:
    """The checks' reasons that no override can lift: samples lost (DAQ or load cell), the
    record has no data there (NaN), so an FRF from it would be NaN. The others (overload, double
    hit, clock drift) are the operator's call."""
    return [r for r in reasons if "samples lost" in r]


@dataclass(frozen=True)
class Progress:
    input_index: int
    n_inputs: int
    accepted: int
    wanted: int
    rejected: int
    message: str


@dataclass(frozen=True)
class AverageRecord:
    input_index: int
    first_sample: int
    n_samples: int
    accepted: bool
    reasons: tuple[str, ...]


@dataclass(frozen=True, eq=False)
class ImpactResult:
    """FRFs of the test and the history of every average.

    Attributes
    ----------
    H : ndarray, shape (n_lines, n_outputs, n_inputs)
        Outputs: the response channels, then per load cell its 6 loads (N/N, N·m/N, cell
        frame) or its 12 gauges (V/N).
    coherence : ndarray, shape (n_lines, n_outputs, n_inputs)
        NaN for inputs with one average (undefined, see :func:`~dimacq.pipeline.
        frf_estimation.estimate_frf`).
    input_names : tuple of str
        The inputs with FRFs (the complete ones), in session order; ``input_indices`` their
        indices among the session's inputs.
    n_accepted : tuple of int
        Accepted averages of every session input.
    incomplete_inputs : tuple of str
        Inputs left with fewer than ``min_averages`` accepted averages (no FRF).
    min_averages : int
        The minimum that was applied.
    lost_strikes : tuple of int
        Per session input: strikes lost to DAQ sample gaps while waiting for them (asked again,
        not counted against the strike budget).
    """

    frequencies_hz: NDArray[np.float64]
    H: NDArray[np.complex128]
    coherence: NDArray[np.float64]
    output_names: tuple[str, ...]
    input_names: tuple[str, ...]
    averages: tuple[AverageRecord, ...]
    n_accepted: tuple[int, ...]
    input_indices: tuple[int, ...] = ()
    incomplete_inputs: tuple[str, ...] = ()
    min_averages: int = 1
    lost_strikes: tuple[int, ...] = ()


def impact_frf(
    result: ImpactResult, setup: TestSetup, *, meta: Mapping[str, str] | None = None
) -> FrfData:
    """The session's FRFs as :class:`FrfData` in the setup's channel order (the 0 Hz line dropped).

    Outputs: each response (accelerance, (m/s²)/N), then per load cell of the setup its six loads
    (directions 1..6, N/N and N·m/N, cell frame, as the driver's calibration matrix gives them);
    inputs: the setup's excitations with FRFs (``result.input_indices``; the incomplete ones are
    named in ``meta["incomplete_inputs"]``, e.g. ``"10+X, 12+Y"``). Needs a session run with
    ``loadcell_outputs="forces"``.

    Raises
    ------
    DataError
        The result's shape does not match the setup.
    """
    n_acc = len(setup.responses)
    n_out = n_acc + 6 * len(setup.load_cells)
    kept = result.input_indices or tuple(range(result.H.shape[2]))
    if (
        result.H.shape[1] != n_out
        or result.H.shape[2] != len(kept)
        or max(kept) >= len(setup.excitations)
    ):
        raise DataError(
            f"impact result has {result.H.shape[1]} outputs × {result.H.shape[2]} inputs; the setup "
            f"needs {n_out} × {len(setup.excitations)} (run the session with "
            "loadcell_outputs='forces')"
        )
    outputs = [Channel(c.node, c.direction) for c in setup.responses]
    kinds: list[OutputKind] = ["acceleration"] * n_acc
    for lc in setup.load_cells:
        outputs += [Channel(lc.node, k) for k in range(1, 7)]
        kinds += ["reaction"] * 6
    incomplete = [input_name(e) for j, e in enumerate(setup.excitations) if j not in kept]
    extra = {"incomplete_inputs": ", ".join(incomplete)} if incomplete else {}
    f = result.frequencies_hz
    # the 0 Hz line leads (ascending lines): a slice keeps views, not copies, of the arrays
    keep: slice | NDArray[np.bool_] = slice(1, None) if f.size and f[0] == 0 else f > 0
    return FrfData(
        frequencies_hz=result.frequencies_hz[keep],
        H=result.H[keep],
        outputs=tuple(outputs),
        output_kinds=tuple(kinds),
        inputs=tuple(
            Channel(setup.excitations[j].node, setup.excitations[j].direction) for j in kept
        ),
        coherence=result.coherence[keep],
        meta={"source": "dimacq impact acquisition", **extra, **(meta or {})},
    )


def input_frf(
    records: Sequence[Mapping[str, NDArray[np.float64]]], fs: float, settings: ImpactSettings
) -> tuple[NDArray[np.float64], NDArray[np.complex128], NDArray[np.float64]]:
    """One input's FRFs from its accepted records, as the live session estimates them (and
    as an acquisition finished after a crash does, from the records kept on disk).

    ``records``: per average ``"force"`` (1, n) N and ``"outputs"`` (n_outputs, n), the
    ``n = record_samples`` samples starting ``pretrigger_samples`` before the trigger. The force
    window (``force_window_samples`` after the pretrigger) goes on the hammer, the exponential
    window (``exponential_tau_s``, from the trigger) on everything, then
    :func:`~dimacq.pipeline.frf_estimation.estimate_frf` with ``settings.estimator``.

    Returns
    -------
    frequencies_hz : ndarray, shape (n_lines,)
    H : ndarray, shape (n_lines, n_outputs)
    coherence : ndarray, shape (n_lines, n_outputs)
        Ordinary coherence (NaN with one average).
    """
    s = settings
    n = s.record_samples
    w_out = (
        exponential_window(n, fs, s.exponential_tau_s, start_sample=s.pretrigger_samples)
        if s.exponential_tau_s
        else np.ones(n)
    )
    w_in = w_out.copy()
    if s.force_window_samples:
        w_in *= force_window(n, min(n, s.pretrigger_samples + s.force_window_samples))
    x = np.stack([r["force"] for r in records])
    y = np.stack([r["outputs"] for r in records])
    est = estimate_frf(x, y, fs, estimator=s.estimator, input_window=w_in, output_window=w_out)
    return est.frequencies_hz, est.H[:, :, 0], est.ordinary_coherence[:, :, 0]


def records_frf(
    records: Sequence[Sequence[Mapping[str, NDArray[np.float64]]]],
    fs: float,
    settings: ImpactSettings,
    setup: TestSetup,
    *,
    meta: Mapping[str, str] | None = None,
) -> FrfData:
    """FRFs from kept records, as a session that accepted them would give them: the inputs with
    at least ``min(min_averages, averages_per_input)`` records each by :func:`input_frf`, in
    :class:`FrfData` by :func:`impact_frf` (the others named in ``meta["incomplete_inputs"]``).

    ``records``: per input of ``setup`` (in its order) its accepted records, as in
    :data:`AverageCallback`; ``fs`` the sample rate, Hz.

    Raises
    ------
    DataError
        No input has enough records, or ``records`` does not match the setup's inputs.
    """
    if len(records) != len(setup.excitations):
        raise DataError(
            f"{len(records)} lists of records for {len(setup.excitations)} inputs of the setup"
        )
    need = min(settings.min_averages, settings.averages_per_input)
    names = [input_name(e) for e in setup.excitations]
    kept = [j for j, r in enumerate(records) if len(r) >= need]
    if not kept:
        raise DataError(f"inputs {names}: fewer than {need} accepted averages each; no FRF")
    cols = [input_frf(records[j], fs, settings) for j in kept]
    result = ImpactResult(
        frequencies_hz=cols[0][0],
        H=np.stack([c[1] for c in cols], axis=2),
        coherence=np.stack([c[2] for c in cols], axis=2),
        output_names=(),
        input_names=tuple(names[j] for j in kept),
        averages=(),
        n_accepted=tuple(len(r) for r in records),
        input_indices=tuple(kept),
        incomplete_inputs=tuple(n for j, n in enumerate(names) if j not in kept),
        min_averages=need,
    )
    return impact_frf(result, setup, meta=meta)
