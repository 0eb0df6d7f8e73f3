"""The UFF datasets dimacq reads, each converted to SI and the global system: 164 units, 2420/18
coordinate systems, 2411/15 nodes and 58 FRF records (:func:`parse`, :func:`_record`), with the
ordinate types a 58 record may carry (:data:`ORDINATE_TYPES`).

Reading a whole test (:func:`read_uff_test`) follows the layout commercial systems export:

- **164** units (optional). Factors convert file units to SI by *division*
  (``value_SI = value_file / factor``; mm → length factor 1000). A 164 applies to the datasets that
  follow it; without one the file is SI.
- **2420** (or **18**) coordinate systems. For 2420, row k (k = 1..3) of the 4×3 matrix is local
  axis k in the GCS and row 4 the origin. For 18 the system is built from its origin, a point on +x
  and a point in the +xz plane given in its reference system (nested systems are resolved).
  System 0 is the GCS. Only Cartesian systems are accepted.
- **2411** (or **15**) nodes with coordinates in their definition system (``def_cs``; non-zero is
  transformed to the GCS through the systems above) and a displacement system (``disp_cs``)
  whose axes the UFF directions ±1..±6 refer to.
- **58** records, function type 4 (FRF). The response ordinate type says what a record is:

  ==========  =====================  ===========================================================
  type        meaning                dimacq output
  ==========  =====================  ===========================================================
  12          acceleration           accelerometer channel, accelerance (m/s²)/N
  11          velocity               accelerometer channel, converted: ``A = iω V``
  8           displacement           accelerometer channel, converted: ``A = −ω² X``
  9           reaction force         load cell channel: directions 1–3 forces (N/N), 4–6 moments
                                     (N·m/N) in the cell's system
  ==========  =====================  ===========================================================

  The denominator must be an excitation force (type 13; 0 "unknown" is taken as force). The
  reference node and direction (±1..±3) give the input's point and line of action.

Units: the dimension of an ordinate is fixed by its specific data type and direction (the UFF
spec says the exponent fields matter only for "general" or scalar data), so numerators are
converted with the 164 factors as length (types 8, 11, 12), force (type 9, directions 1–3) or
force × length (type 9, directions 4–6), and the denominator as force. An acceleration record
whose ordinate units label is ``g`` (``g``, ``g/N``, ``G/lbf`` ...) is in standard gravity units
(×9.80665 m/s², 164 length factor not applied to it).
"""

from __future__ import annotations

import logging
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from dimacq.errors import DataError
from dimacq.io._uff_read import read_sets
from dimacq.model.frf import STANDARD_GRAVITY, to_accelerance
from dimacq.model.setup import (
    direction_label,
)

#: the logger of the module before the split into a package: the messages keep its name
logger = logging.getLogger("dimacq.io.uff")


#: UFF 58 specific data types dimacq reads as response ordinates.
ORDINATE_TYPES: dict[int, str] = {
    8: "displacement",
    9: "reaction force",
    11: "velocity",
    12: "acceleration",
}
_TYPE_NAMES: dict[int, str] = {
    0: "unknown",
    1: "general",
    2: "stress",
    3: "strain",
    5: "temperature",
    6: "heat flux",
    8: "displacement",
    9: "reaction force",
    11: "velocity",
    12: "acceleration",
    13: "excitation force",
    15: "pressure",
    16: "mass",
    17: "time",
    18: "frequency",
    19: "rpm",
    20: "order",
}
ORTHO_TOL = 1e-6  # max |M Mᵀ − I| of a coordinate system's axes (as the model's unit tolerance)
SAME_TOL = 1e-12  # positions/directions that must agree when one node carries several items
_G_LABEL = re.compile(r"^g(/.*)?$")


# --------------------------------------------------------------------------------------------
# Reading
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class _System:
    label: int
    axes: NDArray[np.float64]  # (3, 3), row k = local axis k in the GCS
    origin_m: NDArray[np.float64]  # (3,)
    source: str


