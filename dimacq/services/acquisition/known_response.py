"""The known factor a load cell's own sampling puts on its FRFs, divided out per input.

A cell that answers with values held from its own free-running clock (a Net F/T on CAN, a CiA
404 amplifier) says what that does on average: ``known_response(f)`` (its mean delay and
magnitude, :class:`~dimacq.drivers.held_timing.HeldSampleTiming`). Its rows of each input's
FRFs are divided by it: ``H_cell ← H_cell / R(f)``. Cells without it are left as they are.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from dimacq.devices.loadcell import LoadCell

__all__ = ["KnownResponses"]


class KnownResponses:
    """The cells of one acquisition with a ``known_response`` and their rows in the FRFs.

    Parameters
    ----------
    loadcells : sequence of LoadCell
    widths : sequence of int
        Rows of each cell in the FRFs.
    first_row : int
        The cells' first row.
    """

    def __init__(self, loadcells: Sequence[LoadCell], widths: Sequence[int], first_row: int):
        self.cells: list[tuple[slice, LoadCell]] = []
        row = first_row
        for lc, n in zip(loadcells, widths, strict=True):
            if getattr(lc, "known_response", None) is not None:
                self.cells.append((slice(row, row + n), lc))
            row += n

    def apply(self, frequencies_hz: NDArray[np.float64], H: NDArray[np.complex128]) -> None:
        """``H`` (n_lines, n_outputs) with each such cell's rows divided by its ``R(f)``, in
        place."""
        for rows, lc in self.cells:
            R = np.asarray(lc.known_response(np.asarray(frequencies_hz, dtype=float)))  # type: ignore[attr-defined]
            H[:, rows] /= R[:, None]
