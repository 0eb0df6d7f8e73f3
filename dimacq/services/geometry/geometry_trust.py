"""Trust limits of the digitized geometry: a registration judged against its limit, and the
stated uncertainty of what is digitized through it (triax orientations, lines of action, the
setup's :class:`~dimacq.model.setup.GeometryUncertainty`).

The limit of one reference node's residual is ``5 sqrt(σ_point² + σ_reference²)`` (the array's
``[accuracy] point_m`` and the ``reference_node_accuracy_m`` setting); the map's uncertainty
(``σ̂``, ``N⁻¹``) is propagated into the orientation and line-of-action uncertainties.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from dimacq.errors import DataError
from dimacq.model.setup import GeometryUncertainty
from dimacq.pipeline.digitizing.registration import (
    Registration,
    check_registration,
    registration_limit_m,
)
from dimacq.services.geometry.digitizer_config import ArrayConfig

__all__ = [
    "geometry_uncertainty",
    "judge_registration",
    "line_of_action_uncertainty",
    "orientation_uncertainty",
    "registration_from_body",
    "registration_limit",
]


def registration_limit(
    cfg: ArrayConfig, reference_accuracy_m: float, limit_m: float | None = None
) -> float:
    """The residual limit of one reference node, m: ``limit_m`` if given, else
    ``5 sqrt(σ_point² + σ_reference²)`` (:func:`~dimacq.pipeline.digitizing.registration.
    registration_limit_m`) with the array's ``[accuracy] point_m``."""
    if limit_m is not None:
        return float(limit_m)
    return registration_limit_m(cfg.accuracy.point_m, reference_accuracy_m)


def judge_registration(
    points_array_m: ArrayLike,
    points_global_m: ArrayLike,
    labels: Sequence[str],
    *,
    limit_m: float,
    prior_sigma_m: float,
    method: str = "rigid",
) -> tuple[Registration, dict[str, Any]]:
    """Register, check against ``limit_m`` and refuse a ``fail``.

    ``prior_sigma_m`` is ``sqrt(σ_point² + σ_reference²)``: the per-coordinate node error the
    uncertainty of the map is propagated with when the residuals show less (few redundant
    coordinates estimate ``σ`` poorly), ``σ_used = max(σ̂, prior)``.

    Returns
    -------
    (Registration, dict)
        The fit and its JSON record (the keys of ``POST /api/digitizer/registrations``:
        ``matrix``, ``offset_m``, ``method``, ``scale``, ``labels``, ``residual_norm_m``,
        ``rms_m``, ``planarity``, ``verdict``, ``reasons``, ``limit_m``, ``worst_node``,
        ``worst_residual_m``, ``suspect``, ``leave_one_out_rms_m``, ``sigma_m``,
        ``sigma_used_m``, ``rotation_uncertainty_deg``, ``centroid_m``, ``rotation_normal_inv``).

    Raises
    ------
    DataError
        A node's residual is above the limit: the message names the worst node, its residual
        in mm, the limit, and the node to re-digitize when leaving it out fixes the fit.
    """
    reg, chk = check_registration(
        points_array_m, points_global_m, list(labels), limit_m, method=method
    )
    if chk.verdict == "fail":
        raise DataError(
            f"registration refused: {chk.reasons[0]} (residuals: "
            + ", ".join(
                f"{lab} {1e3 * r:.2f} mm"
                for lab, r in zip(chk.labels, reg.residual_norm_m, strict=True)
            )
            + "); the patch stays unregistered"
        )
    sigma_used = float(np.nanmax([reg.sigma_m, prior_sigma_m]))
    body: dict[str, Any] = {
        "matrix": np.asarray(reg.matrix).tolist(),
        "offset_m": [float(v) for v in reg.offset_m],
        "method": reg.method,
        "scale": float(reg.scale),
        "labels": list(chk.labels),
        "residual_norm_m": [float(v) for v in reg.residual_norm_m],
        "rms_m": float(reg.rms_m),
        "planarity": float(reg.planarity),
        "verdict": chk.verdict,
        "reasons": list(chk.reasons),
        "limit_m": chk.limit_m,
        "worst_node": chk.worst_label,
        "worst_residual_m": chk.worst_residual_m,
        "suspect": chk.suspect,
        "leave_one_out_rms_m": [None if np.isnan(v) else float(v) for v in chk.leave_one_out_rms_m],
        "sigma_m": None if np.isnan(reg.sigma_m) else float(reg.sigma_m),
        "sigma_used_m": sigma_used,
        "rotation_uncertainty_deg": reg.rotation_uncertainty_deg(sigma_used),
        "centroid_m": [float(v) for v in reg.centroid_global_m],
        "rotation_normal_inv": np.asarray(reg.rotation_normal_inv).tolist(),
    }
    return reg, body


def registration_from_body(body: Mapping[str, Any]) -> Registration:
    """The :class:`Registration` of a stored record (residual vectors are not stored: zeros)."""
    n = len(body["residual_norm_m"])
    ninv = body.get("rotation_normal_inv")
    return Registration(
        matrix=np.asarray(body["matrix"], dtype=float),
        offset_m=np.asarray(body["offset_m"], dtype=float),
        method=str(body["method"]),
        scale=float(body["scale"]),
        residuals_m=np.zeros((n, 3)),
        residual_norm_m=np.asarray(body["residual_norm_m"], dtype=float),
        rms_m=float(body["rms_m"]),
        planarity=float(body["planarity"]),
        sigma_m=float(body.get("sigma_used_m") or np.nan),
        centroid_global_m=np.asarray(body.get("centroid_m", (0.0, 0.0, 0.0)), dtype=float),
        rotation_normal_inv=np.asarray(
            ninv if ninv is not None else np.full((3, 3), np.nan), dtype=float
        ),
    )


