"""Universal File Format (UFF) interchange through pyuff: whole tests and dataset 58 FRFs.

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

Geometry from records: an accelerometer channel ``(node, d)`` gets ``direction_gcs = sign(d) ×
row |d|`` of its node's displacement system and ``position_m`` = the node's coordinates; an
input likewise; a load cell at ``node`` gets ``position_m`` = the node's coordinates and
``rotation`` = the transpose of the node's rows-as-axes matrix (columns = local axes in the GCS),
sign ``"on_structure"`` (the samples' convention: the load the support exerts on the body).

Units: the dimension of an ordinate is fixed by its specific data type and direction (the UFF
spec says the exponent fields matter only for "general" or scalar data), so numerators are
converted with the 164 factors as length (types 8, 11, 12), force (type 9, directions 1–3) or
force × length (type 9, directions 4–6), and the denominator as force. An acceleration record
whose ordinate units label is ``g`` (``g``, ``g/N``, ``G/lbf`` ...) is in standard gravity units
(×9.80665 m/s², 164 length factor not applied to it).

Writing (:func:`write_uff_test`) produces 164 (SI), 2420 (one right-handed system per node, label =
node number), 2411 (``def_cs`` 0, ``disp_cs`` = the node's system) and 58 records in FRF order.
Round trips: binary records store IEEE doubles (bit-exact); ASCII records use the UFF 4E20
layout, written with 14 significant digits (relative error ≤ 5e-14). The frequency axis is
written as even spacing when ``f0 + k·df`` from the header's E13.5 fields reproduces it exactly,
otherwise as uneven abscissa (exact in binary, 8 significant digits in ASCII, logged).
Non-geometric setup fields (reference point, length unit, known properties, labels) have no place
in UFF: the reader takes them from its keyword arguments; ``setup.name`` travels as the 2420 part
name. Load cells with ``sign="on_support"`` are written negated as ``"on_structure"``.
"""

from __future__ import annotations

import logging
import os
import re
import tempfile
from collections.abc import Iterable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np
from numpy.typing import NDArray
from pydantic import ValidationError

from dimacq.errors import DataError, DimacqError, SetupError
from dimacq.io._uff_read import read_sets
from dimacq.model.frf import STANDARD_GRAVITY, Channel, FrfData, to_accelerance
from dimacq.model.setup import (
    Excitation,
    KnownProperties,
    LoadCell,
    ResponseChannel,
    TestSetup,
    Vec3,
    direction_label,
)

__all__ = [
    "ORDINATE_TYPES",
    "UffSource",
    "check_uff_geometry",
    "dump_uff",
    "read_frf_uff",
    "read_uff_test",
    "write_frf_uff",
    "write_uff_test",
]

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
_ORTHO_TOL = 1e-6  # max |M Mᵀ − I| of a coordinate system's axes (as the model's unit tolerance)
_SAME_TOL = 1e-12  # positions/directions that must agree when one node carries several items
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
class _Record:
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
class _Content:
    path: Path
    systems: dict[int, _System]
    nodes: dict[int, _Node]
    records: list[_Record]
    part_name: str


def _int(v: Any) -> int:
    return round(float(v))


def _frame_check(axes: NDArray[np.float64], what: str, path: Path) -> None:
    err = float(np.max(np.abs(axes @ axes.T - np.eye(3))))
    if not np.all(np.isfinite(axes)) or err > _ORTHO_TOL:
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


def _parse(path: Path) -> _Content:
    """Read every dataset and convert geometry and FRFs to SI, GCS."""
    sets = read_sets(path)
    length, force = 1.0, 1.0
    systems: dict[int, _System] = {}
    raw_nodes: list[
        tuple[int, int, int, int, NDArray[np.float64]]
    ] = []  # node, def, disp, set, xyz
    records: list[_Record] = []
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
    return _Content(path, systems, nodes, records, part_name)


def _record(
    d: dict[str, Any],
    k: int,
    length: float,
    force: float,
    path: Path,
    deferred: list[tuple[Any, int, str, float, float]] | None = None,
) -> _Record | None:
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
        return _Record(k, rsp_node, rsp_dir, ref_node, ref_dir, kind, f, d["data"])
    h: NDArray[np.complex128] = np.asarray(d["data"]).astype(complex)
    h = h * c if op == "mul" else h / c
    h = h * force
    if o_type in (8, 11):
        h = to_accelerance(h, f, quantity="displacement" if o_type == 8 else "velocity")
    return _Record(k, rsp_node, rsp_dir, ref_node, ref_dir, kind, f, h)


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


