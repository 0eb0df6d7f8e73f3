"""Digitizing session: a digitizer device + triangulation + registration, nothing ever lost.

:class:`DigitizingSession` fires shots on a :class:`dimacq.devices.digitizer.Digitizer`,
triangulates them (:mod:`dimacq.pipeline.digitizing.triangulation`), combines the shots of each
point robustly and keeps every accepted point with its patch (array position). Each patch is
registered in the GCS from reference nodes (:mod:`dimacq.pipeline.digitizing.registration`).

Robustness: a corrupted record or a timeout is retried; when the port vanishes the session calls
``device.reconnect()`` and carries on. Points already digitized stay in memory (and, with a
``journal`` callback such as :class:`JsonlJournal`, on disk as soon as they are accepted); the
shots of a point interrupted by a lost port are kept and the point resumes on the next
:meth:`DigitizingSession.digitize` call with the same label.

The digitizer's configuration files are read by
:mod:`dimacq.services.geometry.digitizer_config`.
"""

from __future__ import annotations

import json
import logging
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from dimacq.devices.digitizer import Digitizer, ShotRecord
from dimacq.errors import (
    DataError,
    DeviceError,
    DeviceNotFoundError,
    DeviceTimeoutError,
    ProtocolError,
    SetupError,
)
from dimacq.pipeline.digitizing.registration import (
    Registration,
    register,
    three_point_frame,
)
from dimacq.pipeline.digitizing.triangulation import (
    DigitizerGeometry,
    PointEstimate,
    QualityLimits,
    combine_shots,
    triangulate,
)
from dimacq.services.geometry.geometry_trust import judge_registration

__all__ = [
    "DigitizedPoint",
    "DigitizingSession",
    "JsonlJournal",
    "Patch",
    "records_to_arrays",
]

log = logging.getLogger(__name__)
FloatArray = NDArray[np.float64]


# ---------------------------------------------------------------------------- records


def records_to_arrays(
    records: Sequence[ShotRecord],
) -> tuple[
    NDArray[np.int64], NDArray[np.int64], NDArray[np.int64], NDArray[np.int64], NDArray[np.int64]
]:
    """Stack shot records: ``counts (N, E, M)``, ``bar (N, B)``, ``averaging``, ``status``, ``seq``.

    Raises
    ------
    DataError
        Records with different shapes (settings changed between shots): triangulate separately.
    """
    if not records:
        raise DataError("no shot records to triangulate; fire at least one shot")
    shapes = {(r.counts.shape, r.bar_counts.shape) for r in records}
    if len(shapes) != 1:
        raise DataError(
            f"shot records have different shapes {sorted(shapes)}; triangulate each group"
        )
    counts = np.stack([r.counts for r in records]).astype(np.int64)
    bar = np.stack([r.bar_counts for r in records]).astype(np.int64)
    avg = np.array([r.averaging for r in records], dtype=np.int64)
    status = np.array([r.status for r in records], dtype=np.int64)
    seq = np.array([r.seq for r in records], dtype=np.int64)
    return counts, bar, avg, status, seq


# ---------------------------------------------------------------------------- session


@dataclass(frozen=True)
class DigitizedPoint:
    """One accepted point.

    Attributes
    ----------
    label : str
    patch : int
        Index of the array position it was digitized from.
    position_array_m : ndarray, shape (3,)
        DACS coordinates (combined shots).
    spread_m : ndarray, shape (3,)
        Standard deviation of the shots kept.
    n_shots, n_used : int
    seqs : tuple of int
        Sequence numbers of all shots fired for this point.
    """

    label: str
    patch: int
    position_array_m: FloatArray
    spread_m: FloatArray
    n_shots: int
    n_used: int
    seqs: tuple[int, ...]

    def to_json(self) -> dict[str, Any]:
        return {
            "label": self.label,
            "patch": self.patch,
            "position_array_m": [float(v) for v in self.position_array_m],
            "spread_m": [float(v) for v in self.spread_m],
            "n_shots": self.n_shots,
            "n_used": self.n_used,
            "seqs": list(self.seqs),
        }


@dataclass
class Patch:
    """An array position; ``registration`` maps its DACS into the GCS once known."""

    index: int
    name: str
    registration: Registration | None = None


class JsonlJournal:
    """Journal callback: appends each accepted point as one JSON line to ``path`` (flushed)."""

    def __init__(self, path: Path | str) -> None:
        self.path = Path(path)

    def __call__(self, point: DigitizedPoint) -> None:
        with self.path.open("a", encoding="utf-8") as fh:
            fh.write(json.dumps(point.to_json()) + "\n")
            fh.flush()

    def read(self) -> list[dict[str, Any]]:
        """Entries written so far."""
        if not self.path.exists():
            return []
        return [json.loads(line) for line in self.path.read_text().splitlines() if line.strip()]


