"""Rigid-body inertia properties: mass, centre of gravity and inertia tensor.

Sign convention (stated in every report): the inertia tensor holds **tensor elements**,
``I = ∫ (|r|² E − r rᵀ) dm``, so a product of inertia carries its tensor sign,
``Ixy = −∫ x y dm``. Parallel axis theorem from the CG ``c`` (relative to P) to P:
``I_P = I_CG + m (|c|² E − c cᵀ)``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from dimacq.errors import SetupError

__all__ = [
    "PRODUCT_SIGN_CONVENTION",
    "THESIS_CALIBRATION_MASS",
    "THESIS_CALIBRATION_MASS_INERTIA_ORIGIN_KGM2",
    "RigidBodyProperties",
    "inertia_to_vector",
    "parallel_axis_shift",
    "principal_moments",
    "skew",
    "vector_to_inertia",
]

PRODUCT_SIGN_CONVENTION = (
    "inertia tensor elements: I = ∫(|r|²E − r rᵀ)dm, products of inertia carry the tensor sign "
    "(Ixy = −∫xy dm)"
)

_I_INDEX = ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))


def skew(v: NDArray[Any]) -> NDArray[Any]:
    """Skew matrices ``[v]x`` with ``[v]x w = v × w``; ``v`` has shape (..., 3) → (..., 3, 3)."""
    v = np.asarray(v)
    out: NDArray[Any] = np.zeros(v.shape + (3,), dtype=v.dtype)
    out[..., 0, 1] = -v[..., 2]
    out[..., 0, 2] = v[..., 1]
    out[..., 1, 0] = v[..., 2]
    out[..., 1, 2] = -v[..., 0]
    out[..., 2, 0] = -v[..., 1]
    out[..., 2, 1] = v[..., 0]
    return out


def vector_to_inertia(v: NDArray[np.floating]) -> NDArray[np.float64]:
    """``[Ixx, Ixy, Ixz, Iyy, Iyz, Izz]`` (shape (..., 6)) → symmetric tensor (..., 3, 3)."""
    v = np.asarray(v, dtype=float)
    out = np.empty(v.shape[:-1] + (3, 3))
    for k, (i, j) in enumerate(_I_INDEX):
        out[..., i, j] = v[..., k]
        out[..., j, i] = v[..., k]
    return out


def inertia_to_vector(tensor: NDArray[np.floating]) -> NDArray[np.float64]:
    """Symmetric tensor (..., 3, 3) → ``[Ixx, Ixy, Ixz, Iyy, Iyz, Izz]`` (..., 6)."""
    t = np.asarray(tensor, dtype=float)
    return np.stack([0.5 * (t[..., i, j] + t[..., j, i]) for i, j in _I_INDEX], axis=-1)


def parallel_axis_shift(mass_kg: float, offset_m: NDArray[np.floating]) -> NDArray[np.float64]:
    """``m (|c|² E − c cᵀ)``: add to ``I_CG`` to get the tensor about a point at ``−c`` from the CG."""
    c = np.asarray(offset_m, dtype=float)
    return mass_kg * (np.dot(c, c) * np.eye(3) - np.outer(c, c))


def principal_moments(
    tensor: NDArray[np.floating],
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Principal moments (ascending) and axes (columns, right-handed) of a symmetric tensor."""
    w, v = np.linalg.eigh(0.5 * (np.asarray(tensor, float) + np.asarray(tensor, float).T))
    if np.linalg.det(v) < 0:
        v[:, 2] = -v[:, 2]
    # Make each axis point into the positive half of its dominant component, for stable reports.
    for k in range(3):
        i = int(np.argmax(np.abs(v[:, k])))
        if v[i, k] < 0:
            v[:, k] = -v[:, k]
    if np.linalg.det(v) < 0:
        v[:, 2] = -v[:, 2]
    return w, v


