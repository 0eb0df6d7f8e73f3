"""Dependency aliases used by the routers (``Annotated`` types, one place).

:data:`IdPath` is the one type of every stored item's id in a path (``/api/setups/{setup_id}``,
acquisitions, FRF sets, calibrations, studies, solutions): 1..:data:`~dimacq.api.schemas.MAX_ID`,
documented in the spec; a value out of that range is answered 404 like any id that names nothing
(the app's validation handler maps errors located in the path to 404), before any database call.

Id segments are matched by the ``id`` path convertor (:class:`IdConvertor`, ``/{setup_id:id}``):
digits of any length. Starlette's ``int`` convertor calls ``int()`` on them, which raises past
4,300 digits (Python's limit for decimal strings): a long id was a 500 on every route. Here a
segment of more than :data:`ID_DIGITS` digits stays a string, and the id's validation refuses it
(404, as any id out of range).
"""

from __future__ import annotations

import re
from typing import Annotated

from fastapi import Depends, Path, Query, Request
from pydantic import BeforeValidator, Strict
from starlette.convertors import Convertor, register_url_convertor

from dimacq.api.schemas import MAX_ID
from dimacq.config import Settings
from dimacq.model.setup import MAX_NAME_CHARS
from dimacq.services.lab import Lab

__all__ = [
    "CANONICAL_INT",
    "ID_DIGITS",
    "IdConvertor",
    "IdPath",
    "JobIdPath",
    "LabDep",
    "NameQuery",
    "SettingsDep",
    "get_lab",
    "get_settings",
]

#: Longest id segment converted to an int by the router (MAX_ID has 10 digits; leading zeros
#: allowed up to here); longer segments are validated as strings (:class:`IdConvertor`).
ID_DIGITS = 20


class IdConvertor(Convertor[int | str]):
    """A path segment of digits: an int when written canonically (no leading zero) in at most
    :data:`ID_DIGITS` digits, else the string (never ``int()`` of thousands of digits, which
    raises; ``0001`` is not another name of item 1); the route's id validation answers 404."""

    regex = "[0-9]+"

    def convert(self, value: str) -> int | str:
        canonical = len(value) <= ID_DIGITS and (value == "0" or not value.startswith("0"))
        return int(value) if canonical else value

    def to_string(self, value: int | str) -> str:
        return str(value)


register_url_convertor("id", IdConvertor())

_CANONICAL = re.compile(rf"0|-?[1-9][0-9]{{0,{ID_DIGITS - 1}}}")


def _canonical_int(value: object) -> object:
    """A query string's integer as written canonically: ``0`` or an optional ``-`` then at most
    :data:`ID_DIGITS` digits, the first not ``0``. Refused (422 naming the parameter): ``01``,
    ``+1``, `` 1``, ``1_0``, ``1.0``, thousands of digits; pydantic's lax mode reads them all as
    numbers, so one id would have many names."""
    if isinstance(value, str) and not _CANONICAL.fullmatch(value):
        shown = value if len(value) <= 24 else f"{value[:12]}…({len(value)} characters)"
        raise ValueError(
            f"{shown!r} is not an integer written plainly; give digits only, without sign, "
            "spaces or leading zeros (e.g. 12)"
        )
    return value


#: The validator of every integer in a query string (ids, indices, paging): canonical form
#: only, as :class:`IdConvertor` for ids in paths.
CANONICAL_INT = BeforeValidator(_canonical_int)


def get_lab(request: Request) -> Lab:
    lab: Lab = request.app.state.lab
    return lab


def get_settings(request: Request) -> Settings:
    settings: Settings = request.app.state.settings
    return settings


LabDep = Annotated[Lab, Depends(get_lab)]
SettingsDep = Annotated[Settings, Depends(get_settings)]
#: Strict: only what :class:`IdConvertor` made an int (canonical digits) is an id; a segment it
#: left a string (leading zeros, too long) is refused (404).
IdPath = Annotated[int, Strict(), Path(ge=1, le=MAX_ID, description=f"the item's id, 1..{MAX_ID}")]
#: A job's id in a path: letters, digits, ``-`` and ``_`` (the service makes 12 hex digits); any
#: other text (NUL, line separators, a path) names no job and is answered 404 before any lookup.
JobIdPath = Annotated[
    str,
    Path(
        min_length=1,
        max_length=64,
        pattern=r"^[A-Za-z0-9_-]+$",
        description="the job's id (letters, digits, '-' and '_'; the service makes 12 hex digits)",
    ),
]
#: A name given in the query (imports): one line of printable text, at most MAX_NAME_CHARS.
NameQuery = Annotated[
    str,
    Query(
        max_length=MAX_NAME_CHARS,
        pattern=r"^[^\x00-\x1f\x7f]*$",
        description=f"one line of printable text, at most {MAX_NAME_CHARS} characters",
    ),
]
