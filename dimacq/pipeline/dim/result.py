"""The result of a DIM solve: :class:`DimResult` (the solution with its evidence: per-line
spectrum, band statistics, rank, condition number, residual, the channels used, diagnostics) and
:class:`Diagnostic` (one plausibility or quality check), with the JSON of ``dimacq solve --json``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from dimacq.model.frf import Channel
from dimacq.model.properties import (
    RigidBodyProperties,
)

FloatArray = NDArray[np.float64]
ComplexArray = NDArray[np.complex128]


#: θ's first moments ``s = m·c`` reported as the CG parameter they estimate.
_UNKNOWN_NAME = {"sx": "cx", "sy": "cy", "sz": "cz"}


# --------------------------------------------------------------------------------------------
# Results
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Diagnostic:
    """One plausibility or quality check, reported whatever its outcome."""

    code: str
    ok: bool
    message: str
    severity: Literal["info", "warning", "error"] = "warning"

    def as_dict(self) -> dict[str, Any]:
        return {
            "code": self.code,
            "ok": self.ok,
            "severity": self.severity,
            "message": self.message,
        }


@dataclass(frozen=True, eq=False)
class DimResult:
    """A DIM solution with its evidence.

    Attributes
    ----------
    properties : RigidBodyProperties
        Headline answer (CG in the GCS, inertia about the CG).
    reference_point_m : ndarray, shape (3,)
    parameters : ndarray, shape (10,)
        ``[m, cx, cy, cz, Ixx, Ixy, Ixz, Iyy, Iyz, Izz]``, CG in the GCS (m), inertia about P (kg·m²).
    frequencies_hz : ndarray, shape (n_lines,)
    per_line : ndarray, shape (n_lines, 10)
        The spectrum of estimates, same layout as ``parameters`` (NaN on lines of rank < unknowns).
    band_stats : dict
        Per parameter: ``mean``, ``std``, ``min``, ``max`` over the lines of the band.
    method : {"joint", "mean"}
        Joint least squares over the band, or mean of the per-line estimates.
    rank, n_unknowns : int
    condition_number : float
        Of the column-equilibrated design matrix (joint system).
    residual_rel : float
        ``‖A x − b‖ / ‖b‖`` over the band.
    unknowns : tuple of str
    known : dict
    """

    properties: RigidBodyProperties
    reference_point_m: FloatArray
    parameters: FloatArray
    frequencies_hz: FloatArray
    per_line: FloatArray
    band_stats: dict[str, dict[str, float]]
    method: str
    rank: int
    n_unknowns: int
    condition_number: float
    residual_rel: float
    unknowns: tuple[str, ...]
    known: dict[str, float]
    length_unit: str
    responses: tuple[Channel, ...]
    inputs: tuple[Channel, ...]
    load_cells: tuple[int, ...]
    response_condition: float
    diagnostics: tuple[Diagnostic, ...] = ()
    extras: dict[str, Any] = field(default_factory=dict)

    @property
    def mass_kg(self) -> float:
        return self.properties.mass_kg

    @property
    def cg_m(self) -> FloatArray:
        return self.properties.cg_m

    @property
    def inertia_p_kgm2(self) -> FloatArray:
        return self.properties.inertia_about(self.reference_point_m)

    @property
    def inertia_cg_kgm2(self) -> FloatArray:
        return self.properties.inertia_cg_kgm2

    @property
    def band_hz(self) -> tuple[float, float]:
        return float(self.frequencies_hz[0]), float(self.frequencies_hz[-1])

    def to_json(self) -> dict[str, Any]:
        """The JSON of ``dimacq solve --json``."""
        out = self.properties.to_json(self.reference_point_m)
        out.update(
            {
                "band_hz": list(self.band_hz),
                "n_lines": int(self.frequencies_hz.size),
                "method": self.method,
                "length_unit": self.length_unit,
                "known": dict(self.known),
                # the estimated parameters by their names (θ holds s = m·c where the mass is
                # unknown: that is the CG being estimated)
                "unknowns": [_UNKNOWN_NAME.get(u, u) for u in self.unknowns],
                "band_statistics": self.band_stats,
                "rank": self.rank,
                "n_unknowns": self.n_unknowns,
                "condition_number": self.condition_number,
                "response_condition_number": self.response_condition,
                "residual_rel": self.residual_rel,
                "responses_used": [c.as_dict() for c in self.responses],
                "inputs_used": [c.as_dict() for c in self.inputs],
                "load_cells_used": list(self.load_cells),
                "diagnostics": [d.as_dict() for d in self.diagnostics],
            }
        )
        out.update(self.extras)
        return out
