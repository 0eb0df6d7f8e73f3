"""dimacq.io._uff_read (the UFF reader without pyuff) against pyuff's own reading of the same
files: the index, every dataset's keys and values, the batched complex records (issue #27)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import pyuff

from dimacq.io._uff_read import index_blocks, interleaved_complex, read_sets

ROOT = Path(__file__).resolve().parents[2]
EXAMPLE = ROOT / "config" / "examples" / "six_triax_frf.uff"


def _whole_test(tmp_path: Path, *, binary: bool = True) -> Path:
    """A whole-test UFF file (164, 2420, 2411 and 58 records) as ``dimacq simulate`` writes it."""
    from dimacq.io.setup_file import load_setup
    from dimacq.io.uff import read_frf_uff, write_uff_test

    setup = load_setup(ROOT / "config" / "examples" / "six_triax_setup.toml")
    frf = read_frf_uff(EXAMPLE, setup)
    path = tmp_path / ("whole.uff" if binary else "whole-ascii.uff")
    write_uff_test(path, setup, frf, binary=binary)
    return path


def _files(tmp_path: Path) -> list[Path]:
    from _samples import samples_dir  # the shared samples (an independent writer), if present

    shared = sorted(samples_dir().glob("*.uff"))
    return [EXAMPLE, _whole_test(tmp_path), _whole_test(tmp_path, binary=False), *shared]


def _same(got: dict[str, Any], want: dict[str, Any], what: str) -> None:
    assert set(got) - {"_rows"} <= set(want), (what, set(got) - set(want))
    for key in set(got) - {"_rows"}:
        g, w = got[key], want[key]
        if isinstance(w, np.ndarray) or isinstance(g, np.ndarray):
            g, w = np.asarray(g), np.asarray(w)
            assert g.dtype == w.dtype and g.shape == w.shape, (what, key)
            assert g.tobytes() == w.tobytes(), (what, key)  # to the bit, signed zeros too
        elif isinstance(w, list) and w and isinstance(w[0], np.ndarray):
            assert len(g) == len(w), (what, key)
            for a, b in zip(g, w, strict=True):
                assert a.tobytes() == b.tobytes(), (what, key)
        else:
            assert g == w and type(g) is type(w), (what, key, g, w)


@pytest.mark.slow
def test_every_dataset_reads_as_pyuff_reads_it(tmp_path: Path) -> None:
    for path in _files(tmp_path):
        uff = pyuff.UFF(str(path))
        blocks = index_blocks(path.read_bytes())
        assert [(s, e) for s, e, _ in blocks] == [tuple(map(int, b)) for b in uff._block_ind]
        assert [t for _, _, t in blocks] == [int(t) for t in uff.get_set_types()]
        got = read_sets(path)
        assert len(got) == uff.get_n_sets()
        for k, d in enumerate(got):
            _same(d, uff.read_sets(k), f"{path.name} #{k + 1}")


def test_tags_are_found_by_pyuffs_rule(tmp_path: Path) -> None:
    """A tag ends its line (LF, CR, CR LF or the file's end) or is followed by 74 blanks and one
    more byte; '    -1' followed by anything else is no tag (pyuff's index of the same bytes)."""
    raw = (
        b"    -1\r\n  164\n         1  SI\n    1.0    1.0    1.0    0.0\n"
        + b"    -1" + b" " * 74 + b"\n"  # blank-padded closing tag
        + b"    -1\n  2411\n    -1.5    -1   x\n    -1" + b" " * 73 + b"\n"  # none of these
        + b"    -1\r  58\n    -1"  # CR-ended, then one at the file's end
    )  # fmt: skip
    path = tmp_path / "tags.uff"
    path.write_bytes(raw)
    uff = pyuff.UFF(str(path))
    blocks = index_blocks(raw)
    assert [(s, e) for s, e, _ in blocks] == [tuple(map(int, b)) for b in uff._block_ind]
    assert [t for _, _, t in blocks] == [int(t) for t in uff.get_set_types()] == [164, 2411]
    # the 2411 block ends at the CR-ended tag; the tag at the file's end opens no whole block
    assert blocks[1][1] == raw.rindex(b"    -1\r") - 1


@pytest.mark.parametrize("seed", [0, 1])
def test_batched_complex_values_equal_pyuffs_expression_to_the_bit(seed: int) -> None:
    rng = np.random.default_rng(seed)
    values = rng.normal(size=(7, 64))
    specials = np.array([0.0, -0.0, np.inf, -np.inf, np.nan, 1.5, -2.0])
    idx = rng.integers(0, values.size, 120)
    values.flat[idx] = specials[rng.integers(0, specials.size, idx.size)]
    with np.errstate(invalid="ignore"):  # 0·∞ in 1j·im
        want = values[:, 0:-1:2] + 1.0j * values[:, 1::2]
    got = interleaved_complex(values.copy())
    finite = np.isfinite(want)
    assert (np.isfinite(got) == finite).all()
    assert got[finite].tobytes() == want[finite].tobytes()  # signed zeros included
    assert (np.isnan(got.real) == np.isnan(want.real)).all()


@pytest.mark.slow
def test_a_binary_whole_test_is_read_without_pyuff(tmp_path: Path) -> None:
    path = _whole_test(tmp_path)
    code = (
        "import sys; from dimacq.io.uff import read_uff_test; "
        f"read_uff_test({str(path)!r}); print('pyuff' in sys.modules)"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"
