"""Load cell calibration files: JSON (native) and ATI-style XML, import and export.

JSON (``schema_version`` 1)::

    {
      "schema_version": 1,
      "kind": "dimacq.loadcell_calibration",
      "serial_number": "LC501",
      "date": "2026-11-21",
      "method": "inertial",              # or "static"
      "version": 3,                      # counts the calibrations of this cell (optional, 1)
      "gauge_unit": "V",                 # or "mV/V" (strain-gauge bridges)
      "force_unit": "N",
      "moment_unit": "N*m",
      "matrix": [[12 numbers] x 6],        # rows Fx Fy Fz Mx My Mz, F = C g (6 x N:
                                         # N gauges, 12 usually; 6 conditioned outputs)
      "diagnostics": {"residual_rel": ..., ...},
      "certificate": {...},              # static: % FS per axis (optional)
      "notes": ""
    }

Versions: :func:`install_calibration` keeps every calibration of a cell as ``<stem>-v<N>.json``
and ``.xml`` beside the file the rig file names (``<stem>.json``), and replaces that file by the
new one (atomically), so the acquisition uses the newest calibration from then on and the older
ones stay for the record.

The XML follows the layout of ATI Industrial Automation's ``.cal`` files (an ``FTSensor`` element
with a ``Calibration`` child holding one ``Axis`` per load with a ``values`` attribute of
whitespace-separated gauge coefficients), with ``NumGages`` gauge columns (12 usually; 6 for a cell read through its six conditioned
outputs, ``gauge_unit`` ``"V"``); units are given as
``ForceUnits="N"`` and ``TorqueUnits="N-m"``. Only files written by trusted tools should be read
(the standard library parser is used).
"""

from __future__ import annotations

import datetime as _dt
import json
import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from dimacq.errors import DataError, SetupError
from dimacq.model.setup import one_line

__all__ = [
    "InstalledCalibration",
    "LoadCellCalibration",
    "install_calibration",
    "parse_calibration_json",
    "read_calibration",
    "read_calibration_json",
    "read_calibration_xml",
    "write_calibration_json",
    "write_calibration_xml",
]

SCHEMA_VERSION = 1
AXES = ("Fx", "Fy", "Fz", "Tx", "Ty", "Tz")
#: the pound-force by definition: 0.45359237 kg × 9.80665 m/s² (N); the inch 0.0254 m
LBF_N = 0.45359237 * 9.80665
_MOMENT_UNITS = {
    "N*m": 1.0,
    "N-m": 1.0,
    "Nm": 1.0,
    "N·m": 1.0,
    "N-mm": 1e-3,
    "N*mm": 1e-3,
    # ATI's .cal files of US-calibrated cells: TorqueUnits="lbf-in"
    "lbf-in": LBF_N * 0.0254,
    "lbf*in": LBF_N * 0.0254,
    "lbf·in": LBF_N * 0.0254,
    "lbf-ft": LBF_N * 0.3048,
    "lbf*ft": LBF_N * 0.3048,
    "lbf·ft": LBF_N * 0.3048,
}
_FORCE_UNITS = {"N": 1.0, "kN": 1e3, "lbf": LBF_N, "klbf": 1e3 * LBF_N}


