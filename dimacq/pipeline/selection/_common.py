"""Shared helpers of the selection tools: matching FRF outputs to setup channels, robust outlier test."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from dimacq.errors import DataError, SetupError
from dimacq.model.frf import Channel, FrfData
from dimacq.model.setup import TestSetup

FloatArray = NDArray[np.float64]


@dataclass(frozen=True, eq=False)
class ResponseGeometry:
    """Accelerometer outputs of an FRF matched to the setup.

    Attributes
    ----------
    output_index : ndarray, shape (n_ch,)
        Index of each accelerometer output in ``frf.outputs``.
    channels : tuple of Channel
        The FRF's channel identities (node, UFF direction as recorded).
    positions_m : ndarray, shape (n_ch, 3)
    directions : ndarray, shape (n_ch, 3)
        Unit GCS direction of what the FRF record measures (sign of the record applied).
    setup_index : ndarray, shape (n_ch,)
        Index of the matching ``setup.responses`` entry.
    signs : ndarray, shape (n_ch,)
        +1 when the record's direction equals the setup channel's, −1 when opposite.
    """

    output_index: NDArray[np.intp]
    channels: tuple[Channel, ...]
    positions_m: FloatArray
    directions: FloatArray
    setup_index: NDArray[np.intp]
    signs: FloatArray

    @property
    def nodes(self) -> NDArray[np.int64]:
        return np.array([c.node for c in self.channels], dtype=np.int64)


def response_geometry(frf: FrfData, setup: TestSetup) -> ResponseGeometry:
    """Match the acceleration outputs of ``frf`` to ``setup.responses`` (same rule as ``assemble``)."""
    acc = frf.output_index("acceleration")
    if acc.size == 0:
        raise DataError("the FRFs hold no acceleration output; selection needs accelerometer FRFs")
    index = {(c.node, c.direction): i for i, c in enumerate(setup.responses)}
    pos, dirs, sidx, sg = [], [], [], []
    for i in acc:
        ch = frf.outputs[i]
        k = index.get((ch.node, ch.direction))
        s = 1.0
        if k is None:
            k = index.get((ch.node, -ch.direction))
            s = -1.0
        if k is None:
            raise SetupError(
                f"response {ch.name} of the FRFs is not in the setup; add it to responses "
                "with its position and direction, or drop the record"
            )
        rc = setup.responses[k]
        pos.append(rc.position_m)
        dirs.append(s * np.asarray(rc.direction_gcs, float))
        sidx.append(k)
        sg.append(s)
    return ResponseGeometry(
        output_index=acc,
        channels=tuple(frf.outputs[i] for i in acc),
        positions_m=np.asarray(pos, float).reshape(-1, 3),
        directions=np.asarray(dirs, float).reshape(-1, 3),
        setup_index=np.asarray(sidx, dtype=np.intp),
        signs=np.asarray(sg, float),
    )


def robust_outlier(
    value: float, others: FloatArray, *, ratio: float, z: float, floor: float = 1e-6
) -> tuple[bool, float, float]:
    """Is ``value`` an outlier against the sample ``others``?

    Outlier when ``value > ratio · median`` **and** ``value > median + z · σ̂`` with the robust scale
    ``σ̂ = max(1.4826 · MAD, 0.05 · median)`` (the floor keeps a very tight sample from flagging
    ordinary variation), **and** ``value > floor``: relative errors below ``floor`` (1e-6 by
    default, far below any measurement noise) are rounding, never evidence — without it noise-free
    data would lose channels or inputs to differences of 1e-15. Returns (outlier, median,
    threshold).
    """
    o = np.asarray(others, float)
    o = o[np.isfinite(o)]
    if o.size < 3:
        return False, float("nan"), float("inf")
    med = float(np.median(o))
    mad = 1.4826 * float(np.median(np.abs(o - med)))
    sig = max(mad, 0.05 * med)
    thr = max(ratio * med, med + z * sig, floor)
    return bool(value > thr), med, thr


def match_pairs(
    pairs: list[tuple[int, int]] | None, channels: tuple[Channel, ...]
) -> NDArray[np.bool_]:
    """Mask of ``channels`` named by (node, direction) pairs (either sign of the direction)."""
    mask = np.zeros(len(channels), dtype=bool)
    for node, d in pairs or []:
        for i, c in enumerate(channels):
            if c.node == node and abs(c.direction) == abs(d):
                mask[i] = True
    return mask
