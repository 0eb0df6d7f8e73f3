"""File formats: UFF interchange (:mod:`.uff`) and setup files (:mod:`.setup_file`).

The names below are imported from their modules on first use (PEP 562), so that importing one
format (``dimacq solve`` on a UFF file reads :mod:`.uff` only) does not import the others and
their parsers (TOML, JSON documents).
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from dimacq.io.setup_file import load_setup, save_setup
    from dimacq.io.uff import read_frf_uff, read_uff_test, write_frf_uff, write_uff_test

__all__ = [
    "load_setup",
    "read_frf_uff",
    "read_uff_test",
    "save_setup",
    "write_frf_uff",
    "write_uff_test",
]

_HOME = {
    "load_setup": "dimacq.io.setup_file",
    "save_setup": "dimacq.io.setup_file",
    "read_frf_uff": "dimacq.io.uff",
    "read_uff_test": "dimacq.io.uff",
    "write_frf_uff": "dimacq.io.uff",
    "write_uff_test": "dimacq.io.uff",
}


def __getattr__(name: str) -> Any:
    home = _HOME.get(name)
    if home is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(importlib.import_module(home), name)
