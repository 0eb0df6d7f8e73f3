"""Output-error (maximum-likelihood) DIM with geometry self-calibration and residual flexibility.

Why
---
The equation-error DIM (:mod:`dimacq.pipeline.dim`) puts the condensed accelerations ``K = Ψ⁺H`` in
its design matrix and treats them, and the geometry behind ``Ψ`` and ``φ``, as exact. Noise on
``H`` then shrinks the estimate (errors in variables), and the stated geometry sets a floor on the
accuracy (``estimation-notes.md``). Here the measured FRFs are *predicted* from the parameters and
compared where the noise is.

Modules
-------
- :mod:`.model`: the prediction ``Ĥ = ψᵀ M⁻¹ (φ + R) + G b``, the rigid mass matrix of the ten
  properties and its derivatives, how the properties follow the gauge modes, the reduced
  (sufficient) statistics and the stacked residual with its analytic Jacobian.
- :mod:`.noise`: the noise model from the data: FRF noise from the third difference, the
  reactions' noise and its compensation, the line weights, the smooth projection of the
  reactions.
- :mod:`.fit`: the gauge constraint (inner constraint on the modes the data do not identify),
  Levenberg–Marquardt, the residual and cost on every line.
- :mod:`.checks`: the tests on a fit (does the geometry need moving, is the refinement
  adequate), the input-clustered robust covariance, the effective lines of a misfit.
- :mod:`.report`: the options and the result, the reported corrections, residual terms and
  refined setup.
- :mod:`.solver`: :func:`solve_output_error`, which composes them.

The names below are importable from this package as they were from the module it replaces.
"""

from dimacq.pipeline.output_error.checks import ADEQUACY_P, effective_lines
from dimacq.pipeline.output_error.model import Problem, gauge_property_jacobian, mass_matrix
from dimacq.pipeline.output_error.noise import (
    LINE_NOISE_HALF_WIDTH,
    PRECISION_FLOOR_REL,
    REACTION_SNR_LOW,
    SMOOTH_FIT_RATIO,
    estimate_noise,
)
from dimacq.pipeline.output_error.report import OutputErrorOptions, OutputErrorResult
from dimacq.pipeline.output_error.solver import solve_output_error

__all__ = [
    "ADEQUACY_P",
    "LINE_NOISE_HALF_WIDTH",
    "PRECISION_FLOOR_REL",
    "REACTION_SNR_LOW",
    "SMOOTH_FIT_RATIO",
    "OutputErrorOptions",
    "OutputErrorResult",
    "Problem",
    "effective_lines",
    "estimate_noise",
    "gauge_property_jacobian",
    "mass_matrix",
    "solve_output_error",
]
