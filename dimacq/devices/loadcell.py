"""The 6-DOF load cell device interface: what services, the CLI and the API import.

A load cell amplifier streams its 12 gauge voltages on the DAQ's sample counter and turns them
into forces and moments in the cell's frame with its 6×12 calibration matrix (``F = C g``). The
wire-level implementation is :class:`dimacq.drivers.loadcell.driver.LoadCellAmplifier` on a
python-can bus (frames in :mod:`dimacq.drivers.loadcell.protocol`); the simulator runs on
python-can's ``virtual`` interface (:mod:`dimacq.simulators.loadcell.amplifier`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np
from numpy.typing import NDArray

__all__ = ["LoadCell", "LoadCellBlock", "LoadCellEvent", "LoadCellIdentity"]


@dataclass(frozen=True)
class LoadCellIdentity:
    n_gauges: int
    firmware: str
    serial_number: int


@dataclass(frozen=True)
class LoadCellEvent:
    """``kind`` in ``{"gap", "drift", "overload", "sync_missing", "device_error"}`` over a counter
    range (``device_error``: an EMCY or a lost heartbeat of a CANopen amplifier, naming its node)."""

    kind: str
    first_sample: int
    n_samples: int
    message: str


@dataclass(frozen=True, eq=False)
class LoadCellBlock:
    """Samples ``first_sample .. first_sample + n − 1`` on the DAQ's sample counter.

    Attributes
    ----------
    gauges_v : ndarray, shape (n_gauges, n)
        Gauge readings (12 gauges usually; six conditioned outputs for a cell read that way) in
        its calibration's gauge unit; NaN where frames were lost.
    forces : ndarray, shape (6, n) or None
        ``C g``: ``[Fx, Fy, Fz]`` N and ``[Mx, My, Mz]`` N·m in the cell's frame, when a
        calibration matrix is set.
    valid : ndarray of bool, shape (n,)
    overload : ndarray of bool, shape (n,)
    events : tuple of LoadCellEvent
    """

    first_sample: int
    gauges_v: NDArray[np.float64]
    forces: NDArray[np.float64] | None
    valid: NDArray[np.bool_]
    overload: NDArray[np.bool_]
    events: tuple[LoadCellEvent, ...]

    @property
    def n_samples(self) -> int:
        return int(self.gauges_v.shape[1])


@runtime_checkable
class LoadCell(Protocol):
    """One 6-DOF load cell on the DAQ's sample clock: what an acquisition needs of it.

    How a cell is calibrated, tared or stores its matrix is its own amplifier's business (e.g.
    :class:`dimacq.drivers.loadcell.driver.LoadCellAmplifier`); the backend that opens it
    (:mod:`dimacq.backends`) gives it the matrix of its calibration file.
    """

    sample_rate_hz: float | None
    #: The 6×N matrix ``F = C g`` the cell applies (None: gauges only, no loads).
    calibration_matrix: NDArray[np.float64] | None
    events: list[LoadCellEvent]

    def identify(self) -> LoadCellIdentity: ...

    def set_rate(self, rate_hz: int) -> float: ...

    def start(self, *, external_clock: bool = True) -> None: ...

    def stop(self) -> int: ...

    def read_until(self, end_sample: int, timeout_s: float | None = None) -> LoadCellBlock: ...

    def verify_count(self, daq_samples_clocked: int) -> LoadCellEvent | None: ...