@dataclass(frozen=True, eq=False)
class LoadCellCalibration:
    """A 6×N calibration of one load cell (N gauges, usually 12; or 6 conditioned outputs), in
    SI (N and N·m per gauge unit)."""

    serial_number: str
    date: str
    matrix: NDArray[np.float64]
    method: str = "inertial"
    gauge_unit: str = "V"
    diagnostics: dict[str, Any] = field(default_factory=dict)
    notes: str = ""
    version: int = 1
    certificate: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        m = np.asarray(self.matrix, dtype=float)
        if m.ndim != 2 or m.shape[0] != 6 or m.shape[1] < 6 or not np.all(np.isfinite(m)):
            raise DataError(
                f"calibration {self.serial_number}: matrix has shape {m.shape} or non-finite "
                "values; it must be a finite 6xN matrix, N >= 6 gauges or outputs (rows Fx Fy "
                "Fz Mx My Mz; 6x12 for a 12-gauge cell)"
            )
        if not self.serial_number:
            raise DataError("calibration without serial_number; give the load cell's serial")
        try:
            _dt.date.fromisoformat(self.date)
        except ValueError as err:
            raise DataError(
                f"calibration {self.serial_number}: date {self.date!r} is not ISO (YYYY-MM-DD)"
            ) from err
        object.__setattr__(self, "matrix", m)

    @property
    def n_gauges(self) -> int:
        """Columns of the matrix: gauges (or conditioned outputs) it combines."""
        return int(self.matrix.shape[1])

    def to_json(self) -> dict[str, Any]:
        return {
            "schema_version": SCHEMA_VERSION,
            "kind": "dimacq.loadcell_calibration",
            "serial_number": self.serial_number,
            "date": self.date,
            "method": self.method,
            "version": self.version,
            "gauge_unit": self.gauge_unit,
            "force_unit": "N",
            "moment_unit": "N*m",
            "matrix": self.matrix.tolist(),
            "diagnostics": self.diagnostics,
            "certificate": self.certificate,
            "notes": self.notes,
        }


def write_calibration_json(cal: LoadCellCalibration, path: str | Path) -> None:
    Path(path).write_text(json.dumps(cal.to_json(), indent=2) + "\n", encoding="utf-8")


def read_calibration_json(path: str | Path) -> LoadCellCalibration:
    p = Path(path)
    try:
        data = json.loads(p.read_text(encoding="utf-8"))
    except (OSError, json.JSONDecodeError) as err:
        raise DataError(f"{p}: cannot read calibration JSON ({err})") from err
    return parse_calibration_json(data, str(p))


#: Longest text of the one-line items of a calibration (serial number, date, method, gauge
#: unit), characters; and of its notes.
MAX_ITEM_CHARS = 100
MAX_NOTES_CHARS = 20_000


def _check_text(data: dict[str, Any], source: str) -> None:
    """The one-line items are one line of printable text of at most :data:`MAX_ITEM_CHARS`
    (the serial number names the cell in file names, in the XML export's ``Serial`` attribute
    and in every message), the notes at most :data:`MAX_NOTES_CHARS`.

    Raises
    ------
    SetupError
        Naming the item, the limit and the fix (answered 422 by the API).
    """
    for key, limit in (
        ("serial_number", MAX_ITEM_CHARS),
        ("date", MAX_ITEM_CHARS),
        ("method", MAX_ITEM_CHARS),
        ("gauge_unit", MAX_ITEM_CHARS),
        ("notes", MAX_NOTES_CHARS),
    ):
        value = data.get(key)
        if value is None:
            continue
        if isinstance(value, int | float):  # a serial number written as a number: read as text
            value = str(value)
        if not isinstance(value, str):
            raise SetupError(f"{source}: {key} must be a string, not {type(value).__name__}")
        if len(value) > limit:
            raise SetupError(
                f"{source}: {key} has {len(value)} characters, more than {limit} "
                f"({'MAX_NOTES_CHARS' if key == 'notes' else 'MAX_ITEM_CHARS'}); shorten it"
            )
        if key != "notes":
            try:
                one_line(value)
            except ValueError as err:
                raise SetupError(f"{source}: {key} {err}") from None


def _matrix(value: Any, source: str) -> NDArray[np.float64]:
    """The calibration matrix: six rows of the same number (6..64) of finite numbers."""
    if not isinstance(value, list) or len(value) != 6:
        raise DataError(
            f"{source}: matrix must be a list of 6 rows (Fx Fy Fz Mx My Mz); give the 6xN matrix"
        )
    width = len(value[0]) if isinstance(value[0], list) else -1
    for i, row in enumerate(value):
        if not isinstance(row, list) or len(row) != width or not 6 <= width <= 64:
            n = len(row) if isinstance(row, list) else "no"
            raise DataError(
                f"{source}: matrix[{i}] has {n} values, row 0 has {width}; give every row the "
                "same number (6..64) of gauge or output coefficients"
            )
        for j, v in enumerate(row):
            if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
                raise DataError(f"{source}: matrix[{i}][{j}] is {v!r}; give a finite number")
    return np.asarray(value, dtype=float)