def _axis_text(f: NDArray[np.float64]) -> str:
    step = f"{f[1] - f[0]:g} Hz steps" if f.size > 1 else "one line"
    return f"{f.size} lines {f[0]:g}–{f[-1]:g} Hz ({step})" if f.size else "no lines"


def _common_axis(records: Sequence[_Record], path: Path) -> NDArray[np.float64]:
    first = records[0]
    f0 = first.frequencies_hz
    scale = float(np.max(np.abs(f0))) if f0.size else 1.0
    rest = records[1:]
    if all(r.frequencies_hz is f0 for r in rest) and np.all(np.isfinite(f0)):
        return f0  # one axis shared by the records of a batch (dimacq.io._uff_read)
    # np.allclose of every record with the first, in one comparison of the stacked axes.
    ok = np.array([r.frequencies_hz.shape == f0.shape for r in rest], dtype=bool)
    if ok.any():
        same = np.stack([r.frequencies_hz for r, o in zip(rest, ok, strict=True) if o])
        ok[ok] = np.all(np.isclose(same, f0, rtol=1e-9, atol=1e-12 * scale), axis=1)
    if not ok.all():
        r = rest[int(np.argmin(ok))]  # the first record off the axis
        raise DataError(
            f"{path}: {r.name} has {_axis_text(r.frequencies_hz)} but {first.name} has "
            f"{_axis_text(f0)}; export all FRFs on one frequency axis"
        )
    return f0


def _assemble(
    records: Sequence[_Record],
    outputs: Sequence[tuple[Channel, str]],
    inputs: Sequence[Channel],
    path: Path,
) -> FrfData:
    """Fill H (n_lines, n_outputs, n_inputs) from records; every pair must be present once."""
    if not records:
        raise DataError(f"{path}: no FRF records (58, function type 4) to read; export the FRFs")
    f = _common_axis(records, path)
    o_index = {ch: i for i, (ch, _) in enumerate(outputs)}
    i_index = {ch: i for i, ch in enumerate(inputs)}
    n_in = len(inputs)
    data: list[NDArray[np.complex128] | None] = [None] * (len(outputs) * n_in)
    for r in records:
        o = o_index.get(Channel(r.rsp_node, r.rsp_dir))
        i = i_index.get(Channel(r.ref_node, r.ref_dir))
        if o is None or i is None:
            continue
        if data[o * n_in + i] is not None:
            raise DataError(
                f"{path}: {r.name} repeats an FRF already read; keep one record per "
                "response/reference pair"
            )
        data[o * n_in + i] = r.data
    if any(d is None for d in data):
        seen = np.array([d is not None for d in data]).reshape(len(outputs), n_in)
        o, i = (int(v[0]) for v in np.nonzero(~seen))
        raise DataError(
            f"{path}: no FRF for response {outputs[o][0].name} / reference {inputs[i].name} "
            f"({int((~seen).sum())} of {seen.size} pairs missing); "
            "export every response for every input"
        )
    H = _lines_first([d for d in data if d is not None], f.size).reshape(f.size, -1, n_in)
    try:
        return FrfData(
            frequencies_hz=f,
            H=H,
            outputs=tuple(ch for ch, _ in outputs),
            output_kinds=tuple(k for _, k in outputs),  # type: ignore[misc]
            inputs=tuple(inputs),
            meta={"source": str(path)},
        )
    except DataError as err:
        raise DataError(f"{path}: {err}") from err


def _lines_first(rows: Sequence[NDArray[np.complex128]], n_lines: int) -> NDArray[np.complex128]:
    """The records ``rows`` (each n_lines values) as the columns of one (n_lines, n_rows) array.

    Written in blocks of 32 records (stacked, then transposed into place): each block's reads
    and writes stay in the cache, where writing a record straight into its column touches one
    cache line per line, and no whole-size intermediate is allocated (its page faults cost as
    much as the copy: 23 MB for 720 records × 2048 lines)."""
    H = np.empty((n_lines, len(rows)), dtype=np.complex128)
    for r0 in range(0, len(rows), 32):
        H[:, r0 : r0 + 32] = np.stack(rows[r0 : r0 + 32]).T
    return H


