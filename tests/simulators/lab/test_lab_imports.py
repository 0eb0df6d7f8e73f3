"""What the virtual lab's sample source imports: scipy.signal only with shakers."""

from __future__ import annotations

import subprocess
import sys

CODE = """
import sys
import numpy as np
from dimacq.simulators.lab.impact import virtual_lab
from dimacq.simulators.lab.scenarios import build_scenario
built = build_scenario("calibration-mass-bungee", 0)
x = virtual_lab(built).read(np.arange(3), 0, 2048)
print(x.shape == (3, 2048) and bool(np.isfinite(x).all()), "scipy.signal" in sys.modules)
virtual_lab(built, n_shakers=1)
print("scipy.signal" in sys.modules)
"""


def test_an_impact_lab_does_not_load_scipy_signal_a_shaker_lab_does() -> None:
    """An impact test's source needs no filter design or IIR filtering (about 40 MB of scipy
    modules a process would hold); a shaker's anti-alias filter loads them."""
    out = subprocess.run(
        [sys.executable, "-c", CODE], capture_output=True, text=True, check=True
    ).stdout.split()
    assert out == ["True", "False", "True"]
