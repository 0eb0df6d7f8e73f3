"""FRF scaling to a known mass (:func:`scale_to_known_mass`).

FRF scaling (§3.2.2.1): ``γ`` such that the band mass of the solution with FRFs ``γ·H`` equals a
known mass, found with a bracketing root finder (Brent) since load-cell reactions make the mass a
nonlinear function of ``γ``.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from dimacq.errors import SetupError, SolverError
from dimacq.model.frf import FrfData
from dimacq.model.setup import TestSetup
from dimacq.pipeline.dim.assembly import assemble
from dimacq.pipeline.dim.result import DimResult
from dimacq.pipeline.dim.solver import solve_system

FloatArray = NDArray[np.float64]
ComplexArray = NDArray[np.complex128]


# --------------------------------------------------------------------------------------------
# FRF scaling to a known mass
# --------------------------------------------------------------------------------------------
def scale_to_known_mass(
    frf: FrfData,
    setup: TestSetup,
    mass_kg: float,
    *,
    band_hz: tuple[float, float] | None = None,
    kinds: tuple[Literal["acceleration", "reaction"], ...] = ("acceleration", "reaction"),
    length_unit: str | None = None,
    xtol: float = 1e-12,
) -> tuple[float, DimResult]:
    """Find ``γ`` with band mass of the solution on ``γ·H`` equal to ``mass_kg`` (thesis §3.2.2.1).

    ``kinds`` says which FRFs carry the scale error: both (a force transducer sensitivity error)
    or only the accelerations. With reactions present the mass is not ``m(1)/γ``; Brent's method
    on a bracket found by expanding around the reaction-free guess ``γ0 = m(1)/m_known``.

    Returns
    -------
    gamma : float
    result : DimResult
        The solution on the scaled FRFs (mass not imposed).
    """
    from scipy.optimize import brentq  # here: scipy.optimize costs start-up time to every solve

    if not mass_kg > 0:
        raise SetupError(f"known mass {mass_kg} kg must be positive")
    if band_hz is not None:
        frf = frf.band(*band_hz)

    def mass(gamma: float) -> float:
        sys_ = assemble(frf.scaled(gamma, kinds), setup, length_unit=length_unit)
        return solve_system(sys_, check_plausibility=False).mass_kg

    m1 = mass(1.0)
    g0 = m1 / mass_kg if m1 > 0 else 1.0
    lo, hi = g0 / 1.5, g0 * 1.5
    f_lo, f_hi = mass(lo) - mass_kg, mass(hi) - mass_kg
    for _ in range(40):
        if f_lo * f_hi < 0:
            break
        lo, hi = lo / 2.0, hi * 2.0
        f_lo, f_hi = mass(lo) - mass_kg, mass(hi) - mass_kg
    else:
        raise SolverError(
            f"no FRF scale factor between {lo:.3g} and {hi:.3g} gives a mass of {mass_kg} kg; "
            "check the known mass and the FRF units"
        )
    gamma = float(
        brentq(lambda g: mass(g) - mass_kg, lo, hi, xtol=xtol, rtol=4 * np.finfo(float).eps)
    )
    sys_ = assemble(frf.scaled(gamma, kinds), setup, length_unit=length_unit)
    result = solve_system(sys_)
    return gamma, replace(result, extras={**result.extras, "frf_scale_factor": gamma})
