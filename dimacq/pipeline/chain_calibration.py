"""Calibration of the measurement chain on a reference mass (the "mass calibration" of modal
testing, ISO 7626-2 §8): what no redundancy in a DIM test can find.

Every FRF of a DIM test is a ratio to the hammer's force. The FRFs are scaled by the sensitivities
of the calibration certificates; a hammer whose certificate value ``s_c`` is off its true value
``s`` gives the measured force ``F_m = F s / s_c``, so every acceleration FRF and every load-cell
reaction FRF is measured as

    H_m = κ H,        κ = s_c / s        (the chain factor; accelerometer errors aside).

The DIM equations ``M (κ H) = 1 + κ R/F`` (per unit input force) then give

    m = M / κ + (1 − 1/κ) (R/F) / H ≈ M / κ,

the second term being the reaction force's share of the inertia force, small above the suspension
(``|R/F| ≤ 10⁻²`` over a rigid-body band: ``O(10⁻⁴)`` for a chain off by 1 %). Mass and inertia
come out ``1/κ``-scaled whatever the data, and the test's own redundancy cannot see it
(:class:`~dimacq.model.setup.TransducerUncertainty`). A body of known mass ``m_ref`` (weighed)
measured with the same hammer and sensors gives it:

    γ = m_meas / m_ref  (= 1/κ),     u(γ)/γ = √[(u(m_meas)/m_meas)² + (u(m_ref)/m_ref)²],

with ``u(m_meas)`` the measurement's standard uncertainty *without* the hammer certificate term
(lines, inputs, sensors, geometry, the accelerometer certificates). Every later test multiplies
its FRFs by ``γ`` (:meth:`~dimacq.model.frf.FrfData.scaled`, accelerations and reactions) and
carries ``u(γ)/γ`` in place of the hammer certificate's uncertainty.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from dimacq.errors import DataError, SetupError

__all__ = ["MAX_CHAIN_DEVIATION", "ChainCalibration", "chain_calibration"]

#: A chain off by more than this (relative) is not a calibration error but a wrong sensitivity,
#: unit or cabling: refused.
MAX_CHAIN_DEVIATION = 0.10


@dataclass(frozen=True)
class ChainCalibration:
    """The chain factor ``γ`` (module docstring) with its evidence.

    Attributes
    ----------
    factor : float
        ``γ``: multiply the FRFs (accelerations and reactions) of later tests by it.
    u_rel : float
        Relative standard uncertainty of ``γ`` (1σ).
    reference_mass_kg, reference_mass_u_kg : float
        The weighed mass of the reference body and its standard uncertainty, kg.
    measured_mass_kg, measured_mass_u_kg : float
        The DIM mass of the reference body and its standard uncertainty without the hammer
        certificate term, kg.
    source : str
        Where it was measured (e.g. ``"solution 3 (FRF set 2)"``).
    """

    factor: float
    u_rel: float
    reference_mass_kg: float
    reference_mass_u_kg: float
    measured_mass_kg: float
    measured_mass_u_kg: float
    source: str = ""

    def to_json(self) -> dict[str, Any]:
        return {
            "factor": self.factor,
            "u_rel": self.u_rel,
            "reference_mass_kg": self.reference_mass_kg,
            "reference_mass_u_kg": self.reference_mass_u_kg,
            "measured_mass_kg": self.measured_mass_kg,
            "measured_mass_u_kg": self.measured_mass_u_kg,
            "source": self.source,
        }

    @classmethod
    def from_json(
        cls, doc: Mapping[str, Any], where: str = "chain_calibration"
    ) -> ChainCalibration:
        """Read :meth:`to_json`'s document back, checked."""
        try:
            out = cls(
                factor=float(doc["factor"]),
                u_rel=float(doc["u_rel"]),
                reference_mass_kg=float(doc["reference_mass_kg"]),
                reference_mass_u_kg=float(doc["reference_mass_u_kg"]),
                measured_mass_kg=float(doc["measured_mass_kg"]),
                measured_mass_u_kg=float(doc["measured_mass_u_kg"]),
                source=str(doc.get("source", "")),
            )
        except (KeyError, TypeError, ValueError) as err:
            raise SetupError(
                f"{where}: not a chain calibration ({err}); give the 'chain_calibration' object "
                "of a reference-mass solve (factor, u_rel, reference_mass_kg, ...)"
            ) from err
        if not (math.isfinite(out.factor) and abs(out.factor - 1.0) <= MAX_CHAIN_DEVIATION):
            raise SetupError(
                f"{where}: factor {out.factor} is not within ±{MAX_CHAIN_DEVIATION:.0%} of 1"
            )
        if not (math.isfinite(out.u_rel) and 0.0 <= out.u_rel < 0.5):
            raise SetupError(f"{where}: u_rel {out.u_rel} must be finite, ≥ 0 and < 0.5")
        return out


def chain_calibration(
    measured_mass_kg: float,
    measured_mass_u_kg: float,
    reference_mass_kg: float,
    reference_mass_u_kg: float,
    *,
    source: str = "",
) -> ChainCalibration:
    """``γ = m_meas / m_ref`` and its relative uncertainty (module docstring).

    Raises
    ------
    SetupError
        A reference mass that is not positive and finite, or a negative uncertainty.
    DataError
        A chain off by more than :data:`MAX_CHAIN_DEVIATION` (a wrong sensitivity, unit or
        cabling, not a calibration error) or a measured mass that is not positive.
    """
    for name, v in (("reference mass", reference_mass_kg),):
        if not (math.isfinite(v) and v > 0):
            raise SetupError(f"{name} {v} kg: give the weighed mass in kg (> 0)")
    for name, v in (
        ("reference mass uncertainty", reference_mass_u_kg),
        ("measured mass uncertainty", measured_mass_u_kg),
    ):
        if not (math.isfinite(v) and v >= 0):
            raise SetupError(f"{name} {v} kg must be finite and ≥ 0 (a standard uncertainty)")
    if not (math.isfinite(measured_mass_kg) and measured_mass_kg > 0):
        raise DataError(
            f"the reference body's measured mass is {measured_mass_kg} kg: no chain factor from "
            "a non-physical solution; check the channels and the band"
        )
    gamma = measured_mass_kg / reference_mass_kg
    if abs(gamma - 1.0) > MAX_CHAIN_DEVIATION:
        raise DataError(
            f"the reference body measures {measured_mass_kg:.4g} kg against its weighed "
            f"{reference_mass_kg:.4g} kg ({100 * (gamma - 1):+.1f} %): a chain off by more than "
            f"{MAX_CHAIN_DEVIATION:.0%} is a wrong sensitivity, unit or cabling, not a calibration "
            "error; check the rig file's sensitivities"
        )
    u_rel = math.hypot(
        measured_mass_u_kg / measured_mass_kg, reference_mass_u_kg / reference_mass_kg
    )
    return ChainCalibration(
        factor=gamma,
        u_rel=u_rel,
        reference_mass_kg=reference_mass_kg,
        reference_mass_u_kg=reference_mass_u_kg,
        measured_mass_kg=measured_mass_kg,
        measured_mass_u_kg=measured_mass_u_kg,
        source=source,
    )