@dataclass(frozen=True)
class _Node:
    number: int
    position_m: NDArray[np.float64]
    disp_cs: int


@dataclass(frozen=True)
class Record:
    index: int  # dataset number in the file, 1-based
    rsp_node: int
    rsp_dir: int
    ref_node: int
    ref_dir: int
    kind: str  # "acceleration" | "reaction"
    frequencies_hz: NDArray[np.float64]
    data: NDArray[np.complex128]  # SI

    @property
    def name(self) -> str:
        return (
            f"58 record #{self.index} ({self.rsp_node}{direction_label(self.rsp_dir)}/"
            f"{self.ref_node}{direction_label(self.ref_dir)})"
        )


@dataclass
class Content:
    path: Path
    systems: dict[int, _System]
    nodes: dict[int, _Node]
    records: list[Record]
    part_name: str


def _int(v: Any) -> int:
    return round(float(v))


def _frame_check(axes: NDArray[np.float64], what: str, path: Path) -> None:
    err = float(np.max(np.abs(axes @ axes.T - np.eye(3))))
    if not np.all(np.isfinite(axes)) or err > ORTHO_TOL:
        raise DataError(
            f"{path}: {what}: axes are not orthonormal (max |M Mᵀ − I| = {err:.3g}); "
            "rows 1–3 of a coordinate system must be its unit x, y, z axes in the global system"
        )


def _system_18(
    dset: dict[str, Any], k: int, length: float, systems: dict[int, _System], path: Path
) -> None:
    pending = {}
    for i in range(len(dset["cs_num"])):
        pending[_int(dset["cs_num"][i])] = i
    # resolve in dependency order (a system may be defined in another system of this dataset)
    while pending:
        progress = False
        for label, i in list(pending.items()):
            ref = _int(dset["ref_cs_num"][i])
            if ref != 0 and ref not in systems:
                continue
            if _int(dset["cs_type"][i]) != 0:
                raise DataError(
                    f"{path}: dataset #{k} (18): coordinate system {label} is not Cartesian; "
                    "export node systems as Cartesian"
                )
            pts = [
                np.asarray(dset[key][i], dtype=float) / length
                for key in ("ref_o", "x_point", "xz_point")
            ]
            if ref != 0:
                r = systems[ref]
                pts = [r.origin_m + r.axes.T @ p for p in pts]
            o, px, pxz = pts
            # x towards the x point; the xz point lies in the x–z half-plane with z > 0, so
            # y ∝ (p_xz − o) × x and z = x × y
            x = px - o
            y = np.cross(pxz - o, x)
            if np.linalg.norm(x) == 0 or np.linalg.norm(y) == 0:
                raise DataError(
                    f"{path}: dataset #{k} (18): coordinate system {label} is degenerate (its x "
                    "point or xz-plane point coincides with the origin or the x axis); "
                    "fix its definition"
                )
            x = x / np.linalg.norm(x)
            y = y / np.linalg.norm(y)
            z = np.cross(x, y)
            systems[label] = _System(label, np.vstack([x, y, z]), o, "18")
            del pending[label]
            progress = True
        if not progress:
            raise DataError(
                f"{path}: dataset #{k} (18): coordinate systems {sorted(pending)} refer to "
                "reference systems that are not defined; add them"
            )