@dataclass(frozen=True)
class RigidBodyProperties:
    """Mass, CG and inertia of a rigid body.

    Attributes
    ----------
    mass_kg : float
    cg_m : ndarray, shape (3,)
        CG in the GCS, metres.
    inertia_cg_kgm2 : ndarray, shape (3, 3)
        Inertia tensor about the CG (tensor elements), kg·m².
    """

    mass_kg: float
    cg_m: NDArray[np.float64]
    inertia_cg_kgm2: NDArray[np.float64]

    def __post_init__(self) -> None:
        object.__setattr__(self, "cg_m", np.asarray(self.cg_m, dtype=float).reshape(3))
        t = np.asarray(self.inertia_cg_kgm2, dtype=float).reshape(3, 3)
        if not np.allclose(t, t.T, rtol=0, atol=1e-12 * max(1.0, float(np.abs(t).max()))):
            raise SetupError(
                "inertia_cg_kgm2 must be symmetric; give tensor elements with Ixy = Iyx"
            )
        object.__setattr__(self, "inertia_cg_kgm2", 0.5 * (t + t.T))

    @classmethod
    def from_about_point(
        cls,
        mass_kg: float,
        cg_m: NDArray[np.floating],
        inertia_p_kgm2: NDArray[np.floating],
        point_m: NDArray[np.floating] | None = None,
    ) -> RigidBodyProperties:
        """From the inertia tensor about a point P: ``I_CG = I_P − m(|c|²E − c cᵀ)``, c = CG − P."""
        point = np.zeros(3) if point_m is None else np.asarray(point_m, float)
        c = np.asarray(cg_m, float) - point
        return cls(
            mass_kg,
            np.asarray(cg_m, float),
            np.asarray(inertia_p_kgm2, float) - parallel_axis_shift(mass_kg, c),
        )

    def inertia_about(self, point_m: NDArray[np.floating]) -> NDArray[np.float64]:
        """Inertia tensor about ``point_m`` (GCS, metres)."""
        return self.inertia_cg_kgm2 + parallel_axis_shift(
            self.mass_kg, self.cg_m - np.asarray(point_m, float)
        )

    def mass_matrix(self, point_m: NDArray[np.floating]) -> NDArray[np.float64]:
        """6×6 rigid-body mass matrix about P for motion ``[u_P; θ]``.

        ``[[m E, −m[c]x], [m[c]x, I_P]]`` with ``c = CG − P``, from ``F = m a − m c×α``,
        ``M = m c×a + I_P α``.
        """
        c = self.cg_m - np.asarray(point_m, float)
        cx = skew(c)
        m = self.mass_kg
        out = np.zeros((6, 6))
        out[:3, :3] = m * np.eye(3)
        out[:3, 3:] = -m * cx
        out[3:, :3] = m * cx
        out[3:, 3:] = self.inertia_about(point_m)
        return out

    def parameter_vector(self, point_m: NDArray[np.floating]) -> NDArray[np.float64]:
        """The ten DIM parameters about P: ``[m, cx, cy, cz, Ixx, Ixy, Ixz, Iyy, Iyz, Izz]`` (c rel. P)."""
        c = self.cg_m - np.asarray(point_m, float)
        return np.concatenate([[self.mass_kg], c, inertia_to_vector(self.inertia_about(point_m))])

    def to_json(self, point_m: NDArray[np.floating] | None = None) -> dict[str, Any]:
        """The keys of ``dimacq solve --json`` (CG in the GCS; inertia about P and about the CG)."""
        point_m = np.zeros(3) if point_m is None else np.asarray(point_m, float)
        w, v = principal_moments(self.inertia_cg_kgm2)
        return {
            "mass_kg": float(self.mass_kg),
            "cg_m": self.cg_m.tolist(),
            "inertia_p_kgm2": self.inertia_about(point_m).tolist(),
            "inertia_cg_kgm2": self.inertia_cg_kgm2.tolist(),
            "principal_moments_kgm2": w.tolist(),
            "principal_axes": v.tolist(),
            "reference_point_m": np.asarray(point_m, float).tolist(),
            "product_sign_convention": PRODUCT_SIGN_CONVENTION,
        }

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> RigidBodyProperties:
        """Read the keys written by :meth:`to_json` (``inertia_cg_kgm2`` or ``inertia_p_kgm2``)."""
        try:
            m = float(data["mass_kg"])
            cg = np.asarray(data["cg_m"], float)
        except KeyError as err:
            raise SetupError(f"properties JSON lacks key {err}; give mass_kg and cg_m") from err
        if "inertia_cg_kgm2" in data:
            return cls(m, cg, np.asarray(data["inertia_cg_kgm2"], float))
        if "inertia_p_kgm2" in data:
            p = np.asarray(data.get("reference_point_m", [0.0, 0.0, 0.0]), float)
            return cls.from_about_point(m, cg, np.asarray(data["inertia_p_kgm2"], float), p)
        raise SetupError(
            "properties JSON lacks inertia_cg_kgm2 and inertia_p_kgm2; give one of them"
        )


#: The thesis's calibration mass (Lazor 2004, §4.1.1; method.md §9): inertia tensor elements about
#: the GCS origin used there, kg·m². The one copy of these reference values in the project.
THESIS_CALIBRATION_MASS_INERTIA_ORIGIN_KGM2 = np.array(
    [
        [0.218554, -0.000109, 0.078161],
        [-0.000109, 0.304172, 0.000218],
        [0.078161, 0.000218, 0.158154],
    ]
)
THESIS_CALIBRATION_MASS = RigidBodyProperties.from_about_point(
    18.175,
    np.array([0.035236, 0.000130, -0.085632]),
    THESIS_CALIBRATION_MASS_INERTIA_ORIGIN_KGM2,
)