def _ordered_channels(
    records: Iterable[_Record], path: Path
) -> tuple[list[tuple[Channel, str]], list[Channel]]:
    outputs: dict[Channel, str] = {}
    node_kind: dict[int, tuple[str, _Record]] = {}
    inputs: dict[Channel, None] = {}
    for r in records:
        prev = node_kind.setdefault(r.rsp_node, (r.kind, r))
        if prev[0] != r.kind:
            raise DataError(
                f"{path}: node {r.rsp_node} has {prev[0]} records ({prev[1].name}) and {r.kind} "
                f"records ({r.name}); an accelerometer and a load cell need separate nodes"
            )
        outputs.setdefault(Channel(r.rsp_node, r.rsp_dir), r.kind)
        inputs.setdefault(Channel(r.ref_node, r.ref_dir), None)
    return list(outputs.items()), list(inputs)


def _node_geometry(content: _Content, node: int, used_by: str) -> tuple[Vec3, NDArray[np.float64]]:
    """Position (GCS, m) and axes (rows) of a node."""
    path = content.path
    n = content.nodes.get(node)
    if n is None:
        raise DataError(
            f"{path}: {used_by} refers to node {node}, which has no coordinates in the file "
            "(no 2411/15 entry); add the node or read the FRFs with read_frf_uff and a setup file"
        )
    if n.disp_cs == 0:
        axes = np.eye(3)
    elif n.disp_cs in content.systems:
        axes = content.systems[n.disp_cs].axes
    else:
        raise DataError(
            f"{path}: node {node} uses displacement coordinate system {n.disp_cs}, which no "
            "2420/18 dataset defines; add the system or export directions in the global system"
        )
    pos = n.position_m
    return (float(pos[0]), float(pos[1]), float(pos[2])), axes


def _vec(v: NDArray[np.float64]) -> Vec3:
    return (float(v[0]), float(v[1]), float(v[2]))


#: A UFF file to read: its path, its content, or a binary stream (an upload).
UffSource = str | os.PathLike[str] | bytes | bytearray | BinaryIO


@contextmanager
def _named_file(source: UffSource) -> Iterator[Path]:
    """The path of ``source``. pyuff reads only named files, so content and streams are spooled
    to a private temporary file here (the one place that knows it), and anything pyuff raises
    on malformed content becomes a DataError."""
    if isinstance(source, str | os.PathLike):
        yield Path(source)
        return
    data = bytes(source) if isinstance(source, bytes | bytearray) else source.read()
    with tempfile.TemporaryDirectory(prefix="dimacq-uff-") as tmp:
        path = Path(tmp) / "upload.uff"
        path.write_bytes(data)
        try:
            yield path
        except DimacqError as err:
            # the messages name the file read; a client must see "the UFF upload", never the
            # server's temporary path
            text = str(err).replace(str(path), "UFF upload").replace(tmp, "<upload>")
            if text == str(err):
                raise
            raise type(err)(text) from err
        except Exception as err:  # pyuff raises bare exceptions on malformed files
            text = f"{type(err).__name__}: {err}".replace(str(path), "UFF upload")
            raise DataError(
                f"UFF upload could not be read ({text.replace(tmp, '<upload>')})"
            ) from err


def read_uff_test(
    path: UffSource,
    *,
    reference_point_m: Vec3 = (0.0, 0.0, 0.0),
    length_unit: str = "m",
    name: str | None = None,
) -> tuple[TestSetup, FrfData]:
    """Read a whole test (geometry and FRFs) from one UFF file, ASCII or binary.

    Parameters
    ----------
    path : the ``.uff``/``.unv`` file (layout in the module docstring): a path, its content
        (bytes) or a binary stream.
    reference_point_m : the reference point P (not stored in UFF), GCS metres.
    length_unit : solver length unit for the setup (``"m"``, ``"cm"``, ``"mm"``).
    name : setup name; default the 2420 part name.

    Returns
    -------
    setup : TestSetup
        Responses in the order of the accelerometer outputs, excitations in input order, load
        cells in order of first appearance (all ``sign="on_structure"``).
    frf : FrfData
        ``H`` of shape ``(n_lines, n_outputs, n_inputs)`` in SI (accelerance (m/s²)/N, reactions
        N/N and N·m/N), outputs and inputs in order of first appearance in the file.

    Raises
    ------
    DataError
        A record's node has no coordinates, frequency axes differ, NaNs, an unknown ordinate type,
        a missing response/reference pair, a non-orthonormal or non-Cartesian system, ...
    """
    with _named_file(path) as p:
        return _read_uff_test(p, reference_point_m, length_unit, name)


