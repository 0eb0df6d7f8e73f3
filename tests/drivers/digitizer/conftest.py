"""Fixtures of the sonic digitizer tests (see tests/_digitizer_support.py)."""

from _digitizer_support import no_thread_leaks

__all__ = ["no_thread_leaks"]
