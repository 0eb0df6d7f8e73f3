"""JSON and TOML documents from outside (uploads, request bodies, files), read within limits.

``json.loads`` and ``tomllib.loads`` have no limits of their own that fail politely: a document
nested 100,000 brackets deep raises ``RecursionError``, a 5,000-digit integer ``ValueError``
(Python's 4,300-digit limit of ``int()``), and a TOML array of millions of items is read whole.
The readers here refuse those with a :class:`~dimacq.errors.SetupError` naming the limit:

- :data:`MAX_DOCUMENT_BYTES` of text (a setup file of the X-38 is ~60 kB, a rig file ~5 kB);
- :data:`MAX_DEPTH` levels of nested arrays and tables/objects (ours use 4);
- :data:`MAX_VALUES` values in all (arrays, tables and scalars);
- integers of at most 4,300 digits (what Python converts);
- finite numbers only (no NaN or infinity: JSON ``NaN``, ``Infinity``, ``1e999``; TOML ``nan``,
  ``inf``), the item named;
- text without unpaired surrogates (JSON ``"\\ud800"``: Python reads it, nothing can store or
  write it as UTF-8).

The depth is checked on the parsed document too (TOML's dotted keys nest without recursion).
"""

from __future__ import annotations

import json
import math
import re
import tomllib
from typing import Any

from dimacq.errors import SetupError

__all__ = [
    "MAX_DEPTH",
    "MAX_DOCUMENT_BYTES",
    "MAX_VALUES",
    "check_shape",
    "find_non_finite",
    "find_surrogate",
    "loads_json",
    "loads_toml",
]

#: Largest JSON or TOML document read, bytes of UTF-8 text.
MAX_DOCUMENT_BYTES = 4 * 1024 * 1024
#: Deepest nesting of arrays and objects/tables.
MAX_DEPTH = 32
#: Most values (scalars, arrays, objects) in one document.
MAX_VALUES = 500_000


def _size(text: str | bytes, source: str) -> None:
    n = len(text.encode("utf-8", "surrogatepass") if isinstance(text, str) else text)
    if n > MAX_DOCUMENT_BYTES:
        raise SetupError(
            f"{source}: {n} bytes, more than the {MAX_DOCUMENT_BYTES} bytes a document may have "
            "(MAX_DOCUMENT_BYTES); send a smaller document"
        )


def _where(loc: tuple[str | int, ...]) -> str:
    out = ""
    for p in loc:
        out += f"[{p}]" if isinstance(p, int) else ("." if out else "") + str(p)
    return out or "the document"


_SURROGATE = re.compile("[\ud800-\udfff]")


def find_non_finite(doc: Any) -> tuple[tuple[str | int, ...], float] | None:
    """The location (keys and indices) and value of the first NaN or ±inf number in ``doc``
    (parsed JSON or TOML), or None; iterative, any depth."""
    todo: list[tuple[Any, tuple[str | int, ...]]] = [(doc, ())]
    while todo:
        value, loc = todo.pop()
        if isinstance(value, float):
            if not math.isfinite(value):
                return loc, value
        elif isinstance(value, dict):
            todo.extend((v, (*loc, str(k))) for k, v in reversed(value.items()))
        elif isinstance(value, list):
            todo.extend((v, (*loc, i)) for i, v in reversed(list(enumerate(value))))
    return None


def find_surrogate(doc: Any) -> tuple[str | int, ...] | None:
    """The location of the first string (value or key) in ``doc`` holding an unpaired UTF-16
    surrogate (JSON ``"\\ud800"``: not a character, cannot be stored or written as UTF-8),
    or None."""
    todo: list[tuple[Any, tuple[str | int, ...]]] = [(doc, ())]
    while todo:
        value, loc = todo.pop()
        if isinstance(value, str):
            if _SURROGATE.search(value):
                return loc
        elif isinstance(value, dict):
            for k in value:
                if isinstance(k, str) and _SURROGATE.search(k):
                    return (*loc, "<key>")
            todo.extend((v, (*loc, str(k))) for k, v in reversed(value.items()))
        elif isinstance(value, list):
            todo.extend((v, (*loc, i)) for i, v in reversed(list(enumerate(value))))
    return None


def check_shape(doc: Any, source: str) -> None:
    """Refuse ``doc`` nested deeper than :data:`MAX_DEPTH`, with more than :data:`MAX_VALUES`
    values, a string with an unpaired surrogate, or a NaN or ±inf number (JSON ``NaN``/``Infinity``/``1e999``, TOML ``nan``/
    ``inf``: no quantity we read may be one). Iterative: any depth is walked safely."""
    todo: list[tuple[Any, int]] = [(doc, 1)]
    count = 0
    while todo:
        value, depth = todo.pop()
        count += 1
        if count > MAX_VALUES:
            raise SetupError(
                f"{source}: more than {MAX_VALUES} values (MAX_VALUES); send a smaller document"
            )
        if isinstance(value, dict):
            children: Any = value.values()
        elif isinstance(value, list):
            children = value
        else:
            continue
        if depth > MAX_DEPTH:
            raise SetupError(
                f"{source}: nested more than {MAX_DEPTH} levels deep (MAX_DEPTH); "
                "flatten the document"
            )
        todo.extend((c, depth + 1) for c in children)
    where = find_surrogate(doc)
    if where is not None:
        raise SetupError(
            f"{source}: {_where(where)} holds an unpaired surrogate (\\ud800-\\udfff), which is "
            "not a character; send UTF-8 text"
        )
    bad = find_non_finite(doc)
    if bad is not None:
        raise SetupError(
            f"{source}: {_where(bad[0])} is {bad[1]}; give a finite number "
            "(NaN and infinities are refused)"
        )


def loads_json(text: str | bytes, source: str) -> Any:
    """Parse JSON within the limits (module docstring).

    Raises
    ------
    SetupError
        Too large, too deep, too many values, an integer of more than 4,300 digits, invalid JSON
        or not UTF-8; the message names ``source``, the limit and the fix.
    """
    _size(text, source)
    try:
        doc = json.loads(text)
    except RecursionError:
        raise SetupError(
            f"{source}: nested more than {MAX_DEPTH} levels deep (MAX_DEPTH); flatten the document"
        ) from None
    except json.JSONDecodeError as err:
        raise SetupError(
            f"{source}: not valid JSON: {err.msg} at line {err.lineno} column {err.colno}; "
            "correct the syntax there"
        ) from err
    except UnicodeDecodeError as err:
        raise SetupError(f"{source}: not UTF-8 text ({err}); save it as UTF-8") from err
    except ValueError:  # int() of more than 4,300 digits
        raise SetupError(
            f"{source}: a number has more than 4300 digits (Python's int limit); write it shorter"
        ) from None
    check_shape(doc, source)
    return doc


def loads_toml(text: str, source: str) -> dict[str, Any]:
    """Parse TOML within the limits (module docstring).

    Raises
    ------
    SetupError
        Too large, too deep, too many values, an integer of more than 4,300 digits or invalid
        TOML; the message names ``source``, the limit and the fix.
    """
    _size(text, source)
    try:
        doc = tomllib.loads(text)
    except RecursionError:
        raise SetupError(
            f"{source}: nested more than {MAX_DEPTH} levels deep (MAX_DEPTH); flatten the document"
        ) from None
    except tomllib.TOMLDecodeError as err:
        raise SetupError(f"{source}: not valid TOML: {err}; correct the syntax there") from err
    except ValueError:  # int() of more than 4,300 digits
        raise SetupError(
            f"{source}: a number has more than 4300 digits (Python's int limit); write it shorter"
        ) from None
    check_shape(doc, source)
    return doc
