"""Fixtures of the sonic digitizer tests (see tests/_digitizer_support.py)."""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from _digitizer_support import no_thread_leaks

__all__ = ["no_thread_leaks"]
