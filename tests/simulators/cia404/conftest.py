"""Shared fixtures of the acquisition tests (see tests/_acq_support.py)."""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from _acq_support import no_leaks

__all__ = ["no_leaks"]
