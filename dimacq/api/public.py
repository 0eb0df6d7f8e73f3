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

_ROOTS: dict[str, tuple[re.Pattern[str], str]] = {}


def _pattern(root: str, tail: bool) -> re.Pattern[str]:
    rest = r"/[^\s:;,'\")]*" if tail else r"(?:/[^\s:;,'\")]*)?"
    return re.compile(r"(?<![\w/.~-])" + re.escape(root.rstrip("/")) + rest)


def hide_root(root: str | Path, label: str) -> None:
    """Show paths under ``root`` as ``<label>/relative`` (``root`` itself as ``<label>``)."""
    for p in {str(Path(root)), str(Path(root).resolve())}:
        if p not in ("", "/", "."):
            _ROOTS[p] = (_pattern(p, tail=False), label)


hide_root(tempfile.gettempdir(), "upload")


def public(text: str) -> str:
    """``text`` with every registered server folder replaced by its label (longest first)."""
    for root in sorted(_ROOTS, key=len, reverse=True):
        rx, label = _ROOTS[root]
        text = rx.sub(
            lambda m, r=root, lab=label: f"<{lab}>{m.group()[len(r.rstrip('/')) :]}", text
        )
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
