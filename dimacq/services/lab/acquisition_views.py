"""What the operator sees and keeps of an acquisition: one hit's traces and spectra, and FRF
sets merged from several acquisitions (redo one input, append inputs)."""

from __future__ import annotations

import queue
import threading
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from dimacq.errors import DataError
from dimacq.model.channels import input_name
from dimacq.model.frf import FrfData
from dimacq.model.setup import TestSetup
from dimacq.services.lab.common import json_safe

__all__ = ["Decision", "LiveReview", "hit_view", "merge_frfs"]

#: the operator's decision; ``"override"``: accept a hit the checks rejected (API: ``accept``
#: with ``override: true``)
Decision = Literal["accept", "reject", "redo", "override"]


@dataclass
class LiveReview:
    """What only the running job knows: the hit waiting for review, the operator's decisions,
    whether every hit is reviewed (the operator may switch it during the run), the finish
    request, the coherence of the inputs done, the strikes lost to DAQ gaps per input."""

    review: bool
    n_inputs: int
    sample_rate_hz: float = 0.0
    pending: dict[str, Any] | None = None
    pending_view: dict[str, Any] | None = None
    last_view: dict[str, Any] | None = None
    decisions: queue.Queue[tuple[int, Decision]] = field(default_factory=queue.Queue)
    #: the last hit a decision was given for (it is not announced again while the job takes it)
    answered: int = 0
    lock: threading.Lock = field(default_factory=threading.Lock)
    finish: threading.Event = field(default_factory=threading.Event)
    coherence: list[float | None] = field(default_factory=list)
    #: per struck input: the reason of every strike lost while waiting for it (DAQ samples lost)
    lost: list[list[str]] = field(default_factory=list)

    def current_hit(self) -> dict[str, Any] | None:
        """The hit waiting for review, else the one just decided (not yet recorded by the job),
        else the last recorded one; None when there is none."""
        with self.lock:
            pending, view, last = self.pending, self.pending_view, self.last_view
            answered = self.answered
        if pending is not None and view is not None:
            return json_safe({**view, **pending, "pending": True})
        if view is not None:  # decided, not yet recorded by the job
            return json_safe({**view, "number": answered, "pending": False})
        if last is not None:
            return json_safe({**last, "pending": False})
        return None

    @staticmethod
    def keep_newest_views(lives: Mapping[int, LiveReview], keep: int = 16) -> None:
        """Forget the hits' traces of all but the ``keep`` newest acquisitions (insertion
        order): memory, and the garbage collector's work. Older ones keep their coherence; GET
        .../hit answers 404 for them, as after a restart of the service."""
        for old in list(lives)[:-keep]:
            lives[old].drop_views()

    def drop_views(self) -> None:
        """Forget the hits' traces (an acquisition long finished: :meth:`current_hit` is None)."""
        with self.lock:
            self.pending_view = self.last_view = None


def hit_view(
    record: Mapping[str, NDArray[np.float64]], fs: float, n_responses: int
) -> dict[str, Any]:
    """What the operator sees of one hit: the force and the strongest response, and spectra.

    ``record``: ``"force"`` (1, n) N and ``"outputs"`` (n_outputs, n) (responses first,
    m/s²). Spectra are the magnitudes of the one-sided DFT, ``|X_k| = |Σ x_n e^{-2πikn/N}| / N``
    in dB re their own maximum (a hammer's force spectrum should fall by at most 10–20 dB over the
    band used: below that the input does not excite the band), at ``f_k = k fs / N``.

    Returns
    -------
    dict
        Arrays as numpy arrays (:meth:`LiveReview.current_hit` makes them JSON):
        ``sample_rate_hz``, ``time_s`` (n,), ``force_n`` (n,), ``response`` (its index),
        ``response_ms2`` (n,), ``frequencies_hz`` (n//2+1,), ``force_db``, ``response_db``,
        ``peak_force_n``.
    """
    force = np.asarray(record["force"], dtype=float)[0]
    outs = np.asarray(record["outputs"], dtype=float)[: max(1, n_responses)]
    k = int(np.nanargmax(np.nanmax(np.abs(outs), axis=1))) if outs.size else 0
    resp = outs[k] if outs.size else np.zeros_like(force)
    n = force.size
    fs = fs if fs > 0 else 1.0

    def db(x: NDArray[np.float64]) -> NDArray[np.float64]:
        mag = np.abs(np.fft.rfft(np.nan_to_num(x))) / max(n, 1)
        return 20 * np.log10(np.maximum(mag, 1e-300) / max(float(mag.max()), 1e-300))

    # numpy arrays, made JSON (lists, NaN → null) only when asked for (LiveReview.current_hit):
    # kept as lists of Python floats, every finished acquisition's last hit (10⁴ floats each)
    # was walked by each full garbage collection: ~80 ms per 300 acquisitions, under the GIL
    return {
        "sample_rate_hz": fs,
        "time_s": np.arange(n) / fs,
        "force_n": force.copy(),  # not views: the record's arrays are not kept alive
        "response": k,
        "response_ms2": resp.copy(),
        "frequencies_hz": np.fft.rfftfreq(n, 1 / fs),
        "force_db": np.maximum(db(force), -120.0),
        "response_db": np.maximum(db(resp), -120.0),
        "peak_force_n": float(np.nanmax(np.abs(force))) if n else 0.0,
    }


def merge_frfs(base: FrfData, new: FrfData, setup: TestSetup) -> FrfData:
    """``base`` with the inputs of ``new`` replaced (redo) or added (append), in setup order.

    Raises
    ------
    DataError
        Different frequency lines or outputs (other acquisition settings): nothing to merge.
    """
    if base.frequencies_hz.shape != new.frequencies_hz.shape or not np.allclose(
        base.frequencies_hz, new.frequencies_hz, rtol=1e-9, atol=1e-9
    ):
        raise DataError(
            f"FRF set lines {base.frequencies_hz.size} × {base.frequencies_hz[1] - base.frequencies_hz[0]:g} Hz "
            "differ from the new acquisition's; acquire with the same record_samples and rate"
        )
    if base.outputs != new.outputs:
        raise DataError(
            "the FRF set's outputs differ from the new acquisition's; use the same setup"
        )
    cols: dict[Any, tuple[NDArray[np.complex128], NDArray[np.float64] | None]] = {}
    for j, ch in enumerate(base.inputs):
        cols[ch] = (base.H[:, :, j], None if base.coherence is None else base.coherence[:, :, j])
    for j, ch in enumerate(new.inputs):
        cols[ch] = (new.H[:, :, j], None if new.coherence is None else new.coherence[:, :, j])
    order = [(e.node, e.direction) for e in setup.excitations]
    chans = sorted(
        cols,
        key=lambda c: (
            order.index((c.node, c.direction)) if (c.node, c.direction) in order else len(order)
        ),
    )
    H = np.stack([cols[c][0] for c in chans], axis=2)
    cohs = [cols[c][1] for c in chans]
    coh = (
        None
        if any(c is None for c in cohs)
        else np.stack([c for c in cohs if c is not None], axis=2)
    )
    done = {(c.node, c.direction) for c in chans}
    missing = [input_name(e) for e in setup.excitations if (e.node, e.direction) not in done]
    meta = {k: v for k, v in {**base.meta, **new.meta}.items() if k != "incomplete_inputs"}
    if missing:
        meta["incomplete_inputs"] = ", ".join(missing)
    return FrfData(
        frequencies_hz=base.frequencies_hz,
        H=H,
        outputs=base.outputs,
        output_kinds=base.output_kinds,
        inputs=tuple(chans),
        coherence=coh,
        meta=meta,
    )
