"""Reading the datasets of a UFF file as pyuff reads them, without pyuff where the layout allows.

:func:`read_sets` returns what ``pyuff.UFF(path).read_sets(k)`` returns for every dataset ``k``
(the keys :mod:`dimacq.io.uff` reads, with the same values to the bit), read directly for the
datasets dimacq writes and commercial systems export:

- the **index** of the file: pyuff's own rule (``UFF.refresh``), in one regular-expression pass:
  a tag ``'    -1'`` followed by a line end, by the end of the file, or by 74 blanks and one more
  byte; the tags pair up as (start, end) of each dataset; its type is the integer in the first
  six columns of its second line (0 when that does not parse);
- **164** units, **2411** nodes and **2420** coordinate systems (ASCII): the same lines split the
  same way and the same ``float``/``int`` conversions as pyuff's ``_extract164/2411/2420``;
- binary **58** records (58b): the header lines cut at pyuff's columns with pyuff's rules
  (:func:`_fields`), the values read with ``np.frombuffer`` in the stated byte order and
  precision, abscissa and ordinate formed with pyuff's own expressions. The complex records of
  one file with evenly spaced lines (every FRF a test writes) are converted together: their
  values go into one array (one row per record) and ``x_re + 1j·x_im`` is one operation, each
  element the same as pyuff's per record; the rows come back as views of that array
  (``data``) and one frequency axis per distinct header (``x``, shared by the records).

Anything else (ASCII 58 records, datasets 15, 18, 55, …, a header that does not parse as
expected) is read by pyuff, imported only then, with its own errors; ``dimacq solve`` on a
binary whole-test file then does not import pyuff at all (about 25 ms of start-up) nor index the
file twice. ``tests/io/test_uff_fast_58b.py`` and ``tests/io/test_uff_direct_read.py`` compare
every key and array with pyuff's on the shipped example, the shared samples and variants.
"""

from __future__ import annotations

import re
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from dimacq.errors import DataError

__all__ = ["fast_58b", "index_blocks", "interleaved_complex", "read_sets"]

#: A line end as ``bytes.splitlines`` sees one.
_EOL = re.compile(rb"\r\n|\r|\n")
#: A dataset tag as pyuff's ``refresh`` accepts one (see the module docstring).
_TAG = re.compile(rb"    -1(?=\r|\n|\Z| {74}.)", re.DOTALL)

Spec = Sequence[tuple[int, int, str, str, bool]]


def index_blocks(raw: bytes) -> list[tuple[int, int, int]]:
    """``(start, end, type)`` of each dataset, as pyuff's ``UFF.refresh`` finds them.

    ``start`` is the offset of the opening tag, ``end`` the last byte before the closing one
    (both inclusive, pyuff's ``_block_ind``); ``type`` the dataset number, 0 when unreadable.
    """
    tags = [m.start() for m in _TAG.finditer(raw)]
    out: list[tuple[int, int, int]] = []
    for start, stop in zip(tags[0:-1:2], tags[1::2], strict=False):
        end = stop - 1
        # pyuff: int(data[start:end + 1].splitlines()[1][0:6]), 0 on any error
        m1 = _EOL.search(raw, start, end + 1)
        kind = 0
        if m1 is not None:
            m2 = _EOL.search(raw, m1.end(), end + 1)
            line = raw[m1.end() : (m2.start() if m2 is not None else end + 1)]
            if m2 is not None or m1.end() < end + 1:
                try:
                    kind = int(line[0:6])
                except ValueError:
                    kind = 0
        out.append((start, end, kind))
    return out


def _fields(line: str, spec: Spec) -> dict[str, Any] | None:
    """Fixed-width fields of a header line as pyuff's ``_parse_header_line`` reads them.

    ``spec`` rows: (start, width, type "i"/"f"/"s", name, mandatory). An optional number that
    does not parse becomes 0 (pyuff's rule); a mandatory one returns None (pyuff then raises).
    """
    if len(line) < 80:
        line = line + " " * (80 - len(line))
    out: dict[str, Any] = {}
    for start, width, kind, name, mandatory in spec:
        text = line[start : start + width].strip()
        if kind == "s":
            out[name] = text
            continue
        try:
            out[name] = int(text) if kind == "i" else float(text)
        except ValueError:
            if mandatory:
                return None
            out[name] = 0 if kind == "i" else 0.0
    return out


