"""dimacq.cli._process.keep_freed_memory: glibc keeps the memory a batch command frees."""

from __future__ import annotations

import subprocess
import sys

import pytest

CODE = """
import resource, sys
import numpy as np
from dimacq.cli._process import keep_freed_memory
took = keep_freed_memory() if sys.argv[1] == "on" else False
a = np.ones(1 << 22)  # 32 MB: above glibc's largest automatic mmap threshold
del a
before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
for _ in range(5):
    a = np.ones(1 << 22)
    del a
print(took, resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before)
"""


def _faults(mode: str) -> tuple[bool, int]:
    out = subprocess.run(
        [sys.executable, "-c", CODE, mode], capture_output=True, text=True, check=True
    ).stdout.split()
    return out[0] == "True", int(out[1])


@pytest.mark.slow
@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's mallopt")
def test_freed_arrays_are_reused_without_page_faults() -> None:
    took, kept = _faults("on")
    _, default = _faults("off")
    assert took
    # by default 5 × 32 MB of fresh pages: at least 16 faults each even in 2 MB huge pages
    # (8192 in 4 kB pages); reused memory: next to none
    assert default >= 5 * 16
    assert kept < 16
