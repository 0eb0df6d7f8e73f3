"""The virtual lab's transducers as they really are: sensitivities off their nominal value.

A real accelerometer or impact hammer leaves the factory within a datasheet tolerance of its
nominal sensitivity (e.g. 100 mV/g ± 5 %); the lab knows it only through its calibration
certificate, which carries the calibrated value with its own small error. The simulated lab
draws each transducer's *true* sensitivity here, seeded by the transducer's serial number, so it
is a property of the transducer, not of the test: the same sensor on the same input is the same
in every run. The code under test never calls this module: it reads the sensitivities of the
rig file (``config/rig.toml``), written once from the simulated certificates
(``tests/scripts/simulated_rig_files.py``).
"""

from __future__ import annotations

import zlib

import numpy as np

__all__ = [
    "ACCEL_TOLERANCE",
    "HAMMER_TOLERANCE",
    "NOMINAL_ACCEL_MV_PER_G",
    "NOMINAL_HAMMER_MV_PER_N",
    "accelerometer_serial",
    "hammer_serial",
    "true_sensitivity",
]

#: Nominal sensitivities of the lab's transducers (the datasheet value).
NOMINAL_ACCEL_MV_PER_G = 100.0
NOMINAL_HAMMER_MV_PER_N = 2.25
#: Datasheet tolerances (half-width, relative): the true value lies within ± this of nominal.
ACCEL_TOLERANCE = 0.05
HAMMER_TOLERANCE = 0.05


def accelerometer_serial(physical_channel: int) -> str:
    """Serial number of the accelerometer axis cabled to DAQ input ``physical_channel``."""
    return f"SIM-ACC-{physical_channel:03d}"


def hammer_serial(physical_channel: int) -> str:
    """Serial number of the hammer cabled to DAQ input ``physical_channel``."""
    return f"SIM-HAM-{physical_channel:03d}"


def true_sensitivity(nominal: float, tolerance: float, serial: str) -> float:
    """The true sensitivity of transducer ``serial``: ``nominal · (1 + u)``, ``u`` uniform in
    ``[−tolerance, tolerance]`` drawn from a generator seeded by the serial number."""
    rng = np.random.default_rng([0x5E45, zlib.crc32(serial.encode("utf-8"))])
    return float(nominal * (1.0 + rng.uniform(-tolerance, tolerance)))
