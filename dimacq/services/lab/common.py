"""Small helpers shared by the lab's services (JSON-safe values, vectors, identities)."""

from __future__ import annotations

from dataclasses import asdict, is_dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np

from dimacq.services.geometry.records import vec as vec

__all__ = ["identity_dict", "iso", "json_safe", "package_version", "vec"]


def iso(t: datetime | None) -> str | None:
    """A stored time as ISO 8601 in UTC (``2026-11-23T11:40:06.123456+00:00``); SQLite gives
    back naive times, which were stored as UTC."""
    if t is None:
        return None
    return (t if t.tzinfo is not None else t.replace(tzinfo=UTC)).astimezone(UTC).isoformat()


def json_safe(obj: Any) -> Any:
    """NaN/inf → None and numpy → Python, so the JSON is strict."""
    if isinstance(obj, dict):
        return {str(k): json_safe(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [json_safe(v) for v in obj]
    if isinstance(obj, np.ndarray):
        if obj.dtype.kind == "f":  # vectorised: a hit's traces are 10⁴ floats
            out = obj.astype(object)
            out[~np.isfinite(obj)] = None
            return out.tolist()
        return json_safe(obj.tolist())
    if isinstance(obj, np.generic):
        return json_safe(obj.item())
    if isinstance(obj, float) and not np.isfinite(obj):
        return None
    if isinstance(obj, Path):
        return str(obj)
    return obj


def identity_dict(ident: Any) -> dict[str, Any]:
    """A driver's identity (a dataclass) as the JSON object of the device list."""
    if is_dataclass(ident) and not isinstance(ident, type):
        return dict(asdict(ident))
    return {"identity": str(ident)}


def package_version() -> str:
    try:
        from importlib.metadata import version

        return version("dimacq")
    except Exception:
        return "unknown"
