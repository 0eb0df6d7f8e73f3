"""The binary 58 record reader of dimacq.io.uff against pyuff's own reading of the same block."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
import pyuff

from dimacq.io._uff_read import fast_58b as _fast_58b

ROOT = Path(__file__).resolve().parents[2]


def _blocks(path: Path) -> list[tuple[int, bytes, pyuff.UFF]]:
    uff = pyuff.UFF(str(path))
    raw = path.read_bytes()
    types = uff.get_set_types()
    return [
        (k, raw[int(b[0]) : int(b[1]) + 1], uff)
        for k, b in enumerate(uff._block_ind)
        if int(types[k]) == 58
    ]


def _same(fast: dict[str, Any], ref: dict[str, Any]) -> None:
    for key, value in fast.items():
        want = ref[key]
        if isinstance(value, np.ndarray):
            assert value.dtype == want.dtype and value.shape == want.shape, key
            np.testing.assert_array_equal(value, want, err_msg=key)
        else:
            assert value == want and type(value) is type(want), (key, value, want)


def _variant(block: bytes, *, order: str, single: bool, real: bool, uneven: bool) -> bytes:
    """The block re-encoded: byte order, precision, real or complex ordinate, even or uneven
    abscissa (header fields edited at pyuff's columns, values packed anew)."""
    lines = block.splitlines(True)
    ref = _extract58(block)
    y = ref["data"].real if real else ref["data"]
    x = ref["x"]
    ord_type = (2 if single else 4) if real else (5 if single else 6)
    cols = [y] if real else [y.real, y.imag]
    vals = np.column_stack(([x] if uneven else []) + cols).ravel()
    data = vals.astype(f"{order}{'f4' if single else 'f8'}").tobytes()
    l1 = lines[1].decode()
    l1 = l1[:7] + f"{1 if order == '<' else 2:6d}" + l1[13:]
    l8 = lines[8].decode()
    l8 = f"{ord_type:10d}" + l8[10:20] + f"{0 if uneven else 1:10d}" + l8[30:]
    head = lines[:1] + [l1.encode()] + lines[2:8] + [l8.encode()] + lines[9:13]
    return b"".join(head) + data + b"\n"


def _extract58(block: bytes) -> dict[str, Any]:
    from pyuff.datasets.dataset_58 import _extract58 as extract

    out: dict[str, Any] = extract(block)
    return out


EXAMPLE = ROOT / "config" / "examples" / "six_triax_frf.uff"


@pytest.mark.parametrize("order", ["<", ">"])
@pytest.mark.parametrize("single", [False, True])
@pytest.mark.parametrize("real", [False, True])
@pytest.mark.parametrize("uneven", [False, True])
def test_binary_variants_read_as_pyuff_reads_them(
    order: str, single: bool, real: bool, uneven: bool
) -> None:
    """Byte orders, precisions, real and complex ordinates, even and uneven abscissae, and the
    header's line ends turned to CR LF."""
    for _, block, _ in _blocks(EXAMPLE)[:5]:
        v = _variant(block, order=order, single=single, real=real, uneven=uneven)
        fast = _fast_58b(v)
        assert fast is not None
        _same(fast, _extract58(v))
        lines = v.splitlines(True)
        crlf = (
            b"".join(ln.rstrip(b"\n") + b"\r\n" for ln in lines[:13])
            + v[len(b"".join(lines[:13])) :]
        )
        fast_crlf = _fast_58b(crlf)
        assert fast_crlf is not None
        _same(fast_crlf, _extract58(crlf))


def test_ascii_records_are_left_to_pyuff(tmp_path: Path) -> None:
    from dimacq.io.setup_file import load_setup
    from dimacq.io.uff import read_frf_uff, write_frf_uff

    setup = load_setup(ROOT / "config" / "examples" / "six_triax_setup.toml")
    frf = read_frf_uff(EXAMPLE, setup)
    path = tmp_path / "ascii.uff"
    write_frf_uff(path, frf.select(outputs=np.arange(2), inputs=np.arange(2)), binary=False)
    blocks = _blocks(path)
    assert blocks and all(_fast_58b(b) is None for _, b, _ in blocks)


def test_shipped_example_records_read_as_pyuff_reads_them() -> None:
    blocks = _blocks(EXAMPLE)
    assert blocks
    memo: dict[tuple[int, str], dict[str, Any] | None] = {}  # shared lines parsed once
    for k, block, uff in blocks:
        for fast in (_fast_58b(block), _fast_58b(block, memo)):
            assert fast is not None
            _same(fast, uff.read_sets(k))
    assert len(memo) < 7 * len(blocks)


def test_malformed_header_is_left_to_pyuff() -> None:
    block = _blocks(EXAMPLE)[0][1]
    lines = block.splitlines(True)
    bad = lines[:8] + [b"   xx" + lines[8][5:]] + lines[9:]  # ord_data_type not a number
    assert _fast_58b(b"".join(bad)) is None
    assert _fast_58b(b"".join(lines[:5])) is None  # cut short


def test_common_axis_names_the_first_record_off_the_axis() -> None:
    """The stacked comparison reports what the per-record np.allclose loop reported."""
    from dimacq.errors import DataError
    from dimacq.io.uff import Record, common_axis

    f = np.linspace(1.0, 100.0, 100)

    def rec(k: int, axis: np.ndarray) -> Record:
        return Record(k, k, 1, 50, 1, "acceleration", axis, np.zeros(axis.size, complex))

    good = [rec(k, f * (1 + 1e-10 * k)) for k in range(1, 5)]  # within rtol 1e-9
    assert common_axis(good, Path("t.uff")) is good[0].frequencies_hz
    off = good[:2] + [rec(7, f + 0.5), rec(8, f[:-1]), rec(9, f + 1.0)]
    with pytest.raises(DataError, match=r"58 record #7 \(7\+X/50\+X\) has 100 lines 1.5"):
        common_axis(off, Path("t.uff"))
    short_first = good[:2] + [rec(8, f[:-1]), rec(9, f + 1.0)]
    with pytest.raises(DataError, match=r"58 record #8 .* has 99 lines"):
        common_axis(short_first, Path("t.uff"))