# (start, width, type, name, mandatory) of the header fields pyuff reads (its widths and types).
_58_LINE1 = (
    (7, 6, "i", "byte_ordering", True),
    (13, 6, "i", "fp_format", True),
    (19, 12, "i", "n_ascii_lines", True),
    (31, 12, "i", "n_bytes", True),
)
_58_LINE7 = (
    (0, 5, "i", "func_type", True),
    (41, 10, "i", "rsp_node", False),
    (51, 4, "i", "rsp_dir", False),
    (66, 10, "i", "ref_node", False),
    (76, 4, "i", "ref_dir", False),
)
_58_LINE8 = (
    (0, 10, "i", "ord_data_type", True),
    (10, 10, "i", "num_pts", True),
    (20, 10, "i", "abscissa_spacing", True),
    (30, 13, "f", "abscissa_min", True),
    (43, 13, "f", "abscissa_inc", True),
    (56, 13, "f", "z_axis_value", True),
)


def _58_axis(prefix: str) -> Spec:
    return (
        (0, 10, "i", f"{prefix}_spec_data_type", True),
        (10, 5, "i", f"{prefix}_len_unit_exp", True),
        (15, 5, "i", f"{prefix}_force_unit_exp", True),
        (20, 5, "i", f"{prefix}_temp_unit_exp", True),
        (25, 21, "s", f"{prefix}_axis_lab", False),
        (46, 21, "s", f"{prefix}_axis_units_lab", False),
    )


_58_SPECS: tuple[tuple[int, Spec], ...] = (
    (1, _58_LINE1),
    (7, _58_LINE7),
    (8, _58_LINE8),
    (9, _58_axis("abscissa")),
    (10, _58_axis("ordinate")),
    (11, _58_axis("orddenom")),
    (12, _58_axis("z_axis")),
)

Memo = dict[tuple[int, str], dict[str, Any] | None]


def _header_58b(
    raw: bytes, start: int, stop: int, memo: Memo | None
) -> tuple[dict[str, Any], int] | None:
    """The header fields of the binary 58 record in ``raw[start:stop]`` and the offset of its
    values, or None (not binary, an ordinate type pyuff does not read, a malformed header)."""
    # The 13 header lines as pyuff cuts them: bytes.splitlines (\n, \r, \r\n), then decoded.
    end = start
    for _ in range(13):
        m = _EOL.search(raw, end, stop)
        if m is None:
            return None
        end = m.end()
    lines = raw[start:end].decode("utf-8", errors="replace").splitlines(True)
    if len(lines) != 13 or len(lines[1]) < 7 or lines[1][6].lower() != "b":
        return None
    d: dict[str, Any] = {"type": 58, "binary": 1}
    for i, spec in _58_SPECS:  # the records of a test share most header lines: parse each once
        if memo is None:
            part = _fields(lines[i], spec)
        else:
            key = (i, lines[i])
            if key not in memo:
                memo[key] = _fields(lines[i], spec)
            part = memo[key]
        if part is None:
            return None
        d.update(part)
    if d["ord_data_type"] not in (2, 4, 5, 6):
        return None
    return d, end


def _values(raw: bytes, d: dict[str, Any], offset: int, stop: int) -> NDArray[np.float64]:
    size = 4 if d["ord_data_type"] in (2, 5) else 8
    order = "<" if d["byte_ordering"] == 1 else ">"
    count = (stop - offset) // size
    return np.frombuffer(raw, dtype=f"{order}f{size}", count=count, offset=offset).astype(
        np.float64
    )


def _fill_58(d: dict[str, Any], values: NDArray[np.float64]) -> dict[str, Any]:
    """pyuff's ``x`` and ``data`` of a 58b record from its values (its expressions)."""
    even = d["abscissa_spacing"] != 0
    if d["ord_data_type"] in (2, 4):
        if even:
            d["x"] = d["abscissa_min"] + np.arange(len(values)) * d["abscissa_inc"]
            d["data"] = values.copy()
        else:
            d["x"] = values[:-1:2].copy()
            d["data"] = values[1::2].copy()
    elif even:
        d["x"] = d["abscissa_min"] + np.arange(len(values) / 2) * d["abscissa_inc"]
        d["data"] = values[0:-1:2] + 1.0j * values[1::2]
    else:
        d["x"] = values[:-2:3].copy()
        d["data"] = values[1:-1:3] + 1.0j * values[2::3]
    return d


