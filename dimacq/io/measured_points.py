"""Labelled points measured by any instrument (a CMM, a laser tracker, photogrammetry, the
sonic digitizer's own export): a CSV or JSON file, read into points in the instrument's frame.

The points enter the digitizing pipeline as one patch (one set-up of the instrument: its own
frame), then go through the same registration from reference nodes, jig orientation and lines
of action as points the digitizer measured live (:meth:`dimacq.services.lab.geometry.
GeometryService.import_points`).

CSV: a header row naming ``label`` and the coordinates with their unit, ``x_m, y_m, z_m`` or
``x_mm, y_mm, z_mm``, and optionally ``sigma_m`` / ``sigma_mm`` (the point's standard
uncertainty per axis); ``#`` starts a comment line::

    # Faro arm, set-up 1
    label,x_mm,y_mm,z_mm,sigma_mm
    REF0,100.000,-200.000,1100.000,0.02
    1101-J01,...

JSON::

    {"schema_version": 1, "kind": "dimacq.measured_points", "instrument": "Leica AT960",
     "unit": "mm", "points": [{"label": "REF0", "xyz": [100.0, -200.0, 1100.0], "sigma": 0.02}]}
"""

from __future__ import annotations

import csv
import io
import math
from dataclasses import dataclass
from typing import Any, Literal

from dimacq.errors import SetupError
from dimacq.io.documents import loads_json
from dimacq.model.types import check_one_line

__all__ = [
    "MAX_POINTS",
    "MAX_POINTS_BYTES",
    "MeasuredPoint",
    "MeasuredPoints",
    "read_measured_points",
]

SCHEMA_VERSION = 1
KIND = "dimacq.measured_points"
_UNITS = {"m": 1.0, "mm": 1e-3}
#: The most points one import may hold (a laser tracker's survey of an article: hundreds).
MAX_POINTS = 5_000
#: The largest file of measured points, bytes (the API refuses a bigger one before reading it).
MAX_POINTS_BYTES = 4 * 2**20
#: The longest line of a CSV file, characters.
MAX_LINE_CHARS = 2_000
MAX_LABEL_CHARS = 200


@dataclass(frozen=True)
class MeasuredPoint:
    """A point in the instrument's frame: ``xyz_m`` metres, ``sigma_m`` its standard
    uncertainty per axis (None: not stated)."""

    label: str
    xyz_m: tuple[float, float, float]
    sigma_m: float | None = None


@dataclass(frozen=True)
class MeasuredPoints:
    instrument: str
    points: tuple[MeasuredPoint, ...]


def _number(v: Any, where: str) -> float:
    try:
        x = float(v)
    except (TypeError, ValueError):
        raise SetupError(f"{where}: {v!r} is not a number; give a decimal number") from None
    if not math.isfinite(x):
        raise SetupError(f"{where}: {v!r} is not finite; give a measured coordinate")
    return x


def _point(label: str, xyz: list[Any], sigma: Any, scale: float, where: str) -> MeasuredPoint:
    if not label or not label.strip():
        raise SetupError(f"{where}: the label is empty; name every point (e.g. REF0, 1101-J01)")
    if len(label) > MAX_LABEL_CHARS:
        raise SetupError(f"{where}: the label has {len(label)} characters; give at most 200")
    try:
        check_one_line(label)
    except ValueError as err:
        raise SetupError(f"{where}: the label {err}") from None
    if len(xyz) != 3:
        raise SetupError(f"{where}: {len(xyz)} coordinates; give x, y and z")
    x, y, z = (_number(v, f"{where} coordinate {i}") * scale for i, v in enumerate(xyz))
    s = None
    if sigma not in (None, ""):
        s = _number(sigma, f"{where} sigma") * scale
        if s < 0:
            raise SetupError(f"{where}: sigma {sigma} is negative; give its standard uncertainty")
    return MeasuredPoint(label.strip(), (x, y, z), s)


def _check_unique(points: list[MeasuredPoint], what: str) -> tuple[MeasuredPoint, ...]:
    seen: set[str] = set()
    for p in points:
        if p.label in seen:
            raise SetupError(
                f"{what}: label {p.label!r} appears twice; one line per point (an instrument's "
                "repeat: keep the one to use, or their mean)"
            )
        seen.add(p.label)
    if not points:
        raise SetupError(f"{what}: no points; give one row per labelled point")
    return tuple(points)


