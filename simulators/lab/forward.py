"""Independent forward model: a body on soft supports, each through a 6-DOF load cell.

The FRFs come from the body's equations of motion, not from the DIM equations run backwards.

Rigid body
----------
Motion ``U = [u_O; θ]`` of the GCS origin O, mass matrix ``M`` about O
(:meth:`RigidBodyProperties.mass_matrix`), and for each support s at ``r_s`` with its load cell's
local-to-global rotation ``R_s`` and 6×6 stiffness ``k_s`` and damping ``c_s`` in the cell frame:

- motion of the cell origin ``U_s = G_s U`` with ``G_s = [[E, −[r_s]x], [0, E]]``;
- load the support exerts on the body at the cell origin, in the GCS
  ``W_s = −(K_s + iω C_s) U_s`` with ``K_s = B_s k_s B_sᵀ``, ``B_s = diag(R_s, R_s)``;
- the same load at O is ``G_sᵀ W_s`` (force unchanged, moment ``m + r_s × f``).

So ``(−ω² M + iω Σ G_sᵀ C_s G_s + Σ G_sᵀ K_s G_s) U = Φ f`` with input columns
``φ_j = [d_j; r_j × d_j]`` (a general 6-DOF load ``[f; m]`` at ``r``: ``[f; r × f + m]``).

Flexible modes (optional)
-------------------------
A modal model of the free-free structure adds coordinates ``η`` (one per elastic mode r,
mass-normalised, orthogonal to the rigid-body motion by assumption, as free-free modes are):
the displacement of node n is ``[u_n; θ_n] = G_n U + Ψ_n η`` with ``Ψ_n`` (6, n_modes) the mode
shapes at that node (GCS translations and rotations per unit modal coordinate, 1/√kg). With
``z = [U; η]``:

- ``M_z = diag(M, I)``, ``K_z = diag(0, ω_r²) + Σ_s A_sᵀ K_s A_s``,
  ``C_z = diag(0, 2 ζ_r ω_r) + Σ_s A_sᵀ C_s A_s`` with ``A_s = [G_s, Ψ_s]`` (6, 6 + n_modes);
- generalised input ``q_j = [φ_j; Ψ_jᵀ [d_j; 0]]``;
- ``(K_z − ω² M_z + iω C_z) z = q f``.

Outputs per unit input force:

- accelerometer along ``d_i`` at ``r_i``: ``q_i = −ω² (d_iᵀ (u_O + θ × r_i) + d_iᵀ Ψ_i,u η)``;
- load cell s: ``−(k_s + iω c_s) B_sᵀ A_s z`` (its local ``[f; m]`` about its origin, the load
  the support exerts on the structure), negated when the cell reports the load on the support
  (``sign = "on_support"``).

Without modes this is exactly the rigid model. With no supports the body is free-free
(``U = −Φ/(ω² M)``). Every output is vectorised over lines and inputs (one batched solve of
small systems per line). Gravity preload (pendulum stiffness) is not modelled: a support is a
linear spring and dashpot at its cell, which is what the DIM equations assume of the supports
(they measure every force through the cells).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Literal

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from dimacq.errors import SetupError
from dimacq.model.frf import Channel, FrfData
from dimacq.model.properties import THESIS_CALIBRATION_MASS, RigidBodyProperties
from dimacq.model.setup import (
    Excitation,
    GeometryUncertainty,
    LoadCell,
    ResponseChannel,
    TestSetup,
)
from dimacq.pipeline.rigid_body import skew

__all__ = [
    "CALIBRATION_MASS",
    "REFERENCE_BLOCK",
    "X38_PROPERTIES",
    "FlexibleMode",
    "ForwardModel",
    "Support",
    "beam_bending_mode",
    "calibration_mass",
    "cube",
    "cube_unit_loads",
    "fixed_support_stiffness",
    "modal_damping",
    "reference_block",
    "reference_block_drawing",
    "six_triax_box",
    "soft_support_stiffness",
    "subsystem_mode",
    "x38_like",
]

FloatArray = NDArray[np.float64]
ComplexArray = NDArray[np.complex128]


def _G(position_m: FloatArray) -> FloatArray:
    """``[[E, −[r]x], [0, E]]``: motion of a point at ``r`` from ``[u_O; θ]``."""
    g = np.eye(6)
    g[:3, 3:] = -skew(np.asarray(position_m, float))
    return g


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
        return _G(self.position_m)

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
    """Diagonal 6×6 stiffness of a soft support (bungee / air ride) in its cell frame.

    ``k_z = m (2π f_bounce)²``, ``k_x = k_y = m (2π f_lateral)²`` (N/m) for the mass ``m`` the
    support carries; the same rocking/torsion stiffness about the three cell axes (N·m/rad).
    """
    kz = mass_kg * (2 * np.pi * bounce_hz) ** 2
    kx = mass_kg * (2 * np.pi * lateral_hz) ** 2
    kr = rocking_stiffness_nm_per_rad
    return np.diag([kx, kx, kz, kr, kr, kr])


def fixed_support_stiffness(
    axial_n_per_m: float = 5.0e8,
    shear_n_per_m: float = 2.0e8,
    bending_nm_per_rad: float = 3.0e5,
    torsion_nm_per_rad: float = 2.0e5,
) -> FloatArray:
    """6×6 stiffness of a 6-DOF load cell bolted between the structure and the floor
    (thesis Appendix B, "calibration mass fixed to floor"): the cell's own stiffness is the
    support. Diagonal in the cell frame: shear x, y; axial z; bending about x, y; torsion z."""
    s, a, b, t = shear_n_per_m, axial_n_per_m, bending_nm_per_rad, torsion_nm_per_rad
    return np.diag([s, s, a, b, b, t])


def modal_damping(
    stiffness: FloatArray,
    properties: RigidBodyProperties,
    position_m: FloatArray,
    damping_ratio: float,
) -> FloatArray:
    """Diagonal damping giving each support direction about ``damping_ratio`` of critical:
    ``c_kk = 2 ζ sqrt(k_kk m_k)`` with ``m_k`` the body's mass (translations) or its largest
    moment of inertia about the support point (rotations). Bungee and air springs damp a few
    per cent of critical in every suspension mode; stiffness-proportional damping would leave
    the pendulum modes nearly undamped."""
    i_max = float(np.linalg.eigvalsh(properties.inertia_about(np.asarray(position_m, float))).max())
    m_eff = np.array([properties.mass_kg] * 3 + [i_max] * 3)
    return np.diag(2 * damping_ratio * np.sqrt(np.clip(np.diag(stiffness), 0, None) * m_eff))


@dataclass(frozen=True, eq=False)
class FlexibleMode:
    """One mass-normalised elastic mode of the free-free structure.

    Attributes
    ----------
    name : str
    frequency_hz : float
        Free-free natural frequency ``ω_r / 2π``.
    damping_ratio : float
        Modal damping ratio ``ζ_r``.
    shapes : mapping node -> ndarray (6,)
        ``[u; θ]`` of the node in the GCS per unit modal coordinate (m/√kg, rad/√kg); nodes not
        listed do not move in this mode.
    """

    name: str
    frequency_hz: float
    damping_ratio: float
    shapes: Mapping[int, FloatArray]

    def __post_init__(self) -> None:
        if not (self.frequency_hz > 0 and np.isfinite(self.frequency_hz)):
            raise SetupError(
                f"mode {self.name!r}: frequency_hz = {self.frequency_hz}; give a positive frequency"
            )
        if not 0 <= self.damping_ratio < 1:
            raise SetupError(
                f"mode {self.name!r}: damping_ratio = {self.damping_ratio}; give 0 ≤ ζ < 1"
            )

    def shape_at(self, node: int) -> FloatArray:
        v = self.shapes.get(int(node))
        return np.zeros(6) if v is None else np.asarray(v, float).reshape(6)


@dataclass(frozen=True)
class ForwardModel:
    """A test article, its supports and its instrumentation (true geometry).

    Attributes
    ----------
    properties : RigidBodyProperties
        True mass, CG and inertia (of the whole free-free structure).
    setup : TestSetup
        True positions and directions of the responses and inputs; its load cells are the
        supports' cells.
    supports : tuple of Support
    modes : tuple of FlexibleMode
        Elastic modes (empty: a rigid body).
    """

    properties: RigidBodyProperties
    setup: TestSetup
    supports: tuple[Support, ...] = ()
    modes: tuple[FlexibleMode, ...] = ()

    # -- structure -------------------------------------------------------------------------
    @property
    def n_dof(self) -> int:
        return 6 + len(self.modes)

    def rigid(self) -> ForwardModel:
        """The same article without its elastic modes."""
        return replace(self, modes=())

    def _shapes(self, node: int) -> FloatArray:
        """``Ψ_n``, shape (6, n_modes)."""
        if not self.modes:
            return np.zeros((6, 0))
        return np.stack([m.shape_at(node) for m in self.modes], axis=1)

    def _A(self, node: int, position_m: FloatArray) -> FloatArray:
        """``[G_n, Ψ_n]``, shape (6, n_dof): GCS ``[u; θ]`` of a node from ``z``."""
        return np.concatenate([_G(position_m), self._shapes(node)], axis=1)

    def dynamic_matrices(self) -> tuple[FloatArray, FloatArray, FloatArray]:
        """``M``, ``C`` and ``K`` (n_dof × n_dof; the rigid part about O)."""
        n = self.n_dof
        M = np.zeros((n, n))
        K = np.zeros((n, n))
        C = np.zeros((n, n))
        M[:6, :6] = self.properties.mass_matrix(np.zeros(3))
        for r, mode in enumerate(self.modes, start=6):
            w = 2 * np.pi * mode.frequency_hz
            M[r, r] = 1.0
            K[r, r] = w**2
            C[r, r] = 2 * mode.damping_ratio * w
        for s in self.supports:
            A, B = self._A(s.node, s.position_m), s.B()
            K += A.T @ B @ s.stiffness @ B.T @ A
            C += A.T @ B @ s.damping @ B.T @ A
        return M, C, K

    def natural_frequencies_hz(self) -> FloatArray:
        """Undamped natural frequencies of the whole model on its supports, ascending."""
        from scipy.linalg import eigh

        M, _, K = self.dynamic_matrices()
        lam = eigh(K, M, eigvals_only=True)
        return np.sqrt(np.clip(lam, 0.0, None)) / (2 * np.pi)

    def suspension_frequencies_hz(self) -> FloatArray:
        """Undamped rigid-body mode frequencies on the supports (generalised eigenproblem)."""
        return self.rigid().natural_frequencies_hz()

    # -- loads -----------------------------------------------------------------------------
    def generalised_loads(
        self,
        nodes: Sequence[int],
        positions_m: FloatArray,
        forces: FloatArray,
        moments: FloatArray | None = None,
    ) -> FloatArray:
        """Generalised forces ``q_j = A_jᵀ [f_j; m_j]`` of 6-DOF loads, shape (n_dof, n_loads).

        Parameters
        ----------
        nodes : sequence of int, length n
            Node of each load (selects its mode shapes).
        positions_m : (n, 3)
        forces : (n, 3)
            Force of each load in the GCS (N per unit input).
        moments : (n, 3), optional
            Pure moment (couple) of each load in the GCS (N·m per unit input).
        """
        pos = np.asarray(positions_m, float).reshape(-1, 3)
        f = np.asarray(forces, float).reshape(-1, 3)
        m = np.zeros_like(f) if moments is None else np.asarray(moments, float).reshape(-1, 3)
        loads = np.concatenate([f, m], axis=1)  # (n, 6)
        return np.stack(
            [self._A(n, p).T @ w for n, p, w in zip(nodes, pos, loads, strict=True)], axis=1
        ).reshape(self.n_dof, -1)

    def input_loads(self) -> FloatArray:
        """Generalised forces of the setup's inputs (unit force along each line of action)."""
        ex = self.setup.excitations
        return self.generalised_loads(
            [e.node for e in ex], self.setup.input_positions, self.setup.input_directions
        )

    # -- responses -------------------------------------------------------------------------
    def motion(
        self, frequencies_hz: Sequence[float] | FloatArray, loads: FloatArray | None = None
    ) -> ComplexArray:
        """``z = [U; η]`` per unit input, shape (n_lines, n_dof, n_inputs).

        ``loads`` (n_dof, n) are generalised forces (default: the setup's inputs).
        """
        w = 2 * np.pi * np.asarray(frequencies_hz, float)
        M, C, K = self.dynamic_matrices()
        q = self.input_loads() if loads is None else np.asarray(loads, float)
        Z = K[None] - (w**2)[:, None, None] * M[None] + 1j * w[:, None, None] * C[None]
        return np.linalg.solve(Z, np.broadcast_to(q.astype(complex), (w.size, *q.shape)))

    def _accel_rows(self) -> FloatArray:
        """``S``, shape (n_responses, n_dof): ``q_i = −ω² S_i z``."""
        pos, dirs = self.setup.response_positions, self.setup.response_directions
        rows = np.concatenate([dirs, np.cross(pos, dirs)], axis=1)
        if self.modes:
            flex = np.stack(
                [
                    d @ self._shapes(c.node)[:3]
                    for c, d in zip(self.setup.responses, dirs, strict=True)
                ]
            )
            rows = np.concatenate([rows, flex], axis=1)
        return rows

    def output_matrices(self, frequencies_hz: Sequence[float] | FloatArray) -> ComplexArray:
        """``O(ω)`` with ``H = O(ω) z``, shape (n_lines, n_outputs, n_dof), outputs in
        :meth:`frf` order (accelerometers, then 6 per load cell)."""
        w = 2 * np.pi * np.asarray(frequencies_hz, float)
        acc = -(w**2)[:, None, None] * self._accel_rows()[None].astype(complex)
        parts = [acc]
        for s in self.supports:
            Zs = s.stiffness[None] + 1j * w[:, None, None] * s.damping[None]
            sign = 1.0 if s.sign == "on_structure" else -1.0
            parts.append(-sign * Zs @ (s.B().T @ self._A(s.node, s.position_m))[None])
        return np.concatenate(parts, axis=1)

    def channels(
        self,
    ) -> tuple[tuple[Channel, ...], tuple[Literal["acceleration", "reaction"], ...]]:
        """Output channels and kinds in :meth:`frf` order."""
        outputs = [Channel(c.node, c.direction) for c in self.setup.responses]
        kinds: list[Literal["acceleration", "reaction"]] = ["acceleration"] * len(outputs)
        for s in self.supports:
            outputs += [Channel(s.node, k) for k in range(1, 7)]
            kinds += ["reaction"] * 6
        return tuple(outputs), tuple(kinds)

    def load_frf(
        self, frequencies_hz: Sequence[float] | FloatArray, loads: FloatArray
    ) -> ComplexArray:
        """Outputs per unit generalised load (see :meth:`generalised_loads`), shape
        (n_lines, n_outputs, n_loads) — e.g. the thesis cube's pure unit moments."""
        f = self._check_freqs(frequencies_hz)
        return self.output_matrices(f) @ self.motion(f, loads)

    def _check_freqs(self, frequencies_hz: Sequence[float] | FloatArray) -> FloatArray:
        f = np.asarray(frequencies_hz, float)
        if f.ndim != 1 or f.size == 0 or np.any(f <= 0) or not np.all(np.isfinite(f)):
            raise SetupError(
                "frequencies must be a non-empty list of positive lines in Hz (a free body has no "
                "static response); drop the 0 Hz line"
            )
        return f

    def frf(self, frequencies_hz: Sequence[float] | FloatArray) -> FrfData:
        """Accelerances of every response and reactions of every load cell, per unit input."""
        f = self._check_freqs(frequencies_hz)
        H = self.output_matrices(f) @ self.motion(f)
        outputs, kinds = self.channels()
        inputs = tuple(Channel(e.node, e.direction) for e in self.setup.excitations)
        return FrfData(f, H, outputs, kinds, inputs)

    def transfer(self, s: Sequence[complex] | ComplexArray) -> ComplexArray:
        """Outputs per unit input at Laplace variables ``s`` (``s = iω`` gives :meth:`frf`),
        shape (n_s, n_outputs, n_inputs).

        ``(K + s C + s² M) z = q``; accelerometers ``s² S z``, load cells
        ``−sign (k_s + s c_s) B_sᵀ A_s z``. An exponential window ``e^{−t/τ}`` on input and output
        turns a measured FRF into ``H(iω + 1/τ)``: this is the reference for windowed impact FRFs.
        """
        s = np.asarray(s, complex).reshape(-1)
        M, C, K = self.dynamic_matrices()
        q = self.input_loads().astype(complex)
        Z = K[None] + s[:, None, None] * C[None] + (s**2)[:, None, None] * M[None]
        z = np.linalg.solve(Z, np.broadcast_to(q, (s.size, *q.shape)))
        parts = [(s**2)[:, None, None] * self._accel_rows()[None]]
        for sup in self.supports:
            Zs = sup.stiffness[None] + s[:, None, None] * sup.damping[None]
            sign = 1.0 if sup.sign == "on_structure" else -1.0
            parts.append(-sign * Zs @ (sup.B().T @ self._A(sup.node, sup.position_m))[None])
        return np.asarray(np.concatenate(parts, axis=1) @ z)

    def node_positions(self) -> dict[int, FloatArray]:
        """Every node of the setup (responses, inputs, load cells) with its GCS position."""
        out: dict[int, FloatArray] = {}
        for c in self.setup.responses:
            out[c.node] = np.asarray(c.position_m, float)
        for e in self.setup.excitations:
            out[e.node] = np.asarray(e.position_m, float)
        for s in self.supports:
            out[s.node] = np.asarray(s.position_m, float)
        return out


