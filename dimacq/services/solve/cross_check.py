"""The second estimator beside the DIM on every solve: the mass-line fit.

:func:`cross_check` runs :func:`dimacq.pipeline.cross_check.mass_line_from_frf` on the data the
DIM used (its band, the channels and inputs its selection and refinement kept, the stated
geometry of the setup given to the solver — not the refined one) and compares the two answers:
for each of mass, CG, inertia about P and the principal moments,

    z = (x_cross − x_DIM) / sqrt(se_cross² + se_DIM²),    agrees ⇔ |z| ≤ 1.96,

i.e. the difference lies within the combined 95 % interval. Both intervals hold the stated
geometry uncertainty, which moves the two estimates alike: the combination is conservative (a
disagreement is real). Inertia is compared about the reference point P, where the DIM states its
intervals; the values about the CG are reported too. The verdict turns a disagreement into a
``warn`` (:func:`dimacq.services.solve.verdict.cross_check_checks`). Without geometry samples
(``dimacq solve --no-geometry-uncertainty``) the comparison holds the noise only, and a stated
geometry that is off makes the two disagree.

What the comparison can see (README, "Cross-check"): the mass line does not refine the geometry
and its unstructured fit is about three times as sensitive to the stated input geometry as the
DIM, so it flags a DIM error only beyond about twice that spread (calibration mass, default
priors: ~1 % on mass, 3–4 % on principal moments); with geometry stated to a tenth of the
defaults, a triax turned 3° that the selection keeps moves the equation-error DIM far enough
(z −3.3).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Any

import numpy as np

from dimacq.errors import SetupError, SolverError
from dimacq.model.frf import FrfData
from dimacq.model.properties import principal_moments, vector_to_inertia
from dimacq.model.setup import TestSetup
from dimacq.pipeline._special import chi2_sf
from dimacq.pipeline.cross_check import QUANTITIES, MassLineFit, mass_line_from_frf
from dimacq.pipeline.dim import DimResult
from dimacq.pipeline.uncertainty import Uncertainty

__all__ = ["METHOD", "N_COMPARED", "Z95", "Z_FAMILY", "CrossCheck", "cross_check"]

log = logging.getLogger(__name__)

#: Two-sided 95 % normal quantile: the combined-interval agreement limit on |z|.
Z95 = 1.959963984540054
#: Items compared: mass, 3 CG coordinates, 6 inertia elements about P, 3 principal moments.
N_COMPARED = 13
#: Family-wise 95 % limit on the largest |z| of the :data:`N_COMPARED` items (Bonferroni,
#: ``Φ⁻¹(1 − 0.025/13)``): with 13 items at 95 % each, about one solve in two would show one
#: item outside its interval by chance if the z were independent standard normals. The verdict
#: warns beyond this limit; ``agrees`` states each item at 95 %.
Z_FAMILY = 2.8905
METHOD = "mass-line"
_I_NAMES = ("Ixx", "Ixy", "Ixz", "Iyy", "Iyz", "Izz")


@dataclass(frozen=True, eq=False)
class CrossCheck:
    """The mass-line estimate beside the DIM's, and whether they agree.

    Attributes
    ----------
    fit : MassLineFit, optional
        None when the fit could not be made (``error`` says why).
    z : dict
        ``mass`` (float), ``cg`` (3), ``inertia`` (``Ixx``..``Izz`` about P), ``principal``
        (3): ``(cross − DIM)/sqrt(se_cross² + se_DIM²)``.
    agrees : dict
        Same layout, ``|z| ≤ 1.96``; ``all`` for every item.
    dim_se : dict
        Same layout: the DIM's standard errors used in ``z`` (:func:`_dim_se`).
    band_hz : (lo, hi)
    error : str, optional
    """

    fit: MassLineFit | None
    z: dict[str, Any]
    agrees: dict[str, Any]
    dim_se: dict[str, Any]
    band_hz: tuple[float, float]
    error: str | None = None

    @property
    def all_agree(self) -> bool:
        return bool(self.agrees.get("all", True))

    @property
    def max_abs_z(self) -> float:
        """The largest |z| over the compared items (0 without a fit)."""
        if self.fit is None:
            return 0.0
        z = self.z
        vals = [z["mass"], *z["cg"], *z["inertia"].values(), *z["principal"]]
        return float(max(abs(float(x)) for x in vals))

    @property
    def family_wise_limit(self) -> float:
        return Z_FAMILY

    @property
    def family_wise_agree(self) -> bool:
        """No item beyond the family-wise limit :data:`Z_FAMILY` (what the verdict checks)."""
        return self.max_abs_z <= Z_FAMILY

    def disagreements(self) -> list[tuple[str, float]]:
        """Names and z-scores of the items that disagree, worst first."""
        out: list[tuple[str, float]] = []
        if self.fit is None:
            return out
        if not self.agrees["mass"]:
            out.append(("mass", float(self.z["mass"])))
        for k, a in zip(("cx", "cy", "cz"), self.agrees["cg"], strict=True):
            if not a:
                out.append((k, float(self.z["cg"][("cx", "cy", "cz").index(k)])))
        for k in _I_NAMES:
            if not self.agrees["inertia"][k]:
                out.append((f"{k} (about P)", float(self.z["inertia"][k])))
        for i, a in enumerate(self.agrees["principal"]):
            if not a:
                out.append((f"I{i + 1}", float(self.z["principal"][i])))
        out.sort(key=lambda t: -abs(t[1]))
        return out

    def to_json(self) -> dict[str, Any]:
        """The ``cross_check`` object of ``dimacq solve --json``."""
        if self.fit is None:
            return {
                "method": METHOD,
                "error": self.error,
                "agrees": {"all": True},
                "family_wise_agree": True,
            }
        f = self.fit
        v, se = f.values, f.se

        def ci(i: int) -> list[float]:
            return [float(v[i] - Z95 * se[i]), float(v[i] + Z95 * se[i])]

        ip = vector_to_inertia(v[4:10])
        icg = vector_to_inertia(v[10:16])
        cmp = _comparison_se(f)
        return {
            "method": METHOD,
            "equation": "A(ω) ≈ Ψ M⁻¹ (Φ + R(ω)), M⁻¹ symmetric (21 entries), weighted least "
            "squares over the band; m = tr(M11)/3, m·c = vee(skew M21), I_P = M22",
            "mass_kg": float(v[0]),
            "cg_m": v[1:4].tolist(),
            "inertia_p_kgm2": ip.tolist(),
            "inertia_cg_kgm2": icg.tolist(),
            "principal_moments_kgm2": v[16:19].tolist(),
            "reference_point_m": f.reference_point_m.tolist(),
            "standard_error": dict(zip(QUANTITIES, se.tolist(), strict=True)),
            "standard_error_sources": {
                "noise": dict(zip(QUANTITIES, f.se_noise.tolist(), strict=True)),
                "inputs": dict(zip(QUANTITIES, f.se_inputs.tolist(), strict=True)),
                "geometry": dict(zip(QUANTITIES, f.se_geometry.tolist(), strict=True)),
            },
            "ci95": {
                "mass_kg": ci(0),
                "cg_m": [ci(i) for i in (1, 2, 3)],
                "inertia_p_kgm2": {k: ci(4 + i) for i, k in enumerate(_I_NAMES)},
                "inertia_cg_kgm2": {k: ci(10 + i) for i, k in enumerate(_I_NAMES)},
                "principal_moments_kgm2": [ci(i) for i in (16, 17, 18)],
            },
            "comparison_standard_error": {
                "mass": float(cmp[0]),
                "cg": cmp[1:4].tolist(),
                "inertia": {k: float(cmp[4 + i]) for i, k in enumerate(_I_NAMES)},
                "principal": cmp[16:19].tolist(),
            },
            "dim_standard_error": self.dim_se,
            "z": self.z,
            "agrees": self.agrees,
            "agreement_rule": "|cross − DIM| ≤ 1.96·sqrt(se_cross² + se_DIM²) per item "
            "(comparison standard errors: what moves the two alike left out); inertia compared "
            "about the reference point P, where the DIM states its intervals",
            "max_abs_z": self.max_abs_z,
            "family_wise_z_limit": Z_FAMILY,
            "family_wise_agree": self.family_wise_agree,
            "rigid_structure": {
                "rel": f.structure_rel,
                "chi2": f.structure_chi2,
                "dof": 11,
                "p_value": _chi2_sf(f.structure_chi2, 11),
            },
            "residual_rel": f.residual_rel,
            "condition_number": f.condition_number,
            "band_hz": list(self.band_hz),
            "n_lines": f.n_lines,
            "n_channels": f.n_channels,
            "n_inputs": f.n_inputs,
            "geometry_samples": f.geometry_samples,
            "geometry": "stated (the setup given to the solver; not the DIM's refinement)",
        }


def _chi2_sf(x: float, dof: int) -> float:
    """χ² survival function, ``scipy.stats.chi2.sf(x, dof)`` (it is
    ``scipy.special.chdtrc(dof, x)``) to ~1e-13, without importing scipy (0.2 s of start-up)."""

    return chi2_sf(x, dof) if np.isfinite(x) else 0.0


def _comparison_se(fit: MassLineFit) -> np.ndarray:
    """The mass-line fit's standard errors for the comparison with the DIM: its own noise /
    input spread, plus the geometry spread of its *difference* from the DIM on the same stated
    geometry (the stated geometry moves both alike; the DIM's own interval holds its share and
    what its refinement corrects). Its full geometry spread when no such difference was made."""
    own = np.maximum(fit.se_noise, fit.se_inputs)
    geo = fit.se_geometry if fit.se_geometry_difference is None else fit.se_geometry_difference
    out: np.ndarray = np.sqrt(own**2 + geo**2)
    return out


def _dim_se(unc: Uncertainty, force_rel: float) -> dict[str, Any]:
    """The DIM's standard errors for the comparison.

    ``sqrt(se_inputs² + se_lines² + se_geometry² − (σ_f·x)²)``: its noise / input and line
    shares and its geometry share without the force-sensor calibration ``σ_f·|x|`` of the mass
    and inertias (a hammer error scales every FRF and moves both estimators alike), never below
    the noise share. The delete-one-sensor-node jackknife (``se_responses``, equation-error
    solves only) is left out: it measures how far one sensor node moves the DIM, which is the
    error the cross-check is there to see — a single mis-mounted node moves the DIM by about
    the jackknife's own spread, so with it in the interval |z| stays below ~1 whatever the
    error.
    """
    prm = unc.parameters

    def comb(u: Any, scaled: bool) -> float:
        geo2 = float(u.se_geometry) ** 2
        if scaled:
            geo2 = max(geo2 - (force_rel * float(u.value)) ** 2, 0.0)
        return float(np.sqrt(float(u.se_inputs) ** 2 + float(u.se_lines) ** 2 + geo2))

    def se(name: str, scaled: bool) -> float:
        u = prm.get(name)
        return 0.0 if u is None else comb(u, scaled)

    pr = [comb(u, True) for u in unc.principal] if unc.principal else [0.0] * 3
    return {
        "mass": se("m", True),
        "cg": [se(k, False) for k in ("cx", "cy", "cz")],
        "inertia": {k: se(k, True) for k in _I_NAMES},
        "principal": pr,
    }


def _kept(
    data: FrfData, setup: TestSetup, result: DimResult, weights: np.ndarray, keep_in: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The channel weights and input mask the DIM's answer used (selection, then refinement)."""
    from dimacq.pipeline.selection._common import response_geometry

    w = np.asarray(weights, float).copy()
    keep = np.asarray(keep_in, dtype=bool).copy()
    gone = result.extras.get("excluded_by_refinement") or {}
    nodes_out = {int(n) for n in gone.get("response_nodes", [])}
    if nodes_out:
        geo = response_geometry(data, setup)
        w[np.isin(geo.nodes, list(nodes_out))] = 0.0
    ins_out = {(int(c["node"]), int(c["direction"])) for c in gone.get("inputs", [])}
    for j, ch in enumerate(data.inputs):
        if (ch.node, ch.direction) in ins_out:
            keep[j] = False
    return w, keep