def parse_calibration_json(data: Any, source: str = "calibration") -> LoadCellCalibration:
    """A calibration from its JSON document (already parsed); errors name ``source``."""
    if not isinstance(data, dict) or data.get("kind") != "dimacq.loadcell_calibration":
        raise DataError(f"{source}: not a dimacq load cell calibration (key 'kind' missing/wrong)")
    if data.get("schema_version") != SCHEMA_VERSION:
        raise DataError(
            f"{source}: schema_version {data.get('schema_version')!r}; this dimacq reads version "
            f"{SCHEMA_VERSION}"
        )
    for key in ("serial_number", "date", "matrix"):
        if key not in data:
            raise DataError(f"{source}: key {key!r} missing")
    _check_text(data, source)
    units = (data.get("force_unit", "N"), data.get("moment_unit", "N*m"))
    fu = _FORCE_UNITS.get(units[0]) if isinstance(units[0], str) else None
    mu = _MOMENT_UNITS.get(units[1]) if isinstance(units[1], str) else None
    if fu is None or mu is None:
        raise DataError(
            f"{source}: units {data.get('force_unit')!r}/{data.get('moment_unit')!r} unknown; "
            f"use one of {sorted(_FORCE_UNITS)} and {sorted(_MOMENT_UNITS)}"
        )
    for key in ("diagnostics", "certificate"):
        if not isinstance(data.get(key, {}), dict):
            raise DataError(f"{source}: {key} must be a table of named values (a JSON object)")
    m = _matrix(data["matrix"], source)
    if m.ndim == 2 and m.shape[0] == 6:
        m = m * np.array([fu] * 3 + [mu] * 3)[:, None]
    return LoadCellCalibration(
        serial_number=str(data["serial_number"]),
        date=str(data["date"]),
        matrix=m,
        method=str(data.get("method", "")),
        gauge_unit=str(data.get("gauge_unit", "V")),
        diagnostics=dict(data.get("diagnostics", {})),
        notes=str(data.get("notes", "")),
        version=_version(data.get("version", 1), source),
        certificate=dict(data.get("certificate", {})),
    )


def _version(v: Any, where: str | Path) -> int:
    if not isinstance(v, int) or isinstance(v, bool) or v < 1:
        raise DataError(f"{where}: version {v!r}; give a positive integer")
    return v


def write_calibration_xml(cal: LoadCellCalibration, path: str | Path) -> None:
    """ATI-style ``FTSensor``/``Calibration``/``Axis`` XML with the calibration's gauges."""
    root = ET.Element(
        "FTSensor",
        Serial=cal.serial_number,
        NumGages=str(cal.n_gauges),
        BodyStyle="dimacq-6DOF",
    )
    calel = ET.SubElement(
        root,
        "Calibration",
        CalDate=cal.date,
        ForceUnits="N",
        TorqueUnits="N-m",
        DistUnits="m",
        GageUnits=cal.gauge_unit,
        Method=cal.method,
        Version=str(cal.version),
    )
    for name, row in zip(AXES, cal.matrix, strict=True):
        ET.SubElement(calel, "Axis", Name=name, values=" ".join(f"{v:.17g}" for v in row))
    ET.indent(root)
    ET.ElementTree(root).write(path, encoding="utf-8", xml_declaration=True)


