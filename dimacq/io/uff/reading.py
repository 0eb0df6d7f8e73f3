"""Reading UFF files: a whole test, geometry and FRFs (:func:`read_uff_test`), or the FRFs matched
to a setup from a setup file (:func:`read_frf_uff`). The datasets are parsed and converted to SI
by :mod:`.datasets`; here the records become one :class:`~dimacq.model.frf.FrfData` on a common
frequency axis, and the nodes' coordinates and systems the setup's geometry.

Geometry from records: an accelerometer channel ``(node, d)`` gets ``direction_gcs = sign(d) ×
row |d|`` of its node's displacement system and ``position_m`` = the node's coordinates; an
input likewise; a load cell at ``node`` gets ``position_m`` = the node's coordinates and
``rotation`` = the transpose of the node's rows-as-axes matrix (columns = local axes in the GCS),
sign ``"on_structure"`` (the samples' convention: the load the support exerts on the body).
"""

from __future__ import annotations

import logging
import os
import tempfile
from collections.abc import Iterable, Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import BinaryIO

import numpy as np
from numpy.typing import NDArray
from pydantic import ValidationError

from dimacq.errors import DataError, DimacqError
from dimacq.io.uff.datasets import Content, Record, axis_text, parse
from dimacq.model.frf import Channel, FrfData
from dimacq.model.setup import (
    Excitation,
    KnownProperties,
    LoadCell,
    ResponseChannel,
    TestSetup,
    Vec3,
)

#: the logger of the module before the split into a package: the messages keep its name
logger = logging.getLogger("dimacq.io.uff")


def common_axis(records: Sequence[Record], path: Path) -> NDArray[np.float64]:
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
            f"{path}: {r.name} has {axis_text(r.frequencies_hz)} but {first.name} has "
            f"{axis_text(f0)}; export all FRFs on one frequency axis"
        )
    return f0


def _assemble(
    records: Sequence[Record],
    outputs: Sequence[tuple[Channel, str]],
    inputs: Sequence[Channel],
    path: Path,
) -> FrfData:
    """Fill H (n_lines, n_outputs, n_inputs) from records; every pair must be present once."""
    if not records:
        raise DataError(f"{path}: no FRF records (58, function type 4) to read; export the FRFs")
    f = common_axis(records, path)
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
    records: Iterable[Record], path: Path
) -> tuple[list[tuple[Channel, str]], list[Channel]]:
    outputs: dict[Channel, str] = {}
    node_kind: dict[int, tuple[str, Record]] = {}
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


def _node_geometry(content: Content, node: int, used_by: str) -> tuple[Vec3, NDArray[np.float64]]:
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
    path : the ``.uff``/``.unv`` file (layout in :mod:`dimacq.io.uff.datasets`): a path, its content
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
    content = parse(p)
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
        axis_text(frf.frequencies_hz),
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
    content = parse(p)
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
