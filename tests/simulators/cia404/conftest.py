"""Shared fixtures of the acquisition tests (see tests/_acq_support.py)."""

from _acq_support import no_leaks

__all__ = ["no_leaks"]