def _reg_terms(
    registrations: Sequence[Mapping[str, Any]], point_m: ArrayLike
) -> tuple[float, float]:
    """Worst rotation (deg, RMS over axes) and per-coordinate position 1σ (m) the registrations
    the points came through add, with ``σ_used``; a record without the uncertainty terms
    (registered by an older dimacq) counts with its RMS residual as the position term."""
    rot, pos = 0.0, 0.0
    for body in registrations:
        if body.get("rotation_normal_inv") is None:
            pos = max(pos, float(body.get("rms_m", 0.0)))
            continue
        reg = registration_from_body(body)
        rot = max(rot, reg.rotation_uncertainty_deg())
        pos = max(pos, float(np.max(reg.position_std_m(np.asarray(point_m, float)))))
    return rot, pos


def orientation_uncertainty(
    jig_uncertainty_deg: float,
    jig_residual_rms_m: float,
    n_points: int,
    origin_m: ArrayLike,
    registrations: Sequence[Mapping[str, Any]],
    point_accuracy_m: float,
) -> dict[str, float]:
    """Orientation and position uncertainty of a triax digitized through ``registrations``.

    The jig fit and the registration are independent (different points), so their small
    rotations add in quadrature: ``u = sqrt(u_jig² + u_reg²)`` (RMS misorientation, degrees, the
    root-sum-square over the three axes). The origin's per-coordinate 1σ is
    ``sqrt(σ_fit² + σ_reg,pos²)`` with ``σ_fit = max(σ̂_jig, σ_point)/sqrt(n)`` (the mean of the
    ``n`` indentations fixes the origin) and ``σ_reg,pos`` the map's position term at the origin.

    Returns
    -------
    dict
        ``uncertainty_deg`` (total), ``jig_uncertainty_deg``, ``registration_uncertainty_deg``,
        ``origin_std_m``.
    """
    reg_rot, reg_pos = _reg_terms(registrations, origin_m)
    sigma_jig = max(jig_residual_rms_m / np.sqrt(3.0), point_accuracy_m)
    fit_pos = sigma_jig / np.sqrt(max(n_points, 1))
    return {
        "uncertainty_deg": float(np.hypot(jig_uncertainty_deg, reg_rot)),
        "jig_uncertainty_deg": float(jig_uncertainty_deg),
        "registration_uncertainty_deg": float(reg_rot),
        "origin_std_m": float(np.hypot(fit_pos, reg_pos)),
    }


def line_of_action_uncertainty(
    fit_angle_std_deg: float,
    point_m: ArrayLike,
    registrations: Sequence[Mapping[str, Any]],
    point_accuracy_m: float,
) -> dict[str, float]:
    """Direction and input-point uncertainty of a line of action (see
    :func:`orientation_uncertainty`): ``angle_std_deg = sqrt(fit² + (u_reg·sqrt(2/3))²)`` —
    the registration's RMS rotation ``u_reg`` has two of its three axes normal to the line —
    and the input point ``sqrt(σ_point² + σ_reg,pos²)`` per coordinate."""
    reg_rot, reg_pos = _reg_terms(registrations, point_m)
    fit = float(fit_angle_std_deg) if np.isfinite(fit_angle_std_deg) else 0.0
    return {
        "angle_std_deg": float(np.hypot(fit, reg_rot * np.sqrt(2.0 / 3.0))),
        "fit_angle_std_deg": float(fit_angle_std_deg),
        "registration_uncertainty_deg": float(reg_rot),
        "point_std_m": float(np.hypot(point_accuracy_m, reg_pos)),
    }


def geometry_uncertainty(
    orientations: Sequence[Mapping[str, Any]],
    lines_of_action: Sequence[Mapping[str, Any]],
    registrations: Sequence[Mapping[str, Any]],
    *,
    point_accuracy_m: float,
    registration_limit_m: float | None,
) -> GeometryUncertainty:
    """The stated 1σ of a setup built from digitized geometry.

    ``GeometryUncertainty`` holds one value per kind and axis, so each is the largest over the
    items (conservative: the intervals then cover the worst-fitted sensor):

    - ``sensor_orientation_deg`` = max over triaxes of ``uncertainty_deg / sqrt(3)`` (jig fit ⊕
      registration, per axis);
    - ``sensor_position_m`` = max ``origin_std_m``;
    - ``line_of_action_deg`` = max ``angle_std_deg / sqrt(2)`` (per axis normal to the line);
    - ``input_position_m`` = max ``point_std_m``;
    - ``registration_rms_m`` = the largest RMS residual of the registrations used,
      ``registration_limit_m`` the limit they were accepted against.

    Items stored without these keys (fitted by an older dimacq) count with the array's point
    accuracy and their fit's own angle.
    """
    ori_deg = [float(o.get("uncertainty_deg", 0.0)) / np.sqrt(3.0) for o in orientations]
    ori_pos = [float(o.get("origin_std_m", point_accuracy_m)) for o in orientations]
    loa_deg = []
    for a in lines_of_action:
        v = float(a.get("angle_std_deg", float("nan")))
        loa_deg.append(v / np.sqrt(2.0) if np.isfinite(v) else 0.0)
    loa_pos = [float(a.get("point_std_m", point_accuracy_m)) for a in lines_of_action]
    rms = [float(r["rms_m"]) for r in registrations if r.get("rms_m") is not None]
    return GeometryUncertainty(
        sensor_position_m=max(ori_pos, default=point_accuracy_m),
        sensor_orientation_deg=max(ori_deg, default=0.0),
        input_position_m=max(loa_pos, default=point_accuracy_m),
        line_of_action_deg=max(loa_deg, default=0.0),
        registration_rms_m=max(rms) if rms else None,
        registration_limit_m=registration_limit_m,
        source="digitized",
    )