def cross_check(
    data: FrfData,
    setup: TestSetup,
    result: DimResult,
    unc: Uncertainty,
    weights: np.ndarray,
    keep_in: np.ndarray,
    *,
    geometry_samples: int = 200,
) -> CrossCheck:
    """The mass-line estimate on the DIM's data and its agreement with the DIM (module doc).

    ``data`` is the band the DIM solved, ``weights`` the selection's channel weights (one per
    acceleration output) and ``keep_in`` its input mask; items the refinement excluded
    (``result.extras["excluded_by_refinement"]``) are left out here too.
    """
    band = result.band_hz
    dim_se = _dim_se(unc, float(setup.transducer_uncertainty.force_sensitivity_rel))
    w, keep = _kept(data, setup, result, weights, keep_in)
    try:
        fit = mass_line_from_frf(
            data,
            setup,
            response_weights=w,
            input_keep=keep,
            reference_point_m=result.reference_point_m,
            geometry=geometry_samples > 0,
            n_samples=max(int(geometry_samples), 0),
            dim_companion=True,
            known=result.known,
            length_unit=result.length_unit,
        )
    except (SolverError, SetupError) as err:
        log.warning("cross-check not made: %s", err)
        return CrossCheck(None, {}, {"all": True}, dim_se, band, error=str(err))

    v = fit.values
    se = _comparison_se(fit)
    ip_dim = result.parameters[4:10]
    pm_dim = principal_moments(result.inertia_cg_kgm2)[0]

    def z(x_cc: float, x_dim: float, s_cc: float, s_dim: float) -> float:
        s = float(np.hypot(s_cc, s_dim))
        d = float(x_cc - x_dim)
        if s > 0:
            return d / s
        scale = max(abs(x_cc), abs(x_dim), 1e-300)
        return 0.0 if abs(d) <= 1e-9 * scale else float(np.sign(d) * np.inf)

    zs: dict[str, Any] = {
        "mass": z(v[0], result.mass_kg, se[0], dim_se["mass"]),
        "cg": [z(v[1 + k], result.cg_m[k], se[1 + k], dim_se["cg"][k]) for k in range(3)],
        "inertia": {
            k: z(v[4 + i], ip_dim[i], se[4 + i], dim_se["inertia"][k])
            for i, k in enumerate(_I_NAMES)
        },
        "principal": [
            z(v[16 + k], pm_dim[k], se[16 + k], dim_se["principal"][k]) for k in range(3)
        ],
    }
    agrees: dict[str, Any] = {
        "mass": bool(abs(zs["mass"]) <= Z95),
        "cg": [bool(abs(x) <= Z95) for x in zs["cg"]],
        "inertia": {k: bool(abs(x) <= Z95) for k, x in zs["inertia"].items()},
        "principal": [bool(abs(x) <= Z95) for x in zs["principal"]],
    }
    agrees["all"] = bool(
        agrees["mass"]
        and all(agrees["cg"])
        and all(agrees["inertia"].values())
        and all(agrees["principal"])
    )
    return CrossCheck(fit, zs, agrees, dim_se, band)
