"""Board files: a good one read back as written, bad items refused with the item and the fix."""

from __future__ import annotations

from pathlib import Path

import pytest

from dimacq.errors import SetupError
from dimacq.io.board_file import BoardFile, dump_board, load_board

GOOD = """schema_version = 1
type = "charuco"
squares_x = 8
squares_y = 11
square_m = 0.025
marker_m = 0.018
dictionary = "DICT_5X5_100"
"""


def test_round_trip(tmp_path: Path) -> None:
    (tmp_path / "b.toml").write_text(GOOD)
    b = load_board(tmp_path / "b.toml")
    assert (b.squares_x, b.squares_y, b.inner_corners) == (8, 11, 70)
    dump_board(b, tmp_path / "c.toml")
    assert load_board(tmp_path / "c.toml") == b
    chess = BoardFile(type="chessboard", squares_x=10, squares_y=7, square_m=0.03)
    assert chess.inner_corners == 54


@pytest.mark.parametrize(
    ("old", "new", "expect"),
    [
        ("marker_m = 0.018", "marker_m = 0.03", r"marker_m = 0\.03 m is not smaller than square_m"),
        ('"DICT_5X5_100"', '"DICT_5X5_99"', r"'DICT_5X5_99' is not an OpenCV predefined dict"),
        ("squares_x = 8", "squares_x = 2", r"item 'squares_x'.*fix: give the number of squares"),
        (
            'squares_x = 8\nsquares_y = 11\nsquare_m = 0.025\nmarker_m = 0.018\ndictionary = "DICT_5X5_100"',
            'squares_x = 13\nsquares_y = 8\nsquare_m = 0.025\nmarker_m = 0.018\ndictionary = "DICT_4X4_50"',
            r"13 x 8 board has 52 markers, more than DICT_4X4_50's 50",
        ),
        ("square_m = 0.025\n", "", r"item 'square_m' is missing; fix: add it: the printed square"),
        ('type = "charuco"', 'type = "charuco"\ncolour = "red"', r"'colour' is not a board item"),
    ],
)
def test_bad_items_named_with_the_fix(tmp_path: Path, old: str, new: str, expect: str) -> None:
    assert old in GOOD
    (tmp_path / "b.toml").write_text(GOOD.replace(old, new))
    with pytest.raises(SetupError, match=expect):
        load_board(tmp_path / "b.toml")


def test_chessboard_with_markers_refused() -> None:
    with pytest.raises(ValueError, match="a chessboard has no markers"):
        BoardFile(type="chessboard", squares_x=10, squares_y=7, square_m=0.03, marker_m=0.02)


def test_missing_file_named(tmp_path: Path) -> None:
    with pytest.raises(SetupError, match="not found; give the path of the board file"):
        load_board(tmp_path / "none.toml")
