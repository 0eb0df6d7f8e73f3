"""Independent forward model: a rigid body on soft supports, each through a 6-DOF load cell.

The FRFs come from the body's equations of motion, not from the DIM equations run backwards.
Motion ``U = [u_O; θ]`` of the GCS origin O, mass matrix ``M`` about O
(:meth:`RigidBodyProperties.mass_matrix`), and for each support s at ``r_s`` with its load cell's
local-to-global rotation ``R_s`` and 6×6 stiffness ``k_s`` and damping ``c_s`` in the cell frame:

- motion of the cell origin ``U_s = G_s U`` with ``G_s = [[E, −[r_s]x], [0, E]]``;
- load the support exerts on the body at the cell origin, in the GCS
  ``W_s = −(K_s + iω C_s) U_s`` with ``K_s = B_s k_s B_sᵀ``, ``B_s = diag(R_s, R_s)``;
- the same load at O is ``G_sᵀ W_s`` (force unchanged, moment ``m + r_s × f``).

So ``(−ω² M + iω Σ G_sᵀ C_s G_s + Σ G_sᵀ K_s G_s) U = Φ f`` with input columns
``φ_j = [d_j; r_j × d_j]``. Outputs per unit input force:

- accelerometer along ``d_i`` at ``r_i``: ``q_i = d_iᵀ (ü_O + θ̈ × r_i)`` with ``Ü = −ω² U``;
- load cell s: ``B_sᵀ W_s`` (its local ``[f; m]`` about its origin), negated when the cell reports
  the load on the support (``sign = "on_support"``).

With no supports the body is free-free (``U = −Φ/(ω² M)``). Every output is vectorised over lines
and inputs (one batched solve of 6×6 systems per line).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from dimacq.model.frf import Channel, FrfData
from dimacq.model.properties import RigidBodyProperties
from dimacq.model.setup import Excitation, LoadCell, ResponseChannel, TestSetup

__all__ = [
    "ForwardModel",
    "Support",
    "calibration_mass",
    "cube",
    "six_triax_box",
    "soft_support_stiffness",
    "x38_like",
]

FloatArray = NDArray[np.float64]


def _skew(v: FloatArray) -> FloatArray:
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


@dataclass(frozen=True)
class Support:
    """A support path through a 6-DOF load cell.

    Attributes
    ----------
    node : int
        Load cell node (its outputs are directions 1–6 = Fx, Fy, Fz, Mx, My, Mz, cell frame).
    position_m : (3,)
        Cell origin in the GCS.
    rotation : (3, 3)
        Cell local-to-global rotation (columns = local axes in the GCS).
    stiffness : (6, 6)
        Support stiffness in the cell frame at its origin: N/m, N·m/rad.
    damping : (6, 6)
        Viscous damping in the cell frame: N·s/m, N·m·s/rad.
    sign : {"on_structure", "on_support"}
        What the cell reports.
    """

    node: int
    position_m: FloatArray
    rotation: FloatArray = field(default_factory=lambda: np.eye(3))
    stiffness: FloatArray = field(default_factory=lambda: np.zeros((6, 6)))
    damping: FloatArray = field(default_factory=lambda: np.zeros((6, 6)))
    sign: Literal["on_structure", "on_support"] = "on_structure"

    def G(self) -> FloatArray:
        g = np.eye(6)
        g[:3, 3:] = -_skew(np.asarray(self.position_m, float))
        return g

    def B(self) -> FloatArray:
        b = np.zeros((6, 6))
        b[:3, :3] = b[3:, 3:] = np.asarray(self.rotation, float)
        return b

    def load_cell(self) -> LoadCell:
        r = np.asarray(self.rotation, float)
        return LoadCell(
            node=self.node,
            position_m=tuple(float(x) for x in self.position_m),  # type: ignore[arg-type]
            rotation=tuple(tuple(float(x) for x in row) for row in r),  # type: ignore[arg-type]
            sign=self.sign,
        )


def soft_support_stiffness(
    mass_kg: float, bounce_hz: float, lateral_hz: float, rocking_stiffness_nm_per_rad: float
) -> FloatArray:
    """Diagonal 6×6 stiffness of a soft support (bungee / air ride) in its cell frame."""
    kz = mass_kg * (2 * np.pi * bounce_hz) ** 2
    kx = mass_kg * (2 * np.pi * lateral_hz) ** 2
    kr = rocking_stiffness_nm_per_rad
    return np.diag([kx, kx, kz, kr, kr, kr])


@dataclass(frozen=True)
class ForwardModel:
    """A rigid test article, its supports and its instrumentation (true geometry).

    Attributes
    ----------
    properties : RigidBodyProperties
        True mass, CG and inertia.
    setup : TestSetup
        True positions and directions of the responses and inputs; its load cells are the
        supports' cells.
    supports : tuple of Support
    """

    properties: RigidBodyProperties
    setup: TestSetup
    supports: tuple[Support, ...] = ()

    def dynamic_matrices(self) -> tuple[FloatArray, FloatArray, FloatArray]:
        """``M`` (about O), ``C`` and ``K`` (6×6 each)."""
        M = self.properties.mass_matrix(np.zeros(3))
        K = np.zeros((6, 6))
        C = np.zeros((6, 6))
        for s in self.supports:
            G, B = s.G(), s.B()
            K += G.T @ B @ s.stiffness @ B.T @ G
            C += G.T @ B @ s.damping @ B.T @ G
        return M, C, K

    def motion(self, frequencies_hz: FloatArray) -> NDArray[np.complex128]:
        """``U`` of O per unit input force, shape (n_lines, 6, n_inputs)."""
        w = 2 * np.pi * np.asarray(frequencies_hz, float)
        M, C, K = self.dynamic_matrices()
        pos, dirs = self.setup.input_positions, self.setup.input_directions
        phi = np.concatenate([dirs, np.cross(pos, dirs)], axis=1).T  # (6, n_in)
        Z = K[None] - (w**2)[:, None, None] * M[None] + 1j * w[:, None, None] * C[None]
        return np.linalg.solve(Z, np.broadcast_to(phi.astype(complex), (w.size, *phi.shape)))

    def frf(self, frequencies_hz: Sequence[float] | FloatArray) -> FrfData:
        """Accelerances of every response and reactions of every load cell, per unit input."""
        f = np.asarray(frequencies_hz, float)
        if np.any(f <= 0):
            raise ValueError("frequencies must be positive (a free body has no static response)")
        w = 2 * np.pi * f
        U = self.motion(f)
        acc = -(w**2)[:, None, None] * U
        pos, dirs = self.setup.response_positions, self.setup.response_directions
        psi = np.concatenate([dirs, np.cross(pos, dirs)], axis=1)
        H = [np.einsum("ck,lkj->lcj", psi, acc)]
        outputs = [Channel(c.node, c.direction) for c in self.setup.responses]
        kinds: list[Literal["acceleration", "reaction"]] = ["acceleration"] * len(outputs)
        for s in self.supports:
            G, B = s.G(), s.B()
            Kg = B @ s.stiffness @ B.T
            Cg = B @ s.damping @ B.T
            Zs = Kg[None] + 1j * w[:, None, None] * Cg[None]
            W = -np.einsum("lab,bc,lcj->laj", Zs, G, U)
            local = np.einsum("ba,lbj->laj", B, W)
            H.append(local * (1.0 if s.sign == "on_structure" else -1.0))
            outputs += [Channel(s.node, k) for k in range(1, 7)]
            kinds += ["reaction"] * 6
        inputs = tuple(Channel(e.node, e.direction) for e in self.setup.excitations)
        return FrfData(f, np.concatenate(H, axis=1), tuple(outputs), tuple(kinds), inputs)

    def suspension_frequencies_hz(self) -> FloatArray:
        """Undamped rigid-body mode frequencies on the supports (generalised eigenproblem)."""
        from scipy.linalg import eigh

        M, _, K = self.dynamic_matrices()
        lam = eigh(K, M, eigvals_only=True)
        return np.sqrt(np.clip(lam, 0.0, None)) / (2 * np.pi)


# ----------------------------------------------------------------------------------------------
# Builders for the reference cases
# ----------------------------------------------------------------------------------------------
def _triaxes(
    nodes: Sequence[int], positions: FloatArray, rotations: Sequence[FloatArray]
) -> list[ResponseChannel]:
    out = []
    for node, r, R in zip(nodes, positions, rotations, strict=True):
        for k in range(3):
            out.append(
                ResponseChannel(
                    node=int(node),
                    direction=k + 1,
                    position_m=tuple(float(x) for x in r),  # type: ignore[arg-type]
                    direction_gcs=tuple(float(x) for x in R[:, k]),  # type: ignore[arg-type]
                )
            )
    return out


def _inputs(
    nodes: Sequence[int], positions: FloatArray, directions: FloatArray
) -> list[Excitation]:
    out = []
    for node, r, d in zip(nodes, positions, directions, strict=True):
        d = np.asarray(d, float) / np.linalg.norm(d)
        out.append(
            Excitation(
                node=int(node),
                direction=1,
                position_m=tuple(float(x) for x in r),  # type: ignore[arg-type]
                direction_gcs=tuple(float(x) for x in d),  # type: ignore[arg-type]
            )
        )
    return out


#: Calibration mass of the thesis (§4.1.1), about the GCS origin used there (tensor elements).
CALIBRATION_MASS = RigidBodyProperties.from_about_point(
    18.175,
    np.array([0.035236, 0.000130, -0.085632]),
    np.array(
        [
            [0.218554, -0.000109, 0.078161],
            [-0.000109, 0.304172, 0.000218],
            [0.078161, 0.000218, 0.158154],
        ]
    ),
)


def calibration_mass(
    seed: int = 0,
    *,
    support: Literal["bungee", "air-ride", "free"] = "bungee",
    cell_angle_deg: float = 45.0,
    sensor_skew_deg: float = 25.0,
) -> ForwardModel:
    """The thesis calibration mass: 8 triaxes, 24 impacts (8 on each of three faces), 1 load cell.

    The block spans x ∈ [−0.10, 0.20], y ∈ [−0.15, 0.15], z ∈ [−0.20, 0.05] m; a triax sits near
    each corner, each turned by a random rotation of up to ``sensor_skew_deg``; the impacts are on
    the +x, +y and −z faces at scattered points, normal to the face. The load cell (turned
    ``cell_angle_deg`` about Z) is on the top face and carries the suspension (bungee: bounce 2 Hz,
    pendulum 0.7 Hz; air ride: load cell underneath, 1.5 Hz / 0.3 Hz).
    """
    rng = np.random.default_rng(seed)
    lo, hi = np.array([-0.10, -0.15, -0.20]), np.array([0.20, 0.15, 0.05])
    corners = np.array(
        [[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])]
    )
    positions = (
        corners + rng.uniform(-0.01, 0.01, corners.shape) - 0.02 * np.sign(corners - (lo + hi) / 2)
    )
    rots = [
        Rotation.from_rotvec(
            np.deg2rad(sensor_skew_deg) * rng.uniform(0, 1) * _unit(rng.normal(size=3))
        ).as_matrix()
        for _ in range(8)
    ]
    responses = _triaxes(range(1, 9), positions, rots)
    pts, dirs = [], []
    for axis, value, normal in (
        (0, hi[0], np.array([-1.0, 0, 0])),
        (1, hi[1], np.array([0, -1.0, 0])),
        (2, lo[2], np.array([0, 0, 1.0])),
    ):
        for _ in range(8):
            p = rng.uniform(lo, hi)
            p[axis] = value
            pts.append(p)
            d = normal + rng.normal(scale=0.05, size=3)  # hammer roughly normal to the face
            dirs.append(d / np.linalg.norm(d))
    inputs = _inputs(range(101, 125), np.array(pts), np.array(dirs))
    supports: tuple[Support, ...] = ()
    if support != "free":
        R = Rotation.from_euler("z", cell_angle_deg, degrees=True).as_matrix()
        m = CALIBRATION_MASS.mass_kg
        if support == "bungee":
            pos, k = np.array([0.05, 0.0, 0.05]), soft_support_stiffness(m, 2.0, 0.7, 5.0)
        else:
            pos, k = np.array([0.05, 0.0, -0.20]), soft_support_stiffness(m, 1.5, 0.3, 20.0)
        supports = (Support(501, pos, R, k, 0.02 * k / (2 * np.pi * 2.0)),)
    setup = TestSetup(
        name=f"calibration mass ({support})",
        responses=tuple(responses),
        excitations=tuple(inputs),
        load_cells=tuple(s.load_cell() for s in supports),
    )
    return ForwardModel(CALIBRATION_MASS, setup, supports)


def _unit(v: FloatArray) -> FloatArray:
    return v / np.linalg.norm(v)


def x38_like(seed: int = 0) -> ForwardModel:
    """An X-38-sized body: m = 8089 kg, CG ≈ (4.14, 0.004, 0.74) m, on 3 skewed load cells.

    21 triaxes over a 9 m × 3 m × 1.8 m hull, 22 inputs, three air-ride-like supports through load
    cells each turned about a tilted axis, so none is aligned with the GCS.
    """
    rng = np.random.default_rng(seed)
    cg = np.array([4.14, 0.004, 0.74])
    I_cg = np.array([[9.8e3, 150.0, -820.0], [150.0, 6.1e4, 35.0], [-820.0, 35.0, 6.4e4]])
    props = RigidBodyProperties(8089.0, cg, I_cg)
    lo, hi = np.array([0.0, -1.5, 0.0]), np.array([9.0, 1.5, 1.8])
    positions = rng.uniform(lo, hi, (21, 3))
    rots = [Rotation.random(random_state=int(rng.integers(1 << 31))).as_matrix() for _ in range(21)]
    responses = _triaxes(range(1001, 1022), positions, rots)
    in_pos = rng.uniform(lo, hi, (22, 3))
    in_dir = np.array([_unit(rng.normal(size=3)) for _ in range(22)])
    inputs = _inputs(range(2001, 2023), in_pos, in_dir)
    supports = []
    for node, pos, ang in (
        (3001, (1.2, -1.1, 0.0), (30, 8, -5)),
        (3002, (1.2, 1.1, 0.0), (-40, -6, 4)),
        (3003, (7.5, 0.0, 0.0), (75, 5, 9)),
    ):
        R = Rotation.from_euler("zyx", ang, degrees=True).as_matrix()
        k = soft_support_stiffness(8089.0 / 3, 1.8, 0.5, 2.0e4)
        supports.append(Support(node, np.array(pos), R, k, 0.03 * k / (2 * np.pi * 1.8)))
    setup = TestSetup(
        name="X-38-like vehicle",
        responses=tuple(responses),
        excitations=tuple(inputs),
        load_cells=tuple(s.load_cell() for s in supports),
    )
    return ForwardModel(props, setup, tuple(supports))


def cube(half_size_m: float, seed: int = 0) -> ForwardModel:
    """The thesis cube model (§2.2.1): 8 triaxes at (±H, ±H, ±H), free-free, calibration-mass
    properties about the origin.

    The thesis applies six unit forces and moments at the origin. A single-point input cannot be a
    pure moment, so the six inputs here are three unit forces at the origin along X, Y, Z and three
    at unit offsets (force along Y at +X, along Z at +Y, along X at +Z), whose 6-DOF vectors span
    the same space; triaxes are aligned with the GCS and rotated by a small seeded angle so each
    case also exercises skewed directions.
    """
    H = float(half_size_m)
    corners = np.array([[x, y, z] for x in (-H, H) for y in (-H, H) for z in (-H, H)])
    rng = np.random.default_rng(seed)
    rots = [
        Rotation.from_rotvec(np.deg2rad(10.0) * _unit(rng.normal(size=3))).as_matrix()
        for _ in range(8)
    ]
    responses = _triaxes(range(1, 9), corners, rots)
    in_pos = np.array([[0, 0, 0], [0, 0, 0], [0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], float)
    in_dir = np.array([[1, 0, 0], [0, 1, 0], [0, 0, 1], [0, 1, 0], [0, 0, 1], [1, 0, 0]], float)
    inputs = _inputs(range(101, 107), in_pos, in_dir)
    setup = TestSetup(
        name=f"cube H = {H:g} m", responses=tuple(responses), excitations=tuple(inputs)
    )
    return ForwardModel(CALIBRATION_MASS, setup, ())


def six_triax_box(setup: TestSetup) -> ForwardModel:
    """The bundled example (``config/examples/six_triax_setup.toml``): a 12.5 kg box hung on its
    load cells; the setup gives the true geometry."""
    props = RigidBodyProperties(
        12.5,
        np.array([0.012, -0.008, 0.135]),
        np.array([[0.31, 0.004, -0.012], [0.004, 0.42, 0.006], [-0.012, 0.006, 0.52]]),
    )
    supports = []
    for lc in setup.load_cells:
        k = soft_support_stiffness(12.5 / max(1, len(setup.load_cells)), 2.5, 0.8, 3.0)
        supports.append(
            Support(
                lc.node,
                np.asarray(lc.position_m),
                lc.rotation_matrix,
                k,
                0.02 * k / (2 * np.pi * 2.5),
                lc.sign,
            )
        )
    return ForwardModel(props, setup, tuple(supports))