def _read_uff_test(
    p: Path, reference_point_m: Vec3, length_unit: str, name: str | None
) -> tuple[TestSetup, FrfData]:
    content = _parse(p)
    outputs, inputs = _ordered_channels(content.records, p)
    frf = _assemble(content.records, outputs, inputs, p)
    first_use: dict[tuple[str, int, int], str] = {}
    for r in content.records:
        first_use.setdefault(("o", r.rsp_node, r.rsp_dir), r.name)
        first_use.setdefault(("i", r.ref_node, r.ref_dir), r.name)
    responses: list[ResponseChannel] = []
    cells: dict[int, LoadCell] = {}
    try:
        for ch, kind in outputs:
            pos, axes = _node_geometry(content, ch.node, first_use[("o", ch.node, ch.direction)])
            if kind == "acceleration":
                d = np.sign(ch.direction) * axes[abs(ch.direction) - 1]
                responses.append(
                    ResponseChannel(
                        node=ch.node, direction=ch.direction, position_m=pos, direction_gcs=_vec(d)
                    )
                )
            elif ch.node not in cells:
                rot = axes.T
                cells[ch.node] = LoadCell(
                    node=ch.node,
                    position_m=pos,
                    rotation=(_vec(rot[0]), _vec(rot[1]), _vec(rot[2])),
                    sign="on_structure",
                )
        excitations = []
        for ch in inputs:
            pos, axes = _node_geometry(content, ch.node, first_use[("i", ch.node, ch.direction)])
            d = np.sign(ch.direction) * axes[abs(ch.direction) - 1]
            excitations.append(
                Excitation(
                    node=ch.node, direction=ch.direction, position_m=pos, direction_gcs=_vec(d)
                )
            )
        setup = TestSetup(
            name=(content.part_name if content.part_name.upper() != "NONE" else "")
            if name is None
            else name,
            reference_point_m=reference_point_m,
            length_unit=length_unit,  # type: ignore[arg-type]
            responses=tuple(responses),
            excitations=tuple(excitations),
            load_cells=tuple(cells.values()),
            known=KnownProperties(),
        )
    except ValidationError as err:
        msgs = "; ".join(
            str(e["msg"]).removeprefix("Value error, ") for e in err.errors(include_url=False)
        )
        raise DataError(f"{p}: the geometry in the file is not a valid test setup: {msgs}") from err
    logger.info(
        "%s: %d accelerometer channels, %d load cells, %d inputs, %s",
        p,
        len(responses),
        len(cells),
        len(excitations),
        _axis_text(frf.frequencies_hz),
    )
    return setup, frf


def read_frf_uff(path: UffSource, setup: TestSetup) -> FrfData:
    """Read the 58 FRF records of a UFF file and match them to a setup (from a setup file).

    Geometry datasets in the file are ignored (the setup is the geometry); 164 units apply.
    Outputs are ordered as ``setup.responses``, then each load cell's records (directions in
    order of first appearance); inputs as ``setup.excitations``.

    Channels in the file that the setup does not list (e.g. extra reference accelerometers)
    are **ignored with a logged warning**; a setup channel without records is refused.

    Raises
    ------
    DataError
        A setup channel has no FRF, a record's type contradicts the setup (accelerometer vs load
        cell), mismatched frequency axes, NaNs, unknown ordinate types.
    """
    with _named_file(path) as p:
        return _read_frf_uff(p, setup)