def parse(path: Path) -> Content:
    """Read every dataset and convert geometry and FRFs to SI, GCS."""
    sets = read_sets(path)
    length, force = 1.0, 1.0
    systems: dict[int, _System] = {}
    raw_nodes: list[
        tuple[int, int, int, int, NDArray[np.float64]]
    ] = []  # node, def, disp, set, xyz
    records: list[Record] = []
    part_name = ""
    skipped: dict[int, int] = {}
    deferred: list[tuple[Any, int, str, float, float]] = []
    for k, d in enumerate(sets, start=1):
        t = int(d["type"])
        if t == 164:
            length, force = float(d["length"]), float(d["force"])
            if not (length > 0 and force > 0):
                raise DataError(
                    f"{path}: dataset #{k} (164) has unit factors length={length}, force={force}; "
                    "both must be positive"
                )
            logger.debug(
                "%s: units %s (length ×%g, force ×%g per SI)",
                path,
                d.get("units_description"),
                length,
                force,
            )
        elif t == 2420:
            part_name = str(d.get("Part_Name", "")).strip()
            for label, cs_type, m in zip(
                d["CS_sys_labels"], d["CS_types"], d["CS_matrices"], strict=True
            ):
                label = _int(label)
                if _int(cs_type) != 0:
                    raise DataError(
                        f"{path}: dataset #{k} (2420): coordinate system {label} is not Cartesian "
                        f"(type {int(cs_type)}); export node systems as Cartesian"
                    )
                m = np.asarray(m, dtype=float)
                systems[label] = _System(label, m[:3].copy(), m[3] / length, "2420")
        elif t == 18:
            _system_18(d, k, length, systems, path)
        elif t in (2411, 15):
            xyz = np.column_stack([d["x"], d["y"], d["z"]]).astype(float) / length
            for i, n in enumerate(d["node_nums"]):
                raw_nodes.append((_int(n), _int(d["def_cs"][i]), _int(d["disp_cs"][i]), k, xyz[i]))
        elif t == 58:
            rec = _record(d, k, length, force, path, deferred)
            if rec is None:
                skipped[int(d["func_type"])] = skipped.get(int(d["func_type"]), 0) + 1
            else:
                records.append(rec)
        else:
            skipped[-t] = skipped.get(-t, 0) + 1
    _scale_rows(deferred)
    if skipped:
        logger.info(
            "%s: ignored %s",
            path,
            ", ".join(
                f"{c} dataset(s) {-t}" if t < 0 else f"{c} 58 record(s) of function type {t}"
                for t, c in sorted(skipped.items())
            ),
        )
    for s in systems.values():
        _frame_check(s.axes, f"coordinate system {s.label} ({s.source})", path)
    nodes: dict[int, _Node] = {}
    for n, def_cs, disp_cs, k, xyz in raw_nodes:
        if def_cs != 0:
            if def_cs not in systems:
                raise DataError(
                    f"{path}: node {n} (dataset #{k}) is defined in coordinate system {def_cs}, "
                    "which no 2420/18 dataset defines; add the system or export global coordinates"
                )
            s = systems[def_cs]
            xyz = s.origin_m + s.axes.T @ xyz
        nodes[n] = _Node(n, np.asarray(xyz, dtype=float), disp_cs)
    return Content(path, systems, nodes, records, part_name)