def fast_58b(block: bytes, memo: Memo | None = None) -> dict[str, Any] | None:
    """A binary 58 record (the fields :mod:`dimacq.io.uff` reads), or None to let pyuff read it.

    pyuff spends about 1 ms of Python per record on the header (its general field parser, on
    every field) and unpacks the values through a tuple of Python floats; an acquired test
    holds hundreds of records. Here the same header lines are cut at the same columns with the
    same rules (:func:`_fields`), the values are read with ``np.frombuffer`` in the stated byte
    order and precision, and abscissa and ordinate are formed with pyuff's own expressions, so
    the arrays are equal to the bit (``tests/io/test_uff_fast_58b.py``). Anything else (ASCII,
    an ordinate type pyuff does not read, a malformed header) returns None. ``memo`` keeps the
    parsed header lines across the records of one file (most lines repeat in every record).
    """
    head = _header_58b(block, 0, len(block), memo)
    if head is None:
        return None
    d, offset = head
    return _fill_58(d, _values(block, d, offset, len(block)))


def _batched_58b(
    raw: bytes, heads: list[tuple[int, dict[str, Any], int, int]]
) -> dict[int, dict[str, Any]]:
    """The complex, evenly spaced 58b records of ``heads`` ((k, header, offset, stop)) read
    together (module docstring): ``{k: record}`` with ``data`` a row view of one array per
    value layout (``_rows``: that array and the row) and ``x`` one axis per distinct (first
    line, step, count)."""
    groups: dict[tuple[str, int], list[tuple[int, dict[str, Any], int]]] = {}
    for k, d, offset, stop in heads:
        size = 4 if d["ord_data_type"] == 5 else 8
        order = "<" if d["byte_ordering"] == 1 else ">"
        count = (stop - offset) // size
        if count % 2:  # pyuff's arange(count / 2) and the data then differ in length
            continue
        groups.setdefault((f"{order}f{size}", count), []).append((k, d, offset))
    out: dict[int, dict[str, Any]] = {}
    for (dtype, count), members in groups.items():
        values = np.empty((len(members), count))
        for row, (_, _, offset) in enumerate(members):
            values[row] = np.frombuffer(raw, dtype=dtype, count=count, offset=offset)
        data = interleaved_complex(values)
        axes: dict[tuple[float, float], NDArray[np.float64]] = {}
        for row, (k, d, _) in enumerate(members):
            key = (d["abscissa_min"], d["abscissa_inc"])
            x = axes.get(key)
            if x is None:
                x = d["abscissa_min"] + np.arange(count / 2) * d["abscissa_inc"]
                axes[key] = x
            d["x"] = x
            d["data"] = data[row]
            d["_rows"] = (data, row)  # for :func:`dimacq.io.uff._scale_rows`: one op per group
            out[k] = d
    return out


def interleaved_complex(values: NDArray[np.float64]) -> NDArray[np.complex128]:
    """pyuff's ``re + 1j * im`` of interleaved values (rows of ``re₀, im₀, re₁, im₁ …``), in place.

    Viewed as complex the values already are ``re + i·im``; the expression differs only where
    IEEE arithmetic touches a zero or a non-finite number: ``1j * im`` is
    ``(0·im − 0) + i (0 + im)``, so an imaginary ``−0`` becomes ``+0``; adding it to ``re`` turns a
    real ``−0`` into ``+0`` unless ``im`` is negative, and a non-finite ``im`` makes the real part
    NaN (``0·∞``). Those cases are set so here: every value is the expression's, bit for bit
    (``tests/io/test_uff_direct_read.py``), without its two temporaries of the array's size.
    """
    re, im = values[:, 0::2], values[:, 1::2]
    re_to_plus = (re == 0) & np.signbit(re) & ~np.signbit(im)
    im_nonfinite = ~np.isfinite(im)
    re[re_to_plus] = 0.0
    im[(im == 0) & np.signbit(im)] = 0.0
    re[im_nonfinite] = np.nan
    return values.view(np.complex128)


# -- ASCII datasets dimacq writes (pyuff's _extract164 / _extract2411 / _extract2420) ---------
_164_LINE2 = (
    (0, 10, "i", "units_code", True),
    (10, 20, "s", "units_description", False),
    (30, 10, "i", "temp_mode", False),
)


def _extract164(text: str) -> dict[str, Any] | None:
    lines = text.splitlines(True)
    head = _fields(lines[2], _164_LINE2)
    if head is None:
        return None
    words = "".join(lines[3:]).split()
    d: dict[str, Any] = {"type": 164, **head}
    for name, word in zip(("length", "force", "temp", "temp_offset"), words[:4], strict=True):
        d[name] = float(word.lower().replace("d", "e"))
    return d