def _read_frf_uff(p: Path, setup: TestSetup) -> FrfData:
    content = _parse(p)
    recs = content.records
    by_node_kind: dict[int, str] = {}
    for r in recs:
        by_node_kind.setdefault(r.rsp_node, r.kind)
    outputs: list[tuple[Channel, str]] = []
    present = {Channel(r.rsp_node, r.rsp_dir): r for r in recs}
    for ch in setup.responses:
        c = Channel(ch.node, ch.direction)
        rec = present.get(c)
        if rec is None:
            raise DataError(
                f"{p}: the setup's response {ch.name} has no FRF record in the file; "
                "export it or remove it from the setup"
            )
        if rec.kind != "acceleration":
            raise DataError(
                f"{p}: {rec.name} is a reaction force record but the setup lists {ch.name} as an "
                "accelerometer channel; correct the setup or the ordinate type"
            )
        outputs.append((c, "acceleration"))
    for cell in setup.load_cells:
        dirs = [c for c in present if c.node == cell.node]
        if not dirs:
            raise DataError(
                f"{p}: load cell {cell.name} (node {cell.node}) has no FRF record in the file; "
                "export its channels or remove it from the setup"
            )
        for c in dirs:
            if present[c].kind != "reaction":
                raise DataError(
                    f"{p}: {present[c].name} is an acceleration record but node {cell.node} is a "
                    "load cell in the setup; correct the setup or the ordinate type"
                )
            outputs.append((c, "reaction"))
    inputs = [Channel(e.node, e.direction) for e in setup.excitations]
    refs = {Channel(r.ref_node, r.ref_dir) for r in recs}
    for e, c in zip(setup.excitations, inputs, strict=True):
        if c not in refs:
            raise DataError(
                f"{p}: the setup's input {e.name} has no FRF record in the file (reference "
                f"{c.name}); export it or remove it from the setup"
            )
    wanted_o = {c for c, _ in outputs}
    extra = sorted(
        {c.name for c in present if c not in wanted_o}
        | {c.name for c in refs if c not in set(inputs)}
    )
    if extra:
        logger.warning("%s: ignoring channels not in the setup: %s", p, ", ".join(extra))
    used = [
        r
        for r in recs
        if Channel(r.rsp_node, r.rsp_dir) in wanted_o
        and Channel(r.ref_node, r.ref_dir) in set(inputs)
    ]
    return _assemble(used, outputs, inputs, p)


# --------------------------------------------------------------------------------------------
# Writing
# --------------------------------------------------------------------------------------------
def _complete_frame(
    node: int, slots: dict[int, tuple[NDArray[np.float64], str]]
) -> NDArray[np.float64]:
    """Rows-as-axes rotation whose row k is the given vector for every given slot k (0-based)."""
    rows: list[NDArray[np.float64] | None] = [None, None, None]
    for k, (v, _) in slots.items():
        rows[k] = v
    given = sorted(slots)
    names = ", ".join(slots[k][1] for k in given)
    if len(given) >= 2:
        g = np.array([rows[k] for k in given])
        err = float(np.max(np.abs(g @ g.T - np.eye(len(given)))))
        if err > _ORTHO_TOL:
            raise SetupError(
                f"node {node}: the directions of {names} are not orthogonal (max |M Mᵀ − I| = "
                f"{err:.3g}); a UFF node's displacement system is a rotation: give the channels' "
                "true orthogonal axes, or give non-orthogonal channels separate node numbers"
            )
    if len(given) == 1:
        i = given[0]
        v = slots[i][0]
        helper = np.eye(3)[int(np.argmin(np.abs(v)))]
        a = helper - (helper @ v) * v
        a /= np.linalg.norm(a)
        rows[(i + 1) % 3] = a
        rows[(i + 2) % 3] = np.cross(v, a)
    elif len(given) == 2:
        k = ({0, 1, 2} - set(given)).pop()
        ra, rb = rows[(k + 1) % 3], rows[(k + 2) % 3]
        assert ra is not None and rb is not None
        c = np.cross(ra, rb)
        rows[k] = c / np.linalg.norm(c)
    m = np.array(rows, dtype=float)
    if np.linalg.det(m) < 0:
        raise SetupError(
            f"node {node}: the directions of {names} form a left-handed set (det = "
            f"{np.linalg.det(m):.3g}); a UFF displacement system must be right-handed: check the "
            "sign of one direction or its UFF direction label"
        )
    return m