def _read_csv(text: str, what: str) -> MeasuredPoints:
    if text.count("\n") > MAX_POINTS + 1000:  # before any parsing: a cheap count
        raise SetupError(
            f"{what}: more than {MAX_POINTS} rows (MAX_POINTS); split the file into patches"
        )
    lines = [ln for ln in text.splitlines() if ln.strip() and not ln.lstrip().startswith("#")]
    for n, ln in enumerate(lines, start=1):
        if len(ln) > MAX_LINE_CHARS:
            raise SetupError(
                f"{what} line {n}: {len(ln)} characters, more than {MAX_LINE_CHARS} "
                "(MAX_LINE_CHARS); give one point per line: label, x, y, z[, sigma]"
            )
    if len(lines) > MAX_POINTS + 1:
        raise SetupError(
            f"{what}: {len(lines) - 1} rows, more than {MAX_POINTS} (MAX_POINTS); split the "
            "file into patches"
        )
    rows = list(csv.reader(io.StringIO("\n".join(lines))))
    if not rows:
        raise SetupError(f"{what}: empty; give a header row (label,x_mm,y_mm,z_mm) and points")
    header = [h.strip().lower() for h in rows[0]]
    unit = next((u for u in _UNITS if f"x_{u}" in header), None)
    if "label" not in header or unit is None:
        raise SetupError(
            f"{what}: header {rows[0]}: name the columns label and x_m,y_m,z_m or x_mm,y_mm,z_mm "
            "(the unit is part of the name)"
        )
    try:
        cols = [header.index(f"{a}_{unit}") for a in "xyz"]
    except ValueError:
        raise SetupError(f"{what}: header {rows[0]}: give y_{unit} and z_{unit} too") from None
    sig = header.index(f"sigma_{unit}") if f"sigma_{unit}" in header else None
    lab = header.index("label")
    pts = []
    for n, r in enumerate(rows[1:], start=2):
        where = f"{what} row {n}"
        if len(r) < len(header):
            raise SetupError(f"{where}: {len(r)} fields, the header has {len(header)}")
        pts.append(
            _point(
                r[lab], [r[c] for c in cols], None if sig is None else r[sig], _UNITS[unit], where
            )
        )
    return MeasuredPoints("", _check_unique(pts, what))


def _read_json(text: str, what: str) -> MeasuredPoints:
    doc = loads_json(text, what)  # size, depth, number and surrogate limits: one line each
    if not isinstance(doc, dict) or doc.get("kind") != KIND:
        raise SetupError(f'{what}: give a JSON object with "kind": "{KIND}"')
    if doc.get("schema_version") != SCHEMA_VERSION:
        raise SetupError(
            f"{what}: schema_version {doc.get('schema_version')!r}; this dimacq reads "
            f"{SCHEMA_VERSION}"
        )
    unit = doc.get("unit")
    if unit not in _UNITS:
        raise SetupError(f'{what}: unit {unit!r}; give "unit": "m" or "mm"')
    raw = doc.get("points")
    if not isinstance(raw, list):
        raise SetupError(f'{what}: "points" must be a list of {{label, xyz, sigma}}')
    if len(raw) > MAX_POINTS:
        raise SetupError(
            f"{what}: {len(raw)} points, more than {MAX_POINTS} (MAX_POINTS); split the file"
        )
    pts = []
    for n, p in enumerate(raw):
        where = f"{what} points[{n}]"
        if not isinstance(p, dict) or not isinstance(p.get("xyz"), list):
            raise SetupError(f'{where}: give {{"label": ..., "xyz": [x, y, z]}}')
        pts.append(_point(str(p.get("label", "")), p["xyz"], p.get("sigma"), _UNITS[unit], where))
    return MeasuredPoints(str(doc.get("instrument", "")), _check_unique(pts, what))


def read_measured_points(
    data: bytes | str, format: Literal["csv", "json"], *, what: str = "measured points"
) -> MeasuredPoints:
    """The points of a CSV or JSON file (see the module docstring).

    Raises
    ------
    SetupError
        A missing column, unit or label, a non-number, a repeated label (one line naming it).
    """
    if len(data) > MAX_POINTS_BYTES:
        raise SetupError(
            f"{what}: {len(data)} bytes, more than {MAX_POINTS_BYTES} (MAX_POINTS_BYTES); "
            "split the file into patches"
        )
    try:
        text = data.decode("utf-8-sig") if isinstance(data, bytes) else data
    except UnicodeDecodeError as err:
        raise SetupError(f"{what}: not UTF-8 text ({err}); save the file as UTF-8") from err
    if format == "csv":
        return _read_csv(text, what)
    if format == "json":
        return _read_json(text, what)
    raise SetupError(f"{what}: format {format!r}; give csv or json")
