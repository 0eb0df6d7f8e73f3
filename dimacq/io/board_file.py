"""Board files: the calibration board a camera is calibrated with.

A board file (TOML, ``schema_version = 1``) states the printed board::

    schema_version = 1
    type = "charuco"             # charuco | chessboard
    squares_x = 8                # squares along the board's width
    squares_y = 11               # squares along its height
    square_m = 0.025             # side of a square as printed (measure it), m
    marker_m = 0.018             # charuco: side of the ArUco marker inside a white square, m
    dictionary = "DICT_5X5_100"  # charuco: cv2.aruco predefined dictionary of the markers
    legacy_pattern = false       # charuco: a board printed by OpenCV before 4.6 with an even
                                 #   squares_y (its first square white instead of black)

A ChArUco board's inner corners are ``(squares_x − 1) (squares_y − 1)``; each is named by the
markers around it, so a photo showing part of the board still gives known corners. A chessboard
gives corners only when all ``(squares_x − 1) × (squares_y − 1)`` inner corners are seen.
``square_m`` sets the scale of the board's poses only: the intrinsics do not depend on it.
"""

from __future__ import annotations

import tomllib
from pathlib import Path
from typing import Any, Literal

import tomli_w
from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from dimacq.errors import SetupError
from dimacq.io.validation import refuse

__all__ = ["DICTIONARY_SIZES", "BoardFile", "dump_board", "load_board"]

#: OpenCV's predefined ArUco dictionaries and how many markers each holds.
DICTIONARY_SIZES = {
    **{f"DICT_{n}X{n}_{k}": k for n in (4, 5, 6, 7) for k in (50, 100, 250, 1000)},
    "DICT_ARUCO_ORIGINAL": 1024,
    "DICT_APRILTAG_16h5": 30,
    "DICT_APRILTAG_25h9": 35,
    "DICT_APRILTAG_36h10": 2320,
    "DICT_APRILTAG_36h11": 587,
    "DICT_ARUCO_MIP_36h12": 250,
}


class BoardFile(BaseModel):
    """A calibration board (see the module)."""

    model_config = ConfigDict(extra="forbid", frozen=True)
    schema_version: Literal[1] = 1
    type: Literal["charuco", "chessboard"] = Field(
        default="charuco", description='the board type: "charuco" or "chessboard"'
    )
    squares_x: int = Field(ge=3, le=100, description="the number of squares across (3 to 100)")
    squares_y: int = Field(ge=3, le=100, description="the number of squares down (3 to 100)")
    square_m: float = Field(
        gt=0, le=1.0, description="the printed square's side in metres (measure the print)"
    )
    marker_m: float | None = Field(
        default=None,
        gt=0,
        description="the marker's side in metres, smaller than square_m (charuco boards)",
    )
    dictionary: str | None = Field(
        default=None,
        description="the markers' OpenCV dictionary name, e.g. DICT_5X5_100 (charuco boards)",
    )
    legacy_pattern: bool = Field(
        default=False,
        description="true for a board printed by OpenCV before 4.6 with an even squares_y",
    )

    @model_validator(mode="after")
    def _consistent(self) -> BoardFile:
        if self.type == "chessboard":
            if self.marker_m is not None or self.dictionary is not None:
                raise ValueError(
                    "a chessboard has no markers: remove marker_m and dictionary, or set "
                    'type = "charuco"'
                )
            return self
        if self.marker_m is None:
            raise ValueError("a charuco board needs marker_m: give the marker's side in metres")
        if not self.marker_m < self.square_m:
            raise ValueError(
                f"marker_m = {self.marker_m} m is not smaller than square_m = {self.square_m} m: "
                "a marker sits inside a square; measure both on the print"
            )
        if self.dictionary is None:
            raise ValueError(
                "a charuco board needs dictionary: give its OpenCV name, e.g. DICT_5X5_100"
            )
        if self.dictionary not in DICTIONARY_SIZES:
            raise ValueError(
                f"dictionary {self.dictionary!r} is not an OpenCV predefined dictionary; give one "
                f"of {', '.join(DICTIONARY_SIZES)}"
            )
        need = self.squares_x * self.squares_y // 2
        if need > DICTIONARY_SIZES[self.dictionary]:
            raise ValueError(
                f"a {self.squares_x} x {self.squares_y} board has {need} markers, more than "
                f"{self.dictionary}'s {DICTIONARY_SIZES[self.dictionary]}: give the dictionary "
                "the board was printed with"
            )
        return self

    @property
    def inner_corners(self) -> int:
        """The board's inner corners, ``(squares_x − 1)(squares_y − 1)``."""
        return (self.squares_x - 1) * (self.squares_y - 1)


def load_board(path: str | Path) -> BoardFile:
    """Read and check a board file; a bad one is refused with the item and the fix named."""
    p = Path(path)
    try:
        data: Any = tomllib.loads(p.read_text(encoding="utf-8"))
    except FileNotFoundError as err:
        raise SetupError(f"board file {p}: not found; give the path of the board file") from err
    except tomllib.TOMLDecodeError as err:
        raise SetupError(f"board file {p}: not valid TOML ({err}); fix the syntax") from err
    try:
        return BoardFile.model_validate(data)
    except ValidationError as err:
        raise refuse(
            "board file", str(p), err, BoardFile, "see dimacq/manual/photo-geometry.md"
        ) from err


def dump_board(board: BoardFile, path: str | Path) -> None:
    """Write a board file (TOML)."""
    Path(path).write_text(tomli_w.dumps(board.model_dump(exclude_none=True)), encoding="utf-8")