def _node_frames(setup: TestSetup) -> dict[int, tuple[NDArray[np.float64], NDArray[np.float64]]]:
    """node → (position (3,), axes rows (3, 3)) for every node of the setup."""
    pos: dict[int, tuple[NDArray[np.float64], str]] = {}
    slots: dict[int, dict[int, tuple[NDArray[np.float64], str]]] = {}
    fixed: dict[int, NDArray[np.float64]] = {}

    def place(node: int, p: Vec3, what: str) -> None:
        if node <= 0:
            raise SetupError(
                f"{what}: node {node} is not a valid UFF node label; use a positive number"
            )
        q = np.asarray(p, dtype=float)
        prev = pos.setdefault(node, (q, what))
        if np.max(np.abs(prev[0] - q)) > _SAME_TOL * max(1.0, float(np.max(np.abs(q)))):
            raise SetupError(
                f"node {node}: {prev[1]} is at {tuple(prev[0])} but {what} at {tuple(q)}; one node "
                "has one position: give them separate node numbers"
            )

    def slot(node: int, direction: int, d: Vec3 | None, what: str) -> None:
        if direction == 0 or abs(direction) > 3 or d is None:
            raise SetupError(f"{what}: direction {direction} is not ±1..±3; give its UFF direction")
        v = np.sign(direction) * np.asarray(d, dtype=float)
        s = slots.setdefault(node, {})
        k = abs(direction) - 1
        if k in s and np.max(np.abs(s[k][0] - v)) > _SAME_TOL:
            raise SetupError(
                f"node {node}: {s[k][1]} and {what} use axis {k + 1} of the node with different "
                "GCS directions; give them separate node numbers or matching directions"
            )
        s.setdefault(k, (v, what))

    for ch in setup.responses:
        place(ch.node, ch.position_m, f"response {ch.name}")
        slot(ch.node, ch.direction, ch.direction_gcs, f"response {ch.name}")
    for ex in setup.excitations:
        place(ex.node, ex.position_m, f"input {ex.name}")
        slot(ex.node, ex.direction, ex.direction_gcs, f"input {ex.name}")
    for lc in setup.load_cells:
        place(lc.node, lc.position_m, f"load cell {lc.name}")
        if lc.node in slots:
            raise SetupError(
                f"node {lc.node}: load cell {lc.name} shares its node with a response or input; "
                "give the load cell its own node number"
            )
        fixed[lc.node] = lc.rotation_matrix.T.copy()
    out: dict[int, tuple[NDArray[np.float64], NDArray[np.float64]]] = {}
    for node, (p, _) in pos.items():
        axes = fixed[node] if node in fixed else _complete_frame(node, slots[node])
        out[node] = (p, axes)
    return out


def _check_match(setup: TestSetup, frf: FrfData) -> None:
    acc = {frf.outputs[i] for i in frf.output_index("acceleration")}
    resp = {Channel(c.node, c.direction) for c in setup.responses}
    for c in sorted(acc - resp, key=lambda c: (c.node, c.direction)):
        raise SetupError(f"FRF output {c.name} is not a response of the setup; add it to the setup")
    for c in sorted(resp - acc, key=lambda c: (c.node, c.direction)):
        raise SetupError(
            f"setup response {c.name} has no FRF; remove it from the setup or add its FRFs"
        )
    cells = {lc.node for lc in setup.load_cells}
    react = {frf.outputs[i] for i in frf.output_index("reaction")}
    for c in react:
        if c.node not in cells:
            raise SetupError(
                f"FRF reaction output {c.name} has no load cell at node {c.node} in the setup; "
                "add it"
            )
    for n in cells - {c.node for c in react}:
        raise SetupError(
            f"setup load cell at node {n} has no FRF outputs; remove it or add its FRFs"
        )
    ins = {Channel(e.node, e.direction) for e in setup.excitations}
    if ins != set(frf.inputs):
        diff = sorted(c.name for c in ins ^ set(frf.inputs))
        raise SetupError(
            f"inputs of the setup and of the FRFs differ ({', '.join(diff)}); give the same inputs"
        )


def _e20(v: float) -> str:
    s = f"{v:20.13e}"
    return s if len(s) <= 20 else f"{v:20.12e}"


def _e13(v: float) -> str:
    s = f"{v:13.7e}"
    return s if len(s) <= 13 else f"{v:13.6e}"


def _even_header(f: NDArray[np.float64]) -> tuple[float, float] | None:
    """(f0, df) as the E13.5 header holds them if ``f0 + k·df`` (pyuff's formula) is exact."""
    if f.size < 2:
        return None
    f0 = float(f"{f[0]:13.5e}")
    df = float(f"{f[1] - f[0]:13.5e}")
    return (f0, df) if np.array_equal(f0 + np.arange(f.size) * df, f) else None


