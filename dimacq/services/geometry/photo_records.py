"""The photo chain's results: the issues named per photo, the adjusted geometry, and the records
it gives a setup (the same orientation and line-of-action records a digitized setup uses)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray
from pydantic import ValidationError

from dimacq.errors import SetupError
from dimacq.io.tags_file import TagsFile
from dimacq.model.setup import TestSetup
from dimacq.pipeline.photogrammetry.bundle import (
    BodyEstimate,
    BodyModel,
    BundleResult,
)
from dimacq.services.geometry.geometry_trust import geometry_uncertainty
from dimacq.services.geometry.records import LineOfAction, Orientation

FloatArray = NDArray[np.float64]


# ------------------------------------------------------------------------------ results
@dataclass(frozen=True)
class PhotoIssue:
    """A photo (or a body) that could not help fully: what is wrong and the fix."""

    photo: str
    severity: str  # "skipped" (not used) or "warn" (used)
    problem: str
    fix: str

    def to_json(self) -> dict[str, str]:
        return {
            "photo": self.photo,
            "severity": self.severity,
            "problem": self.problem,
            "fix": self.fix,
        }

    def __str__(self) -> str:
        return f"{self.photo}: {self.problem}; {self.fix}"


@dataclass(frozen=True)
class PhotoGeometry:
    """What the photographs give: the records, the adjustment and every issue met."""

    orientations: list[Orientation]
    lines_of_action: list[LineOfAction]
    bodies: list[BodyEstimate]
    bundle: BundleResult
    photos: list[str]
    used: list[str]
    issues: list[PhotoIssue]
    unfixed: list[str]
    intrinsics_source: str
    setup: TestSetup | None = None
    counts: dict[str, int] = field(default_factory=dict)

    @property
    def verdict(self) -> str:
        return "fail" if self.unfixed else ("warn" if self.issues else "ok")

    def to_json(self) -> dict[str, Any]:
        from dimacq.io.setup_file import dump_setup_dict

        b = self.bundle
        return {
            "schema_version": 1,
            "source": "photographs",
            "verdict": self.verdict,
            "orientations": [o.to_json() for o in self.orientations],
            "lines_of_action": [a.to_json() for a in self.lines_of_action],
            "references": [
                {
                    "name": e.name,
                    "position_m": [float(v) for v in e.position_m],
                    "position_std_m": [float(v) for v in e.position_std_m],
                }
                for e in self.bodies
                if e.kind in ("reference", "scalebar")
            ],
            "unfixed": list(self.unfixed),
            "issues": [i.to_json() for i in self.issues],
            "photos": {"found": len(self.photos), "used": len(self.used), "names": self.used},
            "camera": {
                "intrinsics": b.intrinsics.to_json(),
                "intrinsics_std": None if b.intrinsics_std is None else b.intrinsics_std.tolist(),
                "source": self.intrinsics_source,
            },
            "adjustment": {
                "sigma_px": b.sigma_px,
                "rms_px": b.rms_px,
                "corners": b.n_corners,
                "parameters": b.n_parameters,
                "evaluations": b.nfev,
                "condition": b.condition,
                "rejected": [
                    {"photo": self.used[p] if p < len(self.used) else p, "tag": t, "rms_px": r}
                    for p, t, r in b.rejected
                ],
                "edge_bias_px": b.edge_bias_px,
                "edge_bias_std_px": b.edge_bias_std_px,
                "tag_placements": [
                    {
                        "tag": tp.tag_id,
                        "body": tp.body,
                        "shift_mm": [1e3 * float(v) for v in tp.shift_m],
                        "shift_std_mm": [1e3 * float(v) for v in tp.shift_std_m],
                        "angle_deg": [float(np.degrees(v)) for v in tp.angle_rad],
                        "angle_std_deg": [float(np.degrees(v)) for v in tp.angle_std_rad],
                        "z": tp.z,
                        "freed": tp.freed,
                        "views": tp.n_views,
                    }
                    for tp in b.placements
                ],
            },
            "setup": None if self.setup is None else dump_setup_dict(self.setup),
        }


def bundle_records(
    bundle: BundleResult, models: list[BodyModel], tags: TagsFile, residual_m: float
) -> tuple[list[Orientation], list[LineOfAction]]:
    """The adjusted bodies as the digitizing chain's records. An adjustment that placed the
    tags on their bodies (:attr:`BundleResult.placements`) holds their placement in each body's
    covariance; one made without it adds ``σ_place/√k`` over the ``k`` tags the body has. A
    body whose corners agree worse than the set's (``residual_factor f > 1``) has the corners'
    part of its covariance scaled by ``f²`` (its own a-posteriori variance: what its views
    show, not the set's), ``f² (Σ − P) + P`` with ``P`` the priors' part."""
    ori, loas = [], []
    for est, model in zip(bundle.bodies, models, strict=True):
        inflate = max(1.0, est.residual_factor) ** 2
        prior = est.prior_covariance
        cov = inflate * (est.covariance - prior) + prior
        if bundle.placements:
            cov_r, cov_p = cov[:3, :3], cov[3:, 3:]
        else:
            k = max(len(model.tags), 1)
            pa = np.radians(tags.placement_angle_deg) / np.sqrt(k)
            pp = tags.placement_position_m / np.sqrt(k)
            cov_r = cov[:3, :3] + pa**2 * np.eye(3)
            cov_p = cov[3:, 3:] + pp**2 * np.eye(3)
        pos_std = float(np.sqrt(np.max(np.linalg.eigvalsh(cov_p))))
        if est.kind == "triax" and est.node is not None:
            axis_std = np.degrees(np.sqrt(np.diag(est.rotation.T @ cov_r @ est.rotation)))
            ori.append(
                Orientation(
                    node=est.node,
                    rotation=np.asarray(est.rotation).tolist(),
                    origin_m=[float(v) for v in est.position_m],
                    method="photos",
                    rods=[],
                    n_points=est.n_corners,
                    residual_rms_m=float(residual_m),
                    angle_std_deg=[float(v) for v in axis_std],
                    uncertainty_deg=float(np.degrees(np.sqrt(np.trace(cov_r)))),
                    jig_uncertainty_deg=float(
                        np.degrees(np.sqrt(np.trace(est.covariance[:3, :3])))
                    ),
                    registration_uncertainty_deg=None,
                    origin_std_m=pos_std,
                )
            )
        elif est.kind == "input" and est.node is not None:
            d = -est.rotation[:, 2]
            proj = np.eye(3) - np.outer(d, d)
            ang = float(np.degrees(np.sqrt(np.trace(proj @ cov_r @ proj))))
            fit = float(np.degrees(np.sqrt(np.trace(proj @ est.covariance[:3, :3] @ proj))))
            loas.append(
                LineOfAction(
                    node=est.node,
                    direction=[float(v) for v in d],
                    point_m=[float(v) for v in est.position_m],
                    method="photos",
                    perpendicular_rms_m=float(residual_m),
                    angle_std_deg=ang,
                    fit_angle_std_deg=fit,
                    registration_uncertainty_deg=None,
                    point_std_m=pos_std,
                )
            )
    return ori, loas


def apply_to_setup(setup: TestSetup, result: PhotoGeometry) -> TestSetup:
    """``setup`` with each photographed triax's channels and each input at the photographed
    geometry (a channel ``±k`` along ``±`` column ``k`` of the triax's rotation), and the
    geometry uncertainty the records state
    (:func:`dimacq.services.geometry.geometry_trust.geometry_uncertainty`), as a digitized setup."""
    ori = {o.node: o for o in result.orientations}
    loas = {a.node: a for a in result.lines_of_action}
    responses = []
    for ch in setup.responses:
        o = ori.get(ch.node)
        if o is None:
            responses.append(ch)
            continue
        r = np.asarray(o.rotation, float)
        sign = 1.0 if ch.direction > 0 else -1.0
        col = sign * r[:, abs(ch.direction) - 1]
        responses.append(
            ch.model_copy(
                update={
                    "position_m": tuple(o.origin_m),
                    "direction_gcs": tuple(float(v) for v in col / np.linalg.norm(col)),
                }
            )
        )
    excitations = []
    for e in setup.excitations:
        a = loas.get(e.node)
        if a is None:
            excitations.append(e)
            continue
        d = np.asarray(a.direction, float)
        excitations.append(
            e.model_copy(
                update={
                    "position_m": tuple(a.point_m),
                    "direction_gcs": tuple(float(v) for v in d / np.linalg.norm(d)),
                }
            )
        )
    geo = geometry_uncertainty(
        [o.to_json() for o in result.orientations if o.node in {c.node for c in setup.responses}],
        [
            a.to_json()
            for a in result.lines_of_action
            if a.node in {e.node for e in setup.excitations}
        ],
        [],
        point_accuracy_m=0.0,
        registration_limit_m=None,
    )
    try:
        return TestSetup.model_validate(
            {
                **setup.model_dump(),
                "responses": [c.model_dump() for c in responses],
                "excitations": [e.model_dump() for e in excitations],
                "geometry_uncertainty": geo.model_dump(),
            }
        )
    except ValidationError as err:
        raise SetupError(f"setup from photographs: {err}") from err
