"""Output-error (maximum-likelihood) DIM with geometry self-calibration and residual flexibility.

The module moved whole into :mod:`dimacq.pipeline.output_error.solver`; this package re-exports
its names where they were imported from before.
"""

from dimacq.pipeline.output_error.solver import (
    REACTION_SNR_LOW,
    OutputErrorOptions,
    OutputErrorResult,
    _Problem,
    estimate_noise,
    gauge_property_jacobian,
    mass_matrix,
    solve_output_error,
)

__all__ = [
    "REACTION_SNR_LOW",
    "OutputErrorOptions",
    "OutputErrorResult",
    "_Problem",
    "estimate_noise",
    "gauge_property_jacobian",
    "mass_matrix",
    "solve_output_error",
]