def _record58(
    h: NDArray[np.complex128],
    f: NDArray[np.float64],
    even: tuple[float, float] | None,
    out: Channel,
    kind: str,
    inp: Channel,
    binary: bool,
) -> bytes:
    """One dataset 58 (complex double FRF) in the layout of pyuff's writer."""
    n = f.size
    if kind == "acceleration":
        o_type, o_len, o_force, o_unit = 12, 1, 0, "m/s^2"
    elif abs(out.direction) <= 3:
        o_type, o_len, o_force, o_unit = 9, 0, 1, "N"
    else:
        o_type, o_len, o_force, o_unit = 9, 1, 1, "N m"
    if even is None:
        data = np.column_stack([f, h.real, h.imag]).ravel()
    else:
        data = np.column_stack([h.real, h.imag]).ravel()
    head = ["    -1", "    58"]
    if binary:
        head[1] += "b%6i%6i%12i%12i%6i%6i%12i%12i" % (1, 2, 11, data.size * 8, 0, 0, 0, 0)  # noqa: UP031
    else:
        head[1] += " " * 74
    head += [
        f"{'FRF':<80}",
        f"{(out.name + '/' + inp.name):<80}",
        f"{'dimacq':<80}",
        f"{'NONE':<80}",
        f"{'NONE':<80}",
        "%5i%10i%5i%10i %10s%10i%4i %10s%10i%4i"  # noqa: UP031 (Fortran record layout)
        % (4, 0, 0, 0, "NONE", out.node, out.direction, "NONE", inp.node, inp.direction),
        "%10i%10i%10i%13.5e%13.5e%13.5e"  # noqa: UP031 (Fortran record layout)
        % (6, n, 1 if even else 0, even[0] if even else 0.0, even[1] if even else 0.0, 0.0),
        "%10i%5i%5i%5i %-20s %-20s" % (18, 0, 0, 0, "Frequency", "Hz"),  # noqa: UP031 (Fortran record layout)
        "%10i%5i%5i%5i %-20s %-20s" % (o_type, o_len, o_force, 0, "NONE", o_unit),  # noqa: UP031 (Fortran record layout)
        "%10i%5i%5i%5i %-20s %-20s" % (13, 0, 1, 0, "NONE", "N"),  # noqa: UP031 (Fortran record layout)
        "%10i%5i%5i%5i %-20s %-20s" % (0, 0, 0, 0, "NONE", "NONE"),  # noqa: UP031 (Fortran record layout)
    ]
    text = "\n".join(head) + "\n"
    if binary:
        return text.encode("ascii") + data.astype("<f8").tobytes() + b"    -1\n"
    if even is not None:
        cells = [_e20(v) for v in data.tolist()]
        lines = ["".join(cells[i : i + 4]) for i in range(0, len(cells), 4)]
    else:
        lines = [
            _e13(x) + _e20(re) + _e20(im)
            for x, re, im in zip(f.tolist(), h.real.tolist(), h.imag.tolist(), strict=True)
        ]
    return (text + "\n".join(lines) + "\n    -1\n").encode("ascii")


def _append58(fh: Any, frf: FrfData, sign: NDArray[np.float64], binary: bool) -> None:
    f = frf.frequencies_hz
    even = _even_header(f)
    if even is None:
        msg = (
            "exact (binary doubles)"
            if binary
            else "rounded to 8 significant digits (ASCII E13 field)"
        )
        logger.warning(
            "frequency axis %s is not f0 + k·df with E13.5 header values; "
            "written as uneven abscissa, %s",
            _axis_text(f),
            msg,
        )
    for i, inp in enumerate(frf.inputs):
        for o, (out, kind) in enumerate(zip(frf.outputs, frf.output_kinds, strict=True)):
            fh.write(_record58(sign[o] * frf.H[:, o, i], f, even, out, kind, inp, binary))


def write_frf_uff(path: str | Path, frf: FrfData, *, binary: bool = True) -> None:
    """Write only the FRFs as dataset 58 records (complex double, SI; preceded by a 164 SI).

    Records are written input by input, outputs in order, so :func:`read_frf_uff` with the
    matching setup and :func:`read_uff_test` return the same order. Accelerometer outputs are
    ordinate type 12 ((m/s²)/N), reaction outputs type 9 (N/N, N·m/N), denominator type 13 (N).
    """
    p = Path(path)
    _write_header_sets(p, None, None)
    with p.open("ab") as fh:
        _append58(fh, frf, np.ones(len(frf.outputs)), binary)