def read_calibration_xml(path: str | Path) -> LoadCellCalibration:
    p = Path(path)
    try:
        root = ET.parse(p).getroot()
    except (OSError, ET.ParseError) as err:
        raise DataError(f"{p}: cannot read calibration XML ({err})") from err
    calel = root.find("Calibration")
    if root.tag != "FTSensor" or calel is None:
        raise DataError(f"{p}: expected an FTSensor element with a Calibration child")
    fu = _FORCE_UNITS.get(calel.get("ForceUnits", "N"))
    mu = _MOMENT_UNITS.get(calel.get("TorqueUnits", "N-m"))
    if fu is None or mu is None:
        raise DataError(
            f"{p}: units {calel.get('ForceUnits')!r}/{calel.get('TorqueUnits')!r} unknown; "
            f"use one of {sorted(_FORCE_UNITS)} and {sorted(_MOMENT_UNITS)}"
        )
    rows = {}
    for ax in calel.findall("Axis"):
        try:
            rows[ax.get("Name")] = [float(v) for v in (ax.get("values") or "").split()]
        except ValueError as err:
            raise DataError(f"{p}: axis {ax.get('Name')}: values are not numbers") from err
    missing = [a for a in AXES if a not in rows]
    if missing:
        raise DataError(f"{p}: axes {missing} missing; need {AXES}")
    try:
        n_gauges = int(root.get("NumGages", "12"))
    except ValueError as err:
        raise DataError(f"{p}: NumGages {root.get('NumGages')!r} is not a number") from err
    m = (
        np.array([rows[a] for a in AXES], dtype=float)
        if all(len(rows[a]) == n_gauges for a in AXES)
        else np.zeros((0,))
    )
    if m.shape != (6, n_gauges) or n_gauges < 6:
        raise DataError(f"{p}: every Axis needs NumGages={n_gauges} gauge values (6 or more)")
    m = m * np.array([fu] * 3 + [mu] * 3)[:, None]
    return LoadCellCalibration(
        serial_number=root.get("Serial", ""),
        date=calel.get("CalDate", ""),
        matrix=m,
        method=calel.get("Method", ""),
        gauge_unit=calel.get("GageUnits", "V"),
        version=_version(int(calel.get("Version", "1") or 1), p),
    )


def read_calibration(path: str | Path) -> LoadCellCalibration:
    """Read JSON or XML by file suffix."""
    suffix = Path(path).suffix.lower()
    if suffix == ".json":
        return read_calibration_json(path)
    if suffix in (".xml", ".cal"):
        return read_calibration_xml(path)
    raise DataError(f"{path}: unknown calibration file type; use .json or .xml/.cal")


@dataclass(frozen=True)
class InstalledCalibration:
    """Where :func:`install_calibration` put a calibration."""

    version: int
    json_path: Path
    xml_path: Path
    current_path: Path


def install_calibration(cal: LoadCellCalibration, current: str | Path) -> InstalledCalibration:
    """Keep ``cal`` as the next version and make it the current calibration.

    ``current`` is the file the rig file names (``calibrations/lc-501.json`` or ``.xml``). The
    version is one more than the highest of ``<stem>-v<N>.json`` beside it and of the current
    file; both formats are written as ``<stem>-v<N>.json/.xml``, then the current file is
    replaced (write to a temporary file, then rename: a reader never sees half a file).

    Raises
    ------
    DataError
        ``current`` exists but is not a calibration file, or is another cell's (serial numbers
        differ): nothing is written.
    """
    import dataclasses
    import os
    import re

    cur = Path(current)
    cur.parent.mkdir(parents=True, exist_ok=True)
    stem = cur.stem
    pat = re.compile(re.escape(stem) + r"-v(\d+)\.(json|xml)$")
    seen = [int(m.group(1)) for f in cur.parent.iterdir() if (m := pat.match(f.name))]
    if cur.exists():
        # the file the rig names is replaced only if it *is* this cell's calibration: a rig file
        # pointing elsewhere (a typo, or a hostile path) never gets another file overwritten
        try:
            old = read_calibration(cur)
        except (DataError, OSError, ValueError) as err:
            raise DataError(
                f"{cur}: not a load cell calibration file ({err}); refusing to replace it. Point "
                "the rig file's calibration_file at the cell's calibration file"
            ) from err
        if old.serial_number and cal.serial_number and old.serial_number != cal.serial_number:
            raise DataError(
                f"{cur}: the calibration of cell {old.serial_number}, not of {cal.serial_number}; "
                "refusing to replace it. Point the rig file's calibration_file at this cell's file"
            )
        seen.append(old.version)
    version = max(seen, default=0) + 1
    new = dataclasses.replace(cal, version=version)
    jp = cur.parent / f"{stem}-v{version}.json"
    xp = cur.parent / f"{stem}-v{version}.xml"
    write_calibration_json(new, jp)
    write_calibration_xml(new, xp)
    tmp = cur.parent / f".{cur.name}.tmp"
    if cur.suffix.lower() in (".xml", ".cal"):
        write_calibration_xml(new, tmp)
    else:
        write_calibration_json(new, tmp)
    os.replace(tmp, cur)
    return InstalledCalibration(version, jp, xp, cur)
