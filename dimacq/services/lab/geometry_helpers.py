"""Small helpers of the geometry service: stored points and registrations from their rows, vectors,
bulk deletes."""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import numpy as np
from sqlalchemy import select

from dimacq.persistence import models as m
from dimacq.services.geometry.records import Registration, StoredPoint
from dimacq.services.lab.common import iso

if TYPE_CHECKING:
    pass


def vec3(v: Sequence[float]) -> tuple[float, float, float]:
    return (float(v[0]), float(v[1]), float(v[2]))


def delete_all(s: Any, model: Any) -> int:
    rows = list(s.scalars(select(model)))
    for r in rows:
        s.delete(r)
    return len(rows)


def distinct(regs: Any) -> list[dict[str, Any]]:
    """The distinct registration records among ``regs`` (one per patch used), as JSON."""
    out: list[Registration] = []
    for r in regs:
        if not any(r is o for o in out):
            out.append(r)
    return [r.to_json() for r in out]


def finite_or_none(x: float | np.floating[Any]) -> float | None:
    """A finite number, or None (JSON null) for NaN/inf (a shot that was not triangulated)."""
    v = float(x)
    return v if np.isfinite(v) else None


def stored_point(r: m.DigitizedPointRow, regs: dict[int, Registration]) -> StoredPoint:
    reg = regs.get(r.patch)
    return StoredPoint(
        id=r.id,
        label=r.label,
        patch=r.patch,
        position_array_m=list(r.position_array_m),
        spread_m=list(r.spread_m),
        n_shots=r.n_shots,
        n_used=r.n_used,
        position_m=reg.apply(r.position_array_m) if reg else None,
        created_at=iso(r.created_at),
    )


def registrations_of(s: Any) -> dict[int, Registration]:
    return {
        p.index: Registration.from_json(p.registration)
        for p in s.scalars(select(m.PatchRow))
        if p.registration
    }
