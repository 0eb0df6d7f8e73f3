"""Writing UFF files: a whole test (:func:`write_uff_test`), only the FRFs (:func:`write_frf_uff`),
their content as bytes (:func:`dump_uff`), and the check of a setup's geometry against what a
UFF node can hold (:func:`check_uff_geometry`).

Writing (:func:`write_uff_test`) produces 164 (SI), 2420 (one right-handed system per node, label =
node number), 2411 (``def_cs`` 0, ``disp_cs`` = the node's system) and 58 records in FRF order.
Round trips: binary records store IEEE doubles (bit-exact); ASCII records use the UFF 4E20
layout, written with 14 significant digits (relative error ≤ 5e-14). The frequency axis is
written as even spacing when ``f0 + k·df`` from the header's E13.5 fields reproduces it exactly,
otherwise as uneven abscissa (exact in binary, 8 significant digits in ASCII, logged).
"""

from __future__ import annotations

import logging
import tempfile
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from dimacq.errors import SetupError
from dimacq.io.uff.datasets import ORTHO_TOL, SAME_TOL, axis_text
from dimacq.model.frf import Channel, FrfData
from dimacq.model.setup import (
    TestSetup,
    Vec3,
)

#: the logger of the module before the split into a package: the messages keep its name
logger = logging.getLogger("dimacq.io.uff")


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
        if err > ORTHO_TOL:
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
        if np.max(np.abs(prev[0] - q)) > SAME_TOL * max(1.0, float(np.max(np.abs(q)))):
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
        if k in s and np.max(np.abs(s[k][0] - v)) > SAME_TOL:
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
            axis_text(f),
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
    axes). :func:`read_uff_test` returns an equal setup (up to the non-UFF fields, see
    :mod:`dimacq.io.uff`) and equal FRFs (bit-exact in binary, ≤ 5e-14 relative in ASCII).

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
