"""The value types every entry point shares: JSON bodies, query strings, TOML/JSON/CSV/UFF files,
the rig file and the bench files are validated through these ``Annotated`` aliases, so a value the
door accepts is one the code below can use.

Numbers
    Strict (``"1"`` and ``true`` are not numbers; an integer is a float) and finite (no NaN or
    ±inf, whether written as a number or as the strings ``"nan"``, ``"inf"``, ``"1e999"``), within a
    physical range where the quantity has one: :data:`Finite`, :data:`Coordinate` (±1e6: metres
    or millimetres of a lab-sized article), :data:`UnitComponent` (a direction's component,
    |·| ≤ 1), :data:`StrictInt`.

Text
    :data:`OneLine` is one line of printable text: no C0 or C1 control character (NUL, tab, CR,
    LF, ``\\x85``), no Unicode line or paragraph separator (``\\u2028``, ``\\u2029``), no unpaired
    surrogate. :data:`FreeText` (notes) may hold line breaks and tabs, nothing else of those.

Every refusal is a pydantic error located at the field, so the message names it.
"""

from __future__ import annotations

import math
import re
from pathlib import PurePosixPath, PureWindowsPath
from typing import Annotated

from pydantic import AfterValidator, Field, Strict

__all__ = [
    "BAD_TEXT",
    "COORDINATE_LIMIT",
    "Coordinate",
    "Finite",
    "FreeText",
    "OneLine",
    "RelativePath",
    "StrictInt",
    "UnitComponent",
    "check_free_text",
    "check_one_line",
    "check_relative_path",
]

#: Characters refused in one line of text: C0 and C1 controls, DEL, the Unicode line and
#: paragraph separators, and unpaired surrogates (they cannot be encoded to UTF-8).
BAD_TEXT = re.compile("[\x00-\x1f\x7f-\x9f\u2028\u2029\ud800-\udfff]")
#: Refused in free text: the same but tab, LF and CR.
_BAD_FREE_TEXT = re.compile("[\x00-\x08\x0b\x0c\x0e-\x1f\x7f-\x9f\u2028\u2029\ud800-\udfff]")

#: The largest coordinate accepted, in the unit of the file (m or mm): 1,000 km in metres.
COORDINATE_LIMIT = 1e6


def _describe(text: str, m: re.Match[str]) -> str:
    ch = m.group()
    if "\ud800" <= ch <= "\udfff":
        return f"holds an unpaired surrogate at position {m.start()}"
    return f"holds the control character {ch!r} at position {m.start()}"


def check_one_line(value: str) -> str:
    """``value`` when it is one line of printable text, else ``ValueError`` saying where not."""
    m = BAD_TEXT.search(value)
    if m is not None:
        raise ValueError(
            f"{_describe(value, m)}; give one line of printable text (no line breaks, tabs, NUL "
            "or Unicode line separators)"
        )
    return value


def check_free_text(value: str) -> str:
    """``value`` when it is printable text (line breaks and tabs allowed), else ``ValueError``."""
    m = _BAD_FREE_TEXT.search(value)
    if m is not None:
        raise ValueError(f"{_describe(value, m)}; give printable text (no NUL or control codes)")
    return value


def check_relative_path(value: str) -> str:
    """``value`` when it is a relative path that stays in its folder (no absolute path, drive,
    ``~`` or ``..``); else ``ValueError``. Where it points is the reader's to check (symbolic
    links)."""
    check_one_line(value)
    p = PurePosixPath(value.replace("\\", "/"))
    if p.is_absolute() or PureWindowsPath(value).is_absolute() or value.startswith("~"):
        raise ValueError(f"{value!r} is an absolute path; give a path relative to the file")
    if ".." in p.parts:
        raise ValueError(f"{value!r} leaves the file's folder ('..'); keep it in that folder")
    return value


def _finite(value: float) -> float:
    if not math.isfinite(value):
        raise ValueError(f"{value!r} is not a finite number; give a finite number")
    return value


#: A finite number (strict: not a string, not a boolean).
Finite = Annotated[float, Strict(), Field(allow_inf_nan=False), AfterValidator(_finite)]
#: An integer (strict: not a string, a float or a boolean).
StrictInt = Annotated[int, Strict()]
#: A coordinate of a lab-sized article, within ±:data:`COORDINATE_LIMIT` (m or mm).
Coordinate = Annotated[Finite, Field(ge=-COORDINATE_LIMIT, le=COORDINATE_LIMIT)]
#: A component of a direction vector (|·| ≤ 1; the vector's length is checked by its model).
UnitComponent = Annotated[Finite, Field(ge=-1.0, le=1.0)]
#: One line of printable text (names, labels, serial numbers, paths).
OneLine = Annotated[str, AfterValidator(check_one_line)]
#: A path relative to the file that names it, inside that file's folder.
RelativePath = Annotated[
    str, Field(min_length=1, max_length=1000), AfterValidator(check_relative_path)
]
#: Printable text that may span lines (notes).
FreeText = Annotated[str, AfterValidator(check_free_text)]
