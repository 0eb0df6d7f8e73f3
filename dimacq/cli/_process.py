"""Process settings for short-lived CLI commands (``dimacq solve``).

:func:`keep_freed_memory` tells glibc's allocator to keep the memory a command frees for its next
arrays instead of handing it back to the kernel. By default glibc maps each block above a
threshold (128 kB, raised up to 32 MB as blocks are freed) with its own ``mmap`` and unmaps it
on ``free``, and returns the top of the heap above 128 kB; every new array of that size then
starts on fresh pages, which the kernel faults in and zeroes one 4 kB page at a time. A solve
makes and drops arrays of 1–25 MB (FRFs, their real views, per-line systems) hundreds of times:
measured on an acquired calibration-mass test (24 × 24 × 2048 lines), 45 000 page faults and
0.2–0.3 s of system time per ``dimacq solve``; with ``M_MMAP_MAX = 0`` (no per-block maps) and
``M_TRIM_THRESHOLD`` at 1 GiB (no trimming) 23 000 faults and 0.06–0.1 s, the peak memory the
same (255 MB). The process exits right after, so nothing is held that another program needs.
Long-running commands (the API server, an acquisition) keep glibc's defaults. Anything other
than glibc (musl, macOS, Windows) is left as it is.
"""

from __future__ import annotations

import ctypes
import logging
import sys

__all__ = ["keep_freed_memory"]

log = logging.getLogger(__name__)

_M_TRIM_THRESHOLD = -1
_M_MMAP_MAX = -4
_KEEP_BYTES = 1 << 30


def keep_freed_memory() -> bool:
    """Keep freed memory in the process (module docstring); True when glibc took the settings."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        # the running program's own symbols (dlopen(NULL)): the C library Python is linked to,
        # without ctypes.util.find_library (which runs `ldconfig -p` in a subprocess)
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):  # not glibc
        return False
    mallopt.argtypes = [ctypes.c_int, ctypes.c_int]
    mallopt.restype = ctypes.c_int
    ok = bool(mallopt(_M_MMAP_MAX, 0)) and bool(mallopt(_M_TRIM_THRESHOLD, _KEEP_BYTES))
    log.debug("allocator keeps freed memory: %s", ok)
    return ok