def _record(
    d: dict[str, Any],
    k: int,
    length: float,
    force: float,
    path: Path,
    deferred: list[tuple[Any, int, str, float, float]] | None = None,
) -> Record | None:
    """One 58 dataset → SI record, or None for a function that is not an FRF.

    A record read in a batch (``d["_rows"]``: a row of an array of records) with ``deferred``
    keeps that row as its data and appends its unit conversion, ``(array, row, "mul"/"div",
    factor, force)``, for :func:`_scale_rows` to apply to all the rows at once.
    """
    func_type = int(d["func_type"])
    rsp_node, rsp_dir = _int(d["rsp_node"]), _int(d["rsp_dir"])
    ref_node, ref_dir = _int(d["ref_node"]), _int(d["ref_dir"])
    ident = f"58 record #{k} (response {rsp_node}:{rsp_dir}, reference {ref_node}:{ref_dir})"
    if func_type != 4:
        return None
    o_type = int(d.get("ordinate_spec_data_type", 0))
    if o_type not in ORDINATE_TYPES:
        raise DataError(
            f"{path}: {ident}: response ordinate type {o_type} ({_TYPE_NAMES.get(o_type, '?')}) "
            "is not acceleration (12), velocity (11), displacement (8) or reaction force (9); "
            "export accelerance or load cell FRFs with their ordinate type set"
        )
    den_type = int(d.get("orddenom_spec_data_type", 0))
    if den_type not in (0, 13):
        raise DataError(
            f"{path}: {ident}: the denominator is {_TYPE_NAMES.get(den_type, den_type)} (type "
            f"{den_type}), not an excitation force (13); export response/force FRFs"
        )
    abs_type = int(d.get("abscissa_spec_data_type", 0))
    if abs_type not in (0, 18):
        raise DataError(
            f"{path}: {ident}: the abscissa is {_TYPE_NAMES.get(abs_type, abs_type)} (type "
            f"{abs_type}), not frequency (18); export FRFs over frequency in Hz"
        )
    kind = "reaction" if o_type == 9 else "acceleration"
    lim = 6 if kind == "reaction" else 3
    if not 1 <= abs(rsp_dir) <= lim:
        raise DataError(
            f"{path}: {ident}: response direction {rsp_dir} is not ±1..±{lim} for a "
            f"{ORDINATE_TYPES[o_type]} record; "
            + ("accelerometers measure translations only" if lim == 3 else "load cells give 1–6")
        )
    if not 1 <= abs(ref_dir) <= 3:
        raise DataError(
            f"{path}: {ident}: reference direction {ref_dir} is not ±1..±3; inputs are forces "
            "along a node's x, y or z axis"
        )
    f = np.asarray(d["x"], dtype=float)
    if f.shape != np.shape(d["data"]) or f.ndim != 1:
        raise DataError(f"{path}: {ident}: abscissa and ordinate lengths differ; re-export it")
    # numerator → SI, denominator (force) → SI: H_SI = (num / f_num) / (den / force)
    label = str(d.get("ordinate_axis_units_lab", "")).strip().lower().replace(" ", "")
    if kind == "acceleration":
        op, c = (
            ("mul", STANDARD_GRAVITY) if o_type == 12 and _G_LABEL.match(label) else ("div", length)
        )
    else:
        op, c = "div", force if abs(rsp_dir) <= 3 else force * length
    # den_type is 13 or 0 here (refused above otherwise): the denominator is a force
    rows = d.get("_rows")
    if deferred is not None and rows is not None and o_type not in (8, 11):
        deferred.append((rows[0], rows[1], op, c, force))
        return Record(k, rsp_node, rsp_dir, ref_node, ref_dir, kind, f, d["data"])
    h: NDArray[np.complex128] = np.asarray(d["data"]).astype(complex)
    h = h * c if op == "mul" else h / c
    h = h * force
    if o_type in (8, 11):
        h = to_accelerance(h, f, quantity="displacement" if o_type == 8 else "velocity")
    return Record(k, rsp_node, rsp_dir, ref_node, ref_dir, kind, f, h)


def _scale_rows(deferred: list[tuple[Any, int, str, float, float]]) -> None:
    """The unit conversions :func:`_record` deferred, in place on the records' rows: rows of one
    array with the same conversion at once, with the same two operations (``× c`` or ``/ c``,
    then ``× force``, Python floats) as a record alone, so each value is the same to the bit."""
    groups: dict[tuple[int, str, float, float], tuple[Any, list[int]]] = {}
    for array, row, op, c, force in deferred:
        groups.setdefault((id(array), op, c, force), (array, []))[1].append(row)
    for (_, op, c, force), (array, rows) in groups.items():
        if len(rows) == len(array):  # every row (an SI file): in place, no copies
            (np.multiply if op == "mul" else np.divide)(array, c, out=array)
            np.multiply(array, force, out=array)
            continue
        idx = np.asarray(rows, dtype=np.intp)
        block = array[idx]
        block = block * c if op == "mul" else block / c
        array[idx] = block * force


def axis_text(f: NDArray[np.float64]) -> str:
    step = f"{f[1] - f[0]:g} Hz steps" if f.size > 1 else "one line"
    return f"{f.size} lines {f[0]:g}–{f[-1]:g} Hz ({step})" if f.size else "no lines"
