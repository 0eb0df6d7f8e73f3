"""The Dynamic Inertia Method solver (method.md §6–7, thesis Appendix A Eq. 32–35, §3.2).

The equation-error DIM: the linearised equations of motion of a rigid body, linear in its ten
inertia properties, assembled from the FRFs and the setup and solved by least squares per
frequency line and jointly over a band.

Modules
-------
- :mod:`.assembly`: from FRFs and setup to the condensed motion ``K`` and the summed forces ``F``
  at P in the working length unit, and the design matrices ``A(a, α)`` (Eq. 32–35).
- :mod:`.solver`: known properties eliminated (``x = T θ + x0``, Eq. 17–22), the normal
  equations per line and over the band, their solution and refinement; the joint solve from
  band-summed Gram matrices (many input weightings, many geometries).
- :mod:`.result`: the solution with its evidence, and its JSON.
- :mod:`.checks`: the physical plausibility checks of an estimate.
- :mod:`.scaling`: the FRF scale factor that gives a known mass (§3.2.2.1).

The names below are importable from this package as they were from the module it replaces.
"""

from dimacq.pipeline.dim.assembly import DimSystem, assemble, cell_reactions, design_matrices
from dimacq.pipeline.dim.checks import plausibility
from dimacq.pipeline.dim.result import Diagnostic, DimResult
from dimacq.pipeline.dim.scaling import scale_to_known_mass
from dimacq.pipeline.dim.solver import (
    input_band_sums,
    line_residuals,
    solve,
    solve_gram_sums,
    solve_joint,
    solve_joint_many,
    solve_system,
)

__all__ = [
    "Diagnostic",
    "DimResult",
    "DimSystem",
    "assemble",
    "cell_reactions",
    "design_matrices",
    "input_band_sums",
    "line_residuals",
    "plausibility",
    "scale_to_known_mass",
    "solve",
    "solve_gram_sums",
    "solve_joint",
    "solve_joint_many",
    "solve_system",
]