# ----------------------------------------------------------------------------------------------
# Mode shape generators
# ----------------------------------------------------------------------------------------------
def _point_mass_matrix(mass_kg: float, position_m: FloatArray) -> FloatArray:
    """6×6 mass matrix about O of a point mass at ``r``: ``Gᵀ diag(m E, 0) G``."""
    G = _G(position_m)
    return G[:3].T @ (mass_kg * G[:3])


def subsystem_mode(
    name: str,
    frequency_hz: float,
    damping_ratio: float,
    *,
    body: RigidBodyProperties,
    part_mass_kg: float,
    part_position_m: FloatArray,
    direction: FloatArray,
    part_nodes: Sequence[int],
    nodes: Mapping[int, FloatArray],
) -> FlexibleMode:
    """A part (lumped mass) rocking against the rest of the body, e.g. a drogue-chute pack.

    The part (mass ``m_p`` at ``r_p``) translates along unit ``e``; the rest of the body moves
    rigidly by ``V`` such that the mode carries no momentum about O:
    ``(M_body − M_p) V = −M_p [e; 0]`` with ``M_p`` the part's point-mass matrix about O. The shape
    is mass-normalised by the modal mass ``μ = m_p + Vᵀ (M_body − M_p) V``. Part nodes move by
    ``e/√μ``; every other node by the rigid motion ``G_n V/√μ``.
    """
    e = np.asarray(direction, float)
    e = e / np.linalg.norm(e)
    Mp = _point_mass_matrix(part_mass_kg, np.asarray(part_position_m, float))
    Mr = body.mass_matrix(np.zeros(3)) - Mp
    V = -np.linalg.solve(Mr, Mp @ np.concatenate([e, np.zeros(3)]))
    mu = part_mass_kg + V @ Mr @ V
    scale = 1.0 / np.sqrt(mu)
    part = set(int(n) for n in part_nodes)
    shapes: dict[int, FloatArray] = {}
    for node, pos in nodes.items():
        if int(node) in part:
            shapes[int(node)] = np.concatenate([e, np.zeros(3)]) * scale
        else:
            shapes[int(node)] = _G(np.asarray(pos, float)) @ V * scale
    return FlexibleMode(name, frequency_hz, damping_ratio, shapes)