@dataclass
class _Pending:
    records: list[ShotRecord] = field(default_factory=list)


class DigitizingSession:
    """Digitize labelled points patch by patch.

    Parameters
    ----------
    device : Digitizer
    geometry : DigitizerGeometry
    limits : QualityLimits, optional
    shots_per_point : int
        Accepted shots wanted per point.
    max_shots_per_point : int
        Give up on a point (DataError; its shots stay pending) after this many shots.
    journal : callable, optional
        Called with each accepted :class:`DigitizedPoint` (e.g. :class:`JsonlJournal`).
    max_reconnects : int
        Reconnects tried per point before giving up (DeviceNotFoundError; nothing is lost).

    Attributes
    ----------
    on_device : callable (lost), optional
        Told what the session sees of the port: why it is lost (``"port lost (...)"``), then
        ``""`` once it is reopened (the service's device state, ``/api/status``).
    """

    def __init__(
        self,
        device: Digitizer,
        geometry: DigitizerGeometry,
        limits: QualityLimits | None = None,
        *,
        shots_per_point: int = 5,
        max_shots_per_point: int = 20,
        journal: Callable[[DigitizedPoint], None] | None = None,
        max_reconnects: int = 3,
    ) -> None:
        if shots_per_point < 1 or max_shots_per_point < shots_per_point:
            raise SetupError(
                f"digitizing session: shots_per_point {shots_per_point} must be >= 1 and <= "
                f"max_shots_per_point {max_shots_per_point}"
            )
        self.device = device
        self.geometry = geometry
        self.limits = limits or QualityLimits()
        self.shots_per_point = shots_per_point
        self.max_shots_per_point = max_shots_per_point
        self.journal = journal
        self.max_reconnects = max_reconnects
        self.patches: list[Patch] = [Patch(0, "patch 0")]
        self._points: list[DigitizedPoint] = []
        self._pending: dict[tuple[int, str], _Pending] = {}
        self.shots_fired = 0
        self.retries = 0
        self.reconnects = 0
        self.on_device: Callable[[str], None] | None = None

    # ------------------------------------------------------------------ patches
    @property
    def patch(self) -> Patch:
        return self.patches[-1]

    def new_patch(self, name: str | None = None) -> Patch:
        """The array moved: points from now on belong to a new patch (register it again)."""
        p = Patch(len(self.patches), name or f"patch {len(self.patches)}")
        self.patches.append(p)
        return p

    # ------------------------------------------------------------------ points
    @property
    def points(self) -> list[DigitizedPoint]:
        """Every accepted point so far, in order (a copy)."""
        return list(self._points)

    def pending_shots(self, label: str) -> int:
        """Shots already fired for an unfinished point of the current patch."""
        pend = self._pending.get((self.patch.index, label))
        return len(pend.records) if pend else 0

    def _fire_one(self, reconnects_left: list[int]) -> ShotRecord | None:
        try:
            return self.device.fire()
        except (ProtocolError, DeviceTimeoutError) as err:
            self.retries += 1
            log.warning("digitizing: shot failed (%s); firing again", err)
            return None
        except DeviceNotFoundError as err:
            if reconnects_left[0] <= 0:
                raise DeviceNotFoundError(
                    f"digitizing: port lost and reconnect failed ({err}); the {len(self._points)} points "
                    "digitized so far are kept: fix the connection and call digitize() again"
                ) from err
            reconnects_left[0] -= 1
            log.warning("digitizing: port lost (%s); reconnecting", err)
            self._tell_device(f"port lost ({err}); reconnecting")
            try:
                self.device.reconnect()
            except DeviceNotFoundError as again:
                self._tell_device(f"port lost, reconnect failed ({again})")
                raise DeviceNotFoundError(
                    f"digitizing: port lost and reconnect failed ({again}); the {len(self._points)} "
                    "points digitized so far are kept: fix the connection and call digitize() again"
                ) from again
            self.reconnects += 1
            self._tell_device("")
            return None

    def _tell_device(self, lost: str) -> None:
        if self.on_device is not None:
            self.on_device(lost)

    def fire(self, n: int) -> list[ShotRecord]:
        """Fire ``n`` raw shots (not kept as a point): a shot whose reply was damaged on the
        link is fired again, a lost port reconnected (as :meth:`digitize`).

        Raises
        ------
        DeviceNotFoundError
            The port is gone and reconnecting failed.
        DeviceError
            More than ``max_shots_per_point`` shots failed in a row.
        """
        reconnects_left = [self.max_reconnects]
        records: list[ShotRecord] = []
        failed = 0
        while len(records) < n:
            rec = self._fire_one(reconnects_left)
            if rec is None:
                failed += 1
                if failed > self.max_shots_per_point:
                    raise DeviceError(
                        f"digitizer: {failed} shots in a row failed (damaged replies or "
                        "timeouts); check the cable and the port"
                    )
                continue
            failed = 0
            records.append(rec)
            self.shots_fired += 1
        return records

    def digitize(self, label: str, shots: int | None = None) -> DigitizedPoint:
        """Fire until ``shots`` accepted shots (default ``shots_per_point``) and keep the point.

        Raises
        ------
        DataError
            Too few accepted shots within ``max_shots_per_point`` (echoes): the shots stay pending,
            call again to continue.
        DeviceNotFoundError
            The port is gone and reconnecting failed; the shots stay pending.
        """
        want = shots or self.shots_per_point
        key = (self.patch.index, label)
        pend = self._pending.setdefault(key, _Pending())
        reconnects_left = [self.max_reconnects]
        fired_here = 0
        est: PointEstimate | None = None
        while True:
            if pend.records:
                counts, bar, avg, status, _ = records_to_arrays(pend.records)
                sol = triangulate(
                    counts, bar, self.geometry, averaging=avg, status=status, limits=self.limits
                )
                if int(sol.accepted.sum()) >= want:
                    est = combine_shots(sol.tip_m, sol.accepted, self.limits.point_outlier_m)
                    break
            if fired_here >= self.max_shots_per_point:
                raise DataError(
                    f"point {label!r}: fewer than {want} accepted shots in {fired_here} (echoes?); "
                    "the shots are kept: move the probe or the array and call digitize() again"
                )
            rec = self._fire_one(reconnects_left)
            if rec is not None:
                pend.records.append(rec)
                self.shots_fired += 1
                fired_here += 1
        point = DigitizedPoint(
            label=label,
            patch=self.patch.index,
            position_array_m=est.position_m,
            spread_m=est.spread_m,
            n_shots=est.n_shots,
            n_used=est.n_used,
            seqs=tuple(r.seq for r in pend.records),
        )
        del self._pending[key]
        self._points.append(point)
        if self.journal is not None:
            self.journal(point)
        return point

    # ------------------------------------------------------------------ registration
    def _patch_points(self, patch: int, labels: Sequence[str]) -> FloatArray:
        found = {p.label: p.position_array_m for p in self._points if p.patch == patch}
        missing = [lab for lab in labels if lab not in found]
        if missing:
            raise SetupError(
                f"patch {patch}: reference node(s) {missing} not digitized in this patch; digitize them first"
            )
        return np.array([found[lab] for lab in labels])

    def register_patch(
        self,
        references_global_m: Mapping[str, ArrayLike],
        method: str = "rigid",
        limit_m: float | None = None,
    ) -> Registration:
        """Register the current patch from reference nodes (label → known GCS coordinates).

        With ``limit_m`` a node residual above it refuses the registration (``DataError`` naming
        the worst node; the patch stays unregistered), see
        :func:`dimacq.services.geometry.geometry_trust.judge_registration`.
        """
        labels = list(references_global_m)
        xa = self._patch_points(self.patch.index, labels)
        xg = np.array([np.asarray(references_global_m[lab], dtype=float) for lab in labels])
        if limit_m is None:
            reg = register(xa, xg, method=method)
        else:
            self.patch.registration = None
            reg, _ = judge_registration(
                xa, xg, labels, limit_m=limit_m, prior_sigma_m=0.0, method=method
            )
        self.patch.registration = reg
        return reg

    def define_frame(self, origin: str, on_x: str, in_xz: str) -> Registration:
        """Three-point frame from three digitized labels of the current patch (DACS ≡ GCS)."""
        pts = self._patch_points(self.patch.index, [origin, on_x, in_xz])
        reg = three_point_frame(*pts)
        self.patch.registration = reg
        return reg

    def global_position(self, point: DigitizedPoint) -> FloatArray:
        """GCS coordinates of a point through its patch's registration."""
        reg = self.patches[point.patch].registration
        if reg is None:
            raise SetupError(
                f"point {point.label!r}: its patch {point.patch} is not registered; register it from "
                "reference nodes"
            )
        return reg.apply(point.position_array_m)

    def global_points(self) -> dict[str, FloatArray]:
        """Label → GCS position of every point whose patch is registered (last one wins)."""
        out: dict[str, FloatArray] = {}
        for p in self._points:
            if self.patches[p.patch].registration is not None:
                out[p.label] = self.global_position(p)
        return out
