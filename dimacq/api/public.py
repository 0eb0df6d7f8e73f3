"""What a client may see of the server's file system: nothing absolute.

Error messages and job results are passed through :func:`public` before they leave the service:
a path under a temporary folder becomes ``<upload>``, one under the data folder ``<data>/...`` and
one under the rig file's folder ``<rig>/...`` (the folders are registered by the app factory,
:func:`hide_root`).
"""

from __future__ import annotations

import re
import tempfile
from pathlib import Path
from typing import Any

__all__ = ["hide_root", "public", "public_value"]

_ROOTS: dict[str, tuple[re.Pattern[str], str, bool]] = {}


def hide_root(root: str | Path, label: str, *, keep_tail: bool = True) -> None:
    """Show paths under ``root`` as ``<label>/relative`` (``keep_tail``) or as ``<label>``
    alone (temporary files: their names mean nothing to a client)."""
    for p in {str(Path(root)), str(Path(root).resolve())}:
        p = p.rstrip("/")
        if p not in ("", "."):
            rx = re.compile(r"(?<![\w/.~-])" + re.escape(p) + r"(?![\w.~-])(?:/[^\s:;,'\")]*)?")
            _ROOTS[p] = (rx, label, keep_tail)


hide_root(tempfile.gettempdir(), "upload", keep_tail=False)


def public(text: str) -> str:
    """``text`` with every registered server folder replaced by its label (longest first)."""
    for root in sorted(_ROOTS, key=len, reverse=True):
        rx, label, keep = _ROOTS[root]
        n = len(root)

        def repl(m: re.Match[str], n: int = n, label: str = label, keep: bool = keep) -> str:
            return f"<{label}>" + (m.group()[n:] if keep else "")

        text = rx.sub(repl, text)
    return text


def public_value(value: Any) -> Any:
    """:func:`public` applied to every string inside ``value`` (dicts, lists)."""
    if isinstance(value, str):
        return public(value)
    if isinstance(value, dict):
        return {k: public_value(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [public_value(v) for v in value]
    return value