def beam_bending_mode(
    name: str,
    frequency_hz: float,
    damping_ratio: float,
    *,
    mass_kg: float,
    x_range_m: tuple[float, float],
    nodes: Mapping[int, FloatArray],
) -> FlexibleMode:
    """First free-free bending mode of a uniform beam along X bending in Z.

    ``w(x) = cosh βx + cos βx − σ (sinh βx + sin βx)``, ``βL = 4.730041``,
    ``σ = (cosh βL − cos βL)/(sinh βL − sin βL)``, with ``∫₀ᴸ w² dx = L``, so with the mass spread
    uniformly ``w/√m`` is mass-normalised and orthogonal to the rigid-body motions. Each node
    moves ``u_z = w(x)/√m`` and rotates ``θ_y = −w'(x)/√m``.
    """
    x0, x1 = x_range_m
    L = x1 - x0
    bl = 4.730040744862704
    sigma = (np.cosh(bl) - np.cos(bl)) / (np.sinh(bl) - np.sin(bl))
    b = bl / L
    shapes: dict[int, FloatArray] = {}
    for node, pos in nodes.items():
        x = float(np.clip(pos[0] - x0, 0.0, L))
        w = np.cosh(b * x) + np.cos(b * x) - sigma * (np.sinh(b * x) + np.sin(b * x))
        dw = b * (np.sinh(b * x) - np.sin(b * x) - sigma * (np.cosh(b * x) + np.cos(b * x)))
        shapes[int(node)] = np.array([0.0, 0.0, w, 0.0, -dw, 0.0]) / np.sqrt(mass_kg)
    return FlexibleMode(name, frequency_hz, damping_ratio, shapes)


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
CALIBRATION_MASS = THESIS_CALIBRATION_MASS


