"""The Dynamic Inertia Method solver (method.md §6–7, thesis Appendix A Eq. 32–35, §3.2).

The module moved whole into :mod:`dimacq.pipeline.dim.solver`; this package re-exports its names
where they were imported from before.
"""

from dimacq.pipeline.dim.solver import (
    _Q,
    _R,
    _REFINE_COND,
    Diagnostic,
    DimResult,
    DimSystem,
    _parameterisation,
    _solve_normal,
    _to_parameters,
    assemble,
    design_matrices,
    line_residuals,
    plausibility,
    scale_to_known_mass,
    solve,
    solve_joint,
    solve_system,
)

__all__ = [
    "_Q",
    "_R",
    "_REFINE_COND",
    "Diagnostic",
    "DimResult",
    "DimSystem",
    "_parameterisation",
    "_solve_normal",
    "_to_parameters",
    "assemble",
    "design_matrices",
    "line_residuals",
    "plausibility",
    "scale_to_known_mass",
    "solve",
    "solve_joint",
    "solve_system",
]