def _write_header_sets(
    p: Path,
    setup: TestSetup | None,
    frames: dict[int, tuple[NDArray[np.float64], NDArray[np.float64]]] | None,
) -> None:
    sets: list[dict[str, Any]] = [
        {
            "type": 164,
            "units_code": 1,
            "units_description": "SI: Meter (newton)",
            "temp_mode": 2,
            "length": 1.0,
            "force": 1.0,
            "temp": 1.0,
            "temp_offset": 273.15,
        }
    ]
    if setup is not None and frames is not None:
        nodes = sorted(frames)
        sets.append(
            {
                "type": 2420,
                "Part_UID": 1,
                "Part_Name": setup.name or "NONE",
                "CS_sys_labels": nodes,
                "CS_types": [0] * len(nodes),
                "CS_colors": [8] * len(nodes),
                "CS_names": [f"node {n}" for n in nodes],
                "CS_matrices": [np.vstack([frames[n][1], frames[n][0]]) for n in nodes],
            }
        )
        xyz = np.array([frames[n][0] for n in nodes])
        sets.append(
            {
                "type": 2411,
                "node_nums": np.array(nodes, dtype=int),
                "def_cs": np.zeros(len(nodes), dtype=int),
                "disp_cs": np.array(nodes, dtype=int),
                "color": np.full(len(nodes), 8, dtype=int),
                "x": xyz[:, 0],
                "y": xyz[:, 1],
                "z": xyz[:, 2],
            }
        )
    try:
        p.write_bytes(b"")
    except OSError as err:
        raise SetupError(f"{p}: cannot write ({err.strerror}); check the path") from err
    try:
        import pyuff

        pyuff.UFF(str(p)).write_sets(sets, mode="overwrite")
    except Exception as err:  # pyuff raises bare Exception
        raise SetupError(f"{p}: pyuff could not write the geometry datasets ({err})") from err


def write_uff_test(
    path: str | Path, setup: TestSetup, frf: FrfData, *, binary: bool = True
) -> None:
    """Write a whole test: 164 (SI), 2420 node systems, 2411 nodes and the 58 FRF records.

    Every node gets its own right-handed displacement system (label = node number): the rows
    that carry a channel or input are exactly its GCS direction (sign folded in), the other rows
    complete an orthonormal frame; a load cell's system is its rotation transposed (rows = local
    axes). :func:`read_uff_test` returns an equal setup (up to the non-UFF fields, see the module
    docstring) and equal FRFs (bit-exact in binary, ≤ 5e-14 relative in ASCII).

    Raises
    ------
    SetupError
        Setup and FRFs do not list the same channels; two items at one node disagree on its
        position or on an axis; a node's directions are not orthogonal or are left-handed.
    """
    p = Path(path)
    _check_match(setup, frf)
    frames = _node_frames(setup)
    flip = {lc.node: lc.sign_factor for lc in setup.load_cells}
    sign = np.array(
        [
            flip.get(c.node, 1.0) if k == "reaction" else 1.0
            for c, k in zip(frf.outputs, frf.output_kinds, strict=True)
        ]
    )
    _write_header_sets(p, setup, frames)
    with p.open("ab") as fh:
        _append58(fh, frf, sign, binary)


def check_uff_geometry(setup: TestSetup) -> None:
    """Raise the :class:`SetupError` :func:`write_uff_test` would raise on ``setup``'s geometry
    (a node's directions not orthogonal, left-handed, or two items at one node that disagree),
    without writing: what an acquisition checks before it strikes, so that no test is lost at
    the end for a file that cannot hold its geometry."""
    _node_frames(setup)


def dump_uff(frf: FrfData, setup: TestSetup | None = None, *, binary: bool = True) -> bytes:
    """The content of a UFF file: the whole test (:func:`write_uff_test`) when ``setup`` is
    given, else only the FRFs (:func:`write_frf_uff`)."""
    with tempfile.TemporaryDirectory(prefix="dimacq-uff-") as tmp:
        path = Path(tmp) / "out.uff"
        if setup is not None:
            write_uff_test(path, setup, frf, binary=binary)
        else:
            write_frf_uff(path, frf, binary=binary)
        return path.read_bytes()