def calibration_mass(
    seed: int = 0,
    *,
    support: Literal["bungee", "air-ride", "ground", "free"] = "bungee",
    cell_angle_deg: float = 45.0,
    sensor_skew_deg: float = 25.0,
) -> ForwardModel:
    """The thesis calibration mass: 8 triaxes, 24 impacts (8 on each of three faces), 1 load cell.

    The block spans x ∈ [−0.10, 0.20], y ∈ [−0.15, 0.15], z ∈ [−0.20, 0.05] m; a triax sits near
    each corner, each turned by a random rotation of up to ``sensor_skew_deg``; the impacts are on
    the +x, +y and −z faces at scattered points, normal to the face. The load cell (turned
    ``cell_angle_deg`` about Z) carries the support: ``"bungee"`` — on the top face, bounce 2 Hz,
    pendulum 0.7 Hz, ζ ≈ 5 % (:func:`modal_damping`); ``"air-ride"`` — underneath, 1.5 Hz /
    0.3 Hz, ζ ≈ 8 %; ``"ground"`` — underneath,
    bolted to the floor, the cell's own stiffness (:func:`fixed_support_stiffness`) is the
    support (thesis Appendix B; rigid-body modes at a few hundred Hz); ``"free"`` — no support.
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
    if support not in ("bungee", "air-ride", "ground", "free"):
        raise SetupError(
            f"calibration mass support {support!r} is unknown; use bungee, air-ride, ground or free"
        )
    if support != "free":
        R = Rotation.from_euler("z", cell_angle_deg, degrees=True).as_matrix()
        m = CALIBRATION_MASS.mass_kg
        if support == "bungee":
            pos, k = np.array([0.05, 0.0, 0.05]), soft_support_stiffness(m, 2.0, 0.7, 5.0)
            c = modal_damping(k, CALIBRATION_MASS, pos, 0.05)
        elif support == "air-ride":
            pos, k = np.array([0.05, 0.0, -0.20]), soft_support_stiffness(m, 1.5, 0.3, 20.0)
            c = modal_damping(k, CALIBRATION_MASS, pos, 0.08)
        else:
            pos, k = np.array([0.05, 0.0, -0.20]), fixed_support_stiffness()
            c = 2 * 0.02 * k / (2 * np.pi * 300.0)  # ζ ≈ 2 % near 300 Hz
        supports = (Support(501, pos, R, k, c),)
    setup = TestSetup(
        name=f"calibration mass ({support})",
        responses=tuple(responses),
        excitations=tuple(inputs),
        load_cells=tuple(s.load_cell() for s in supports),
    )
    return ForwardModel(CALIBRATION_MASS, setup, supports)


#: The lab's reference block (the body of known mass for the chain calibration,
#: :mod:`dimacq.pipeline.chain_calibration`): solid aluminium (2700 kg/m³), machined to
#: x ∈ [−0.11, 0.21], y ∈ [−0.14, 0.14], z ∈ [−0.15, 0.05] m (0.32 × 0.28 × 0.20 m).
REFERENCE_BLOCK_BOX_M = (np.array([-0.11, -0.14, -0.15]), np.array([0.21, 0.14, 0.05]))


def _solid_box(density_kg_m3: float, lo: FloatArray, hi: FloatArray) -> RigidBodyProperties:
    """A homogeneous box: ``m = ρ a b c``, CG at the centre, ``I = m/12 diag(b²+c², a²+c², a²+b²)``."""
    a, b, c = hi - lo
    m = density_kg_m3 * a * b * c
    return RigidBodyProperties(
        m, 0.5 * (lo + hi), m / 12.0 * np.diag([b * b + c * c, a * a + c * c, a * a + b * b])
    )


REFERENCE_BLOCK = _solid_box(2700.0, *REFERENCE_BLOCK_BOX_M)


def reference_block_drawing() -> TestSetup:
    """The reference block as its drawing gives it (what the lab knows, no tolerances).

    A triax in a machined pocket 20 mm in from each corner (nodes 1..8, axes along the block's),
    the load cell (node 501, turned 45° about Z) on the top face at (0.05, 0, 0.05) m, and 24
    marked impact points (nodes 101..124), a 4 × 2 grid on each of the +x, +y and −z faces, struck
    normal to the face.
    """
    lo, hi = REFERENCE_BLOCK_BOX_M
    centre = 0.5 * (lo + hi)
    corners = np.array(
        [[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])]
    )
    positions = corners - 0.02 * np.sign(corners - centre)
    responses = _triaxes(range(1, 9), positions, [np.eye(3)] * 8)
    pts, dirs = [], []
    for axis, value, normal in (
        (0, hi[0], np.array([-1.0, 0, 0])),
        (1, hi[1], np.array([0, -1.0, 0])),
        (2, lo[2], np.array([0, 0, 1.0])),
    ):
        u_ax, v_ax = [k for k in range(3) if k != axis]
        for iu in range(4):
            for iv in range(2):
                p = centre.copy()
                p[axis] = value
                p[u_ax] = lo[u_ax] + (hi[u_ax] - lo[u_ax]) * (0.15 + 0.7 * iu / 3)
                p[v_ax] = lo[v_ax] + (hi[v_ax] - lo[v_ax]) * (0.3 + 0.4 * iv)
                pts.append(p)
                dirs.append(normal)
    inputs = _inputs(range(101, 125), np.array(pts), np.array(dirs))
    R = Rotation.from_euler("z", 45.0, degrees=True).as_matrix()
    cell = Support(501, np.array([0.05, 0.0, 0.05]), R, np.zeros((6, 6)), np.zeros((6, 6)))
    return TestSetup(
        name="reference block (drawing)",
        responses=tuple(responses),
        excitations=tuple(inputs),
        load_cells=(cell.load_cell(),),
        reference_point_m=(float(centre[0]), float(centre[1]), float(centre[2])),
        geometry_uncertainty=GeometryUncertainty(
            sensor_position_m=2e-4,
            sensor_orientation_deg=0.2,
            input_position_m=2e-3,
            line_of_action_deg=2.0,
            source="stated",
        ),
    )


def reference_block(seed: int = 0) -> ForwardModel:
    """The reference block as built, hung on a bungee through the load cell (as the calibration
    mass, :func:`calibration_mass`: bounce 2 Hz, pendulum 0.7 Hz, ζ ≈ 5 %).

    Its geometry is the drawing's (:func:`reference_block_drawing`) within machining tolerance
    (pockets ``N(0, 0.1 mm)`` per coordinate and ``N(0, 0.1°)`` in rotation) and the hand-held
    hammer's placement (marked point ``N(0, 1 mm)``, direction ``N(0, 1°)``), seeded by ``seed``.
    """
    rng = np.random.default_rng([seed, 0xB10C])
    drawing = reference_block_drawing()
    responses = []
    for node in range(1, 9):
        chans = [c for c in drawing.responses if c.node == node]
        R = Rotation.from_rotvec(
            np.deg2rad(0.1) * rng.standard_normal() * _unit(rng.normal(size=3))
        ).as_matrix()
        pos = np.asarray(chans[0].position_m) + rng.normal(scale=1e-4, size=3)
        responses += _triaxes([node], pos[None, :], [R])
    pts, dirs = [], []
    for e in drawing.excitations:
        pts.append(np.asarray(e.position_m) + rng.normal(scale=1e-3, size=3))
        d = np.asarray(e.direction_gcs, float)
        rot = Rotation.from_rotvec(
            np.deg2rad(1.0) * rng.standard_normal() * _unit(np.cross(d, rng.normal(size=3)))
        )
        dirs.append(rot.apply(d))
    inputs = _inputs(range(101, 125), np.array(pts), np.array(dirs))
    m = REFERENCE_BLOCK.mass_kg
    R = Rotation.from_euler("z", 45.0, degrees=True).as_matrix()
    pos, k = np.array([0.05, 0.0, 0.05]), soft_support_stiffness(m, 2.0, 0.7, 5.0)
    support = Support(501, pos, R, k, modal_damping(k, REFERENCE_BLOCK, pos, 0.05))
    setup = TestSetup(
        name="reference block (bungee)",
        responses=tuple(responses),
        excitations=tuple(inputs),
        load_cells=(support.load_cell(),),
        reference_point_m=drawing.reference_point_m,
    )
    return ForwardModel(REFERENCE_BLOCK, setup, (support,))


def _unit(v: FloatArray) -> FloatArray:
    return v / np.linalg.norm(v)


#: X-38-like vehicle (thesis §4.2): mass, CG and inertia about the CG (tensor elements).
X38_PROPERTIES = RigidBodyProperties(
    8089.0,
    np.array([4.14, 0.004, 0.74]),
    np.array([[9.8e3, 150.0, -820.0], [150.0, 6.1e4, 35.0], [-820.0, 35.0, 6.4e4]]),
)

#: Drogue-chute pack of the X-38-like vehicle: the three triaxes on it and where it sits.
X38_CHUTE_NODES = (1019, 1020, 1021)
X38_CHUTE_POSITION_M = np.array([7.6, 0.0, 1.7])
#: Twin vertical tails (their lumped mass centre) of the X-38-like vehicle.
X38_TAIL_POSITION_M = np.array([8.4, 0.0, 2.4])


def x38_like(
    seed: int = 0,
    *,
    flexible: bool = False,
    chute_mass_kg: float = 5.0,
    chute_modes_hz: tuple[float, float] = (4.8, 5.3),
    deformation_mode_hz: float = 23.0,
    tail_mass_kg: float = 40.0,
    suspension_hz: float = 1.8,
) -> ForwardModel:
    """An X-38-sized body: m = 8089 kg, CG ≈ (4.14, 0.004, 0.74) m, on 3 skewed load cells.

    21 triaxes over a 9 m × 3 m × 1.8 m hull — the last three (nodes 1019–1021) on the drogue-chute
    pack near (7.6, 0, 1.7) m — 22 inputs, three air-ride-like supports (rigid-body modes
    0.45–2.2 Hz) through load cells each turned about a tilted axis, so none is aligned with the
    GCS; the cells report the load on the support. With ``flexible`` three elastic modes are
    added (thesis §4.2, Fig. 37: "two closely spaced modes" of the drogue chute near 5 Hz, the
    first deformation mode near 23 Hz): the chute pack rocking laterally and vertically against
    the vehicle (:func:`subsystem_mode`, ζ = 3 %) and the first deformation mode, the twin
    vertical tails (``tail_mass_kg`` near (8.4, 0, 2.4) m) bending laterally against the hull
    (:func:`subsystem_mode`, ζ = 2 %; :func:`beam_bending_mode` gives a global hull bending
    instead, whose quasi-static share spoils a DIM band far more). ``suspension_hz`` sets each
    air-ride support's vertical (bounce) frequency (lateral 0.5 Hz). Above its modes the pack no longer follows the vehicle:
    the DIM then sees ``chute_mass_kg`` less mass (and its inertia), and the chute triaxes
    disagree with rigid-body motion (the thesis solved with 18 of the 21 triaxes).
    """
    rng = np.random.default_rng(seed)
    props = X38_PROPERTIES
    lo, hi = np.array([0.0, -1.5, 0.0]), np.array([9.0, 1.5, 1.8])
    positions = rng.uniform(lo, hi, (21, 3))
    positions[18:] = X38_CHUTE_POSITION_M + np.array(
        [[-0.25, -0.2, 0.05], [0.25, 0.2, 0.05], [0.0, 0.25, -0.1]]
    )
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
        k = soft_support_stiffness(8089.0 / 3, suspension_hz, 0.5, 2.0e4)
        supports.append(
            Support(node, np.array(pos), R, k, 0.03 * k / (2 * np.pi * suspension_hz), "on_support")
        )
    setup = TestSetup(
        name="X-38-like vehicle",
        responses=tuple(responses),
        excitations=tuple(inputs),
        load_cells=tuple(s.load_cell() for s in supports),
    )
    fm = ForwardModel(props, setup, tuple(supports))
    if not flexible:
        return fm
    nodes = fm.node_positions()
    chute = tuple(
        subsystem_mode(
            f"drogue chute {axis}",
            f_hz,
            0.03,
            body=props,
            part_mass_kg=chute_mass_kg,
            part_position_m=X38_CHUTE_POSITION_M,
            direction=direction,
            part_nodes=X38_CHUTE_NODES,
            nodes=nodes,
        )
        for axis, f_hz, direction in (
            ("lateral", chute_modes_hz[0], np.array([0.0, 1.0, 0.0])),
            ("vertical", chute_modes_hz[1], np.array([0.0, 0.0, 1.0])),
        )
    )
    tails = subsystem_mode(
        "vertical tails lateral bending",
        deformation_mode_hz,
        0.02,
        body=props,
        part_mass_kg=tail_mass_kg,
        part_position_m=X38_TAIL_POSITION_M,
        direction=np.array([0.0, 1.0, 0.0]),
        part_nodes=(),
        nodes=nodes,
    )
    return replace(fm, modes=(*chute, tails))


def cube(half_size_m: float, seed: int = 0) -> ForwardModel:
    """The thesis cube model (§2.2.1): 8 triaxes at (±H, ±H, ±H), free-free, calibration-mass
    properties about the origin.

    The thesis applies six unit forces and moments at the origin. A single-point input cannot be a
    pure moment, so the six inputs here are three unit forces at the origin along X, Y, Z and three
    at unit offsets (force along Y at +X, along Z at +Y, along X at +Z), whose 6-DOF vectors span
    the same space; triaxes are aligned with the GCS and rotated by a small seeded angle so each
    case also exercises skewed directions. :func:`cube_unit_loads` gives the thesis's six pure
    unit forces and moments for :meth:`ForwardModel.load_frf`.
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


def cube_unit_loads(fm: ForwardModel) -> FloatArray:
    """The thesis's six unit loads at the origin — forces along X, Y, Z, then pure moments about
    X, Y, Z — as generalised forces (n_dof, 6) for :meth:`ForwardModel.load_frf`."""
    eye = np.eye(3)
    zeros = np.zeros((3, 3))
    return fm.generalised_loads(
        [0] * 6,
        np.zeros((6, 3)),
        np.concatenate([eye, zeros]),
        np.concatenate([zeros, eye]),
    )


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