def _extract2411(text: str) -> dict[str, Any] | None:
    words = "".join(text.splitlines(True)[2:]).split()
    values = np.asarray([float(w.replace("D", "E").replace("d", "E")) for w in words], "d")
    d: dict[str, Any] = {"type": 2411}
    for i, name in enumerate(("node_nums", "def_cs", "disp_cs", "color", "x", "y", "z")):
        d[name] = values[i::7].copy()
    return d


def _extract2420(text: str) -> dict[str, Any] | None:
    lines = text.splitlines(True)
    d: dict[str, Any] = {"type": 2420, "Part_UID": int(lines[2]), "Part_Name": lines[3].rstrip()}
    rec3 = list(map(int, "".join(lines[4::6]).split()))
    d["CS_sys_labels"], d["CS_types"], d["CS_colors"] = rec3[::3], rec3[1::3], rec3[2::3]
    d["CS_names"] = list(map(str.rstrip, lines[5::6]))

    def num(s: str) -> float:
        return float(s.replace("d", "e").replace("D", "E"))

    rows = [list(map(num, "".join(lines[6 + i :: 6]).split())) for i in range(4)]
    d["CS_matrices"] = [
        np.vstack([r[i : i + 3] for r in rows]) for i in np.arange(0, len(rows[0]), 3)
    ]
    return d


_ASCII: dict[int, Callable[[str], dict[str, Any] | None]] = {
    164: _extract164,
    2411: _extract2411,
    2420: _extract2420,
}


def read_sets(path: Path) -> list[dict[str, Any]]:
    """Every dataset of the UFF file at ``path`` (module docstring), in file order.

    Raises
    ------
    DataError
        No such file, no dataset, or a dataset pyuff cannot read (its message quoted).
    """
    if not path.is_file():
        raise DataError(f"{path}: no such UFF file; check the path")
    raw = path.read_bytes()
    blocks = index_blocks(raw)
    if not blocks:
        raise DataError(f"{path}: no UFF datasets found; is it a UFF file?")
    sets: list[dict[str, Any] | None] = [None] * len(blocks)
    memo: Memo = {}  # parsed header lines
    heads: list[tuple[int, dict[str, Any], int, int]] = []
    for k, (start, end, kind) in enumerate(blocks):
        if kind == 58:
            head = _header_58b(raw, start, end + 1, memo)
            if head is None:
                continue  # ASCII or unusual: pyuff's
            d, offset = head
            if d["ord_data_type"] in (5, 6) and d["abscissa_spacing"] != 0:
                heads.append((k, d, offset, end + 1))
            else:
                sets[k] = _fill_58(d, _values(raw, d, offset, end + 1))
        elif kind in _ASCII:
            try:
                sets[k] = _ASCII[kind](raw[start : end + 1].decode("utf-8", errors="replace"))
            except (ValueError, IndexError):
                sets[k] = None  # pyuff reads it (and says what is wrong)
    batched = _batched_58b(raw, heads)
    for k, d, offset, stop in heads:
        sets[k] = batched[k] if k in batched else _fill_58(d, _values(raw, d, offset, stop))
    missing = [k for k, d in enumerate(sets) if d is None]
    if missing:
        _read_with_pyuff(path, blocks, missing, sets)
    return [d for d in sets if d is not None]


def _read_with_pyuff(
    path: Path,
    blocks: list[tuple[int, int, int]],
    missing: list[int],
    sets: list[dict[str, Any] | None],
) -> None:
    """Datasets this module does not read, through pyuff (imported here only)."""
    import pyuff

    try:
        uff = pyuff.UFF(str(path))
        n = uff.get_n_sets()
    except Exception as err:  # pyuff raises bare Exception
        raise DataError(f"{path}: pyuff cannot index the file ({err}); is it a UFF file?") from err
    if n != len(blocks):  # the same rule finds the same datasets; never seen otherwise
        raise DataError(
            f"{path}: pyuff finds {n} datasets where the index finds {len(blocks)}; re-export "
            "the file"
        )
    for k in missing:
        try:
            sets[k] = uff.read_sets(k)
        except Exception as err:
            raise DataError(
                f"{path}: dataset #{k + 1} (type {blocks[k][2]}) cannot be read ({err}); "
                "re-export it or remove it"
            ) from err
