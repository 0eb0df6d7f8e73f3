"""Physical plausibility checks of a DIM estimate (:func:`plausibility`): mass positive, inertia
about the CG positive definite, the triangle inequality of the principal moments
(``I1 + I2 ≥ I3``), the CG inside the convex hull of the measured points, the condition number
of the design matrix; each reported whatever its outcome as a
:class:`~dimacq.pipeline.dim.result.Diagnostic`.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from dimacq.model.properties import (
    RigidBodyProperties,
    principal_moments,
)
from dimacq.pipeline.dim.result import Diagnostic, DimResult

FloatArray = NDArray[np.float64]
ComplexArray = NDArray[np.complex128]


# --------------------------------------------------------------------------------------------
# Plausibility
# --------------------------------------------------------------------------------------------
def plausibility(
    props: RigidBodyProperties, hull_points_m: FloatArray, result: DimResult | None = None
) -> tuple[Diagnostic, ...]:
    """Physical checks on an estimate, all reported whatever their outcome.

    - ``mass_positive``: m > 0.
    - ``inertia_cg_positive_definite``: eigenvalues of I_CG > 0.
    - ``triangle_inequality``: each principal moment ≤ the sum of the other two (a real mass
      distribution satisfies ``I1 + I2 ≥ I3``).
    - ``cg_inside_hull``: the CG lies inside the convex hull of the measured points (responses,
      inputs, load cells); outside it is possible but suspicious.
    - ``condition``: condition number of the design matrix (warning above 1e6).
    """
    diags: list[Diagnostic] = []
    m = props.mass_kg
    diags.append(
        Diagnostic(
            "mass_positive",
            m > 0,
            f"mass {m:.6g} kg " + ("> 0" if m > 0 else "≤ 0: not physical"),
            "error",
        )
    )
    w, _ = principal_moments(props.inertia_cg_kgm2)
    pd = bool(np.all(w > 0))
    diags.append(
        Diagnostic(
            "inertia_cg_positive_definite",
            pd,
            "principal moments about the CG "
            + ", ".join(f"{x:.6g}" for x in w)
            + " kg·m²"
            + ("" if pd else ": not positive definite, not physical"),
            "error",
        )
    )
    tri = bool(w[0] + w[1] >= w[2] * (1 - 1e-9)) and pd
    diags.append(
        Diagnostic(
            "triangle_inequality",
            tri,
            f"I1 + I2 = {w[0] + w[1]:.6g} {'≥' if tri else '<'} I3 = {w[2]:.6g} kg·m²"
            + ("" if tri else ": no real mass distribution has these principal moments"),
            "error",
        )
    )
    diags.append(_hull_check(props.cg_m, hull_points_m))
    if result is not None:
        ok = result.condition_number < 1e6
        diags.append(
            Diagnostic(
                "condition",
                ok,
                f"condition number of the equilibrated design matrix {result.condition_number:.3g}"
                + ("" if ok else ": the estimate is sensitive to noise; add or spread the inputs"),
                "warning" if not ok else "info",
            )
        )
    return tuple(diags)


def _hull_check(cg: FloatArray, points: FloatArray) -> Diagnostic:
    """CG inside the convex hull of the points: on their side of every facet plane, within
    1e-9 of their extent (:func:`dimacq.pipeline.rotations.inside_hull`)."""
    from dimacq.pipeline.rotations import inside_hull

    pts = np.asarray(points, float)
    scale = float(np.ptp(pts, axis=0).max()) if pts.size else 0.0
    inside = inside_hull(cg, pts, 1e-9 * scale)
    if inside is None:
        return Diagnostic(
            "cg_inside_hull",
            True,
            "measured points are coplanar; CG hull check not possible",
            "info",
        )
    return Diagnostic(
        "cg_inside_hull",
        inside,
        "CG inside the hull of the measured points"
        if inside
        else "CG lies outside the hull of the measured points; check signs and geometry",
        "warning",
    )
