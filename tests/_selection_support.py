"""Test support for selection / uncertainty tests: a small closed-form rigid-body test article.

The calibration mass of the thesis (method.md §9) on soft supports, 8 triaxes near the corners of
a box around it, 24 inputs (8 on each of three faces), optionally one elastic mode. The FRFs come
from the closed form of a rigid body with a 6×6 suspension stiffness ``Ks`` (its forces are not
measured unless ``suspension=False``):

    K(ω) = −ω² (Ks − ω² M + iω Cs)⁻¹ Φ_true,   H_acc = Ψ_true K + elastic term

where ``Ψ_true`` and ``Φ_true`` are built from the *true* sensor directions and lines of action,
while the returned :class:`TestSetup` holds the *nominal* ones the solver is told about.
This generator is independent of the solver code (it uses only numpy / scipy Rotation).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from dimacq.model.frf import Channel, FrfData
from dimacq.model.setup import Excitation, ResponseChannel, TestSetup

MASS_KG = 18.175
CG_M = np.array([0.035236, 0.000130, -0.085632])
I_O = np.array(
    [
        [0.218554, -0.000109, 0.078161],
        [-0.000109, 0.304172, 0.000218],
        [0.078161, 0.000218, 0.158154],
    ]
)  # about the origin, tensor elements


def skew(v: NDArray[np.float64]) -> NDArray[np.float64]:
    return np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])


def mass_matrix() -> NDArray[np.float64]:
    M = np.zeros((6, 6))
    M[:3, :3] = MASS_KG * np.eye(3)
    M[:3, 3:] = -MASS_KG * skew(CG_M)
    M[3:, :3] = MASS_KG * skew(CG_M)
    M[3:, 3:] = I_O
    return M


def inertia_cg() -> NDArray[np.float64]:
    c = CG_M
    return I_O - MASS_KG * (c @ c * np.eye(3) - np.outer(c, c))


def triax_positions() -> NDArray[np.float64]:
    xs, ys, zs = (-0.10, 0.17), (-0.11, 0.11), (-0.20, 0.03)
    return np.array([(x, y, z) for x in xs for y in ys for z in zs])


def input_geometry() -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """24 inputs: 8 on the +X face (along −X), 8 on the +Y face (along −Y), 8 on top (along −Z)."""
    pos, d = [], []
    a = np.array([-0.07, -0.02, 0.03, 0.08])
    for u in a:
        for v in (-0.17, -0.02):
            pos.append((0.17, u, v))
            d.append((-1.0, 0.0, 0.0))
    for u in a:
        for v in (-0.17, -0.02):
            pos.append((u + 0.04, 0.11, v))
            d.append((0.0, -1.0, 0.0))
    for u in a:
        for v in (-0.08, 0.08):
            pos.append((u + 0.04, v, 0.03))
            d.append((0.0, 0.0, -1.0))
    return np.array(pos), np.array(d)


def _perp_rotation(d: NDArray[np.float64], angle_deg: float, rng: np.random.Generator) -> Rotation:
    """A rotation by ``angle_deg`` about a random axis perpendicular to ``d``."""
    t = rng.normal(size=3)
    t -= (t @ d) * d
    t /= np.linalg.norm(t)
    return Rotation.from_rotvec(np.deg2rad(angle_deg) * t)


@dataclass
class Case:
    frf: FrfData
    setup: TestSetup
    true_response_dirs: NDArray[np.float64]
    bad_channels: list[tuple[int, int]] = field(default_factory=list)
    bad_inputs: list[tuple[int, int]] = field(default_factory=list)
    triax_rotations: list[Rotation] = field(default_factory=list)


def make_case(
    seed: int,
    *,
    noise: float = 0.01,
    triax_error_deg: float = 0.0,
    bad_channel_deg: float = 0.0,
    n_bad_channels: int = 0,
    n_bad_inputs: int = 0,
    input_angle_deg: float = 30.0,
    input_shift_m: float = 0.03,
    freqs_hz: NDArray[np.float64] | None = None,
    suspension_hz: float = 0.0,
    elastic_hz: float = 0.0,
) -> Case:
    """Build FRFs with the true geometry and a setup with the nominal one.

    ``triax_error_deg``: each triax rotated by angles uniform within ±value about x, y, z.
    ``n_bad_channels`` single channels are further rotated by ``bad_channel_deg`` (plus up to 10°)
    about an axis perpendicular to them; ``n_bad_inputs`` inputs get their line of action rotated by
    ``input_angle_deg`` and position moved by ``input_shift_m``.
    """
    rng = np.random.default_rng(seed)
    f = np.linspace(20.0, 200.0, 91) if freqs_hz is None else np.asarray(freqs_hz, float)
    w = 2 * np.pi * f
    P = triax_positions()
    nodes = np.arange(1, 9) * 100 + 1
    dirs_nom = np.tile(np.eye(3), (8, 1))
    pos_ch = np.repeat(P, 3, axis=0)
    rots = []
    dirs_true = dirs_nom.copy()
    for k in range(8):
        ang = rng.uniform(-triax_error_deg, triax_error_deg, size=3)
        r = Rotation.from_euler("xyz", ang, degrees=True)
        rots.append(r)
        dirs_true[3 * k : 3 * k + 3] = r.apply(dirs_nom[3 * k : 3 * k + 3])
    bad_ch = rng.choice(24, size=n_bad_channels, replace=False) if n_bad_channels else []
    bad_channels = []
    for c in bad_ch:
        ang = bad_channel_deg + rng.uniform(0.0, 10.0)
        dirs_true[c] = _perp_rotation(dirs_true[c], ang, rng).apply(dirs_true[c])
        bad_channels.append((int(nodes[c // 3]), int(c % 3 + 1)))

    in_pos_nom, in_dir_nom = input_geometry()
    in_pos, in_dir = in_pos_nom.copy(), in_dir_nom.copy()
    bad_in = rng.choice(24, size=n_bad_inputs, replace=False) if n_bad_inputs else []
    bad_inputs = []
    for j in bad_in:
        in_dir[j] = _perp_rotation(in_dir[j], input_angle_deg, rng).apply(in_dir[j])
        s = rng.normal(size=3)
        in_pos[j] = in_pos[j] + input_shift_m * s / np.linalg.norm(s)
        bad_inputs.append((int(1001 + j), 1))

    psi_t = np.concatenate([dirs_true, np.cross(pos_ch, dirs_true)], axis=1)
    phi_t = np.concatenate([in_dir, np.cross(in_pos, in_dir)], axis=1).T
    M = mass_matrix()
    Ks = np.zeros((6, 6))
    if suspension_hz > 0:
        lam, V = np.linalg.eigh(M)
        Mh = V @ np.diag(np.sqrt(lam)) @ V.T
        Ks = Mh @ np.diag((2 * np.pi * suspension_hz * np.linspace(0.6, 1.4, 6)) ** 2) @ Mh
    Cs = 0.002 * Ks
    Z = Ks[None] - (w**2)[:, None, None] * M[None] + 1j * w[:, None, None] * Cs[None]
    K = -(w**2)[:, None, None] * np.linalg.solve(Z, phi_t[None].astype(complex))
    H = psi_t[None] @ K
    if elastic_hz > 0:
        # a bending-like mode: shape linear in x·z over the points, unit modal mass scale 1/sqrt(m)
        amp = 1.0 / np.sqrt(MASS_KG)
        sh_out = amp * (pos_ch[:, 0] * pos_ch[:, 2] / 0.02) * np.sum(dirs_true, axis=1)
        sh_in = amp * (in_pos[:, 0] * in_pos[:, 2] / 0.02) * np.sum(in_dir, axis=1)
        we = 2 * np.pi * elastic_hz
        den = we**2 - w**2 + 2j * 0.01 * we * w
        H = H + (-(w**2) / den)[:, None, None] * np.outer(sh_out, sh_in)[None]
    if noise > 0:
        scale = np.sqrt(np.mean(np.abs(H) ** 2, axis=2, keepdims=True))
        H = H + noise * scale * (
            rng.normal(size=H.shape) + 1j * rng.normal(size=H.shape)
        ) / np.sqrt(2)

    outputs = tuple(Channel(int(nodes[c // 3]), int(c % 3 + 1)) for c in range(24))
    inputs = tuple(Channel(1001 + j, 1) for j in range(24))
    frf = FrfData(f, H, outputs, ("acceleration",) * 24, inputs)
    resp = tuple(
        ResponseChannel(
            node=int(nodes[c // 3]),
            direction=int(c % 3 + 1),
            position_m=tuple(pos_ch[c]),  # type: ignore[arg-type]
            direction_gcs=tuple(dirs_nom[c]),  # type: ignore[arg-type]
        )
        for c in range(24)
    )
    exc = tuple(
        Excitation(
            node=1001 + j,
            direction=1,
            position_m=tuple(in_pos_nom[j]),  # type: ignore[arg-type]
            direction_gcs=tuple(in_dir_nom[j]),  # type: ignore[arg-type]
        )
        for j in range(24)
    )
    setup = TestSetup(name="calibration mass (closed form)", responses=resp, excitations=exc)
    return Case(frf, setup, dirs_true, bad_channels, bad_inputs, rots)


# --------------------------------------------------------------------------------------------
# Cases on the virtual lab's forward model (simulators/lab/forward.py): the FRFs come from the
# model with *perturbed* (true) geometry, the solver is given the model's nominal setup.
# --------------------------------------------------------------------------------------------
@dataclass
class ForwardCase:
    frf: FrfData
    nominal: TestSetup
    true: TestSetup
    truth: object  # RigidBodyProperties
    bad_channels: list[tuple[int, int]] = field(default_factory=list)
    bad_inputs: list[tuple[int, int]] = field(default_factory=list)


def forward_case(
    seed: int,
    *,
    noise: float = 0.01,
    triax_error_deg: float = 0.0,
    bad_channel_deg: float = 0.0,
    n_bad_channels: int = 0,
    n_bad_inputs: int = 0,
    input_angle_deg: float = 30.0,
    input_shift_m: float = 0.03,
    freqs_hz: NDArray[np.float64] | None = None,
    support: str = "bungee",
) -> ForwardCase:
    """Calibration mass of the forward model (8 triaxes, 24 impacts, one load cell) with errors.

    ``triax_error_deg``: each triax truly rotated by angles uniform within ±value about x, y, z
    (about its own axes); ``n_bad_channels`` channels further rotated by ``bad_channel_deg`` + U(0,
    10°) about an axis perpendicular to them; ``n_bad_inputs`` inputs with the line of action
    rotated by ``input_angle_deg`` and the point moved by ``input_shift_m``. 1 % noise: complex
    Gaussian scaled by each output's RMS over the inputs at each line.
    """
    from dataclasses import replace as dc_replace

    from dimacq.simulators.lab.forward import calibration_mass

    rng = np.random.default_rng(seed)
    fm = calibration_mass(seed, support=support)  # type: ignore[arg-type]
    nominal = fm.setup
    resp = list(nominal.responses)
    nodes = sorted({c.node for c in resp})
    for n in nodes:
        r = Rotation.from_euler(
            "xyz", rng.uniform(-triax_error_deg, triax_error_deg, 3), degrees=True
        )
        idx = [i for i, c in enumerate(resp) if c.node == n]
        C = np.array([resp[i].direction_gcs for i in idx]).T  # columns: the triax axes (GCS)
        Ct = C @ r.as_matrix()  # rotation about the sensor's own axes
        for k, i in enumerate(idx):
            resp[i] = resp[i].model_copy(
                update={"direction_gcs": tuple(Ct[:, k] / np.linalg.norm(Ct[:, k]))}
            )
    bad_ch = rng.choice(len(resp), size=n_bad_channels, replace=False) if n_bad_channels else []
    bad_channels = []
    for i in bad_ch:
        d = np.asarray(resp[i].direction_gcs)
        d2 = _perp_rotation(d, bad_channel_deg + rng.uniform(0, 10), rng).apply(d)
        resp[i] = resp[i].model_copy(update={"direction_gcs": tuple(d2 / np.linalg.norm(d2))})
        bad_channels.append((resp[i].node, resp[i].direction))
    exc = list(nominal.excitations)
    bad_in = rng.choice(len(exc), size=n_bad_inputs, replace=False) if n_bad_inputs else []
    bad_inputs = []
    for j in bad_in:
        d = np.asarray(exc[j].direction_gcs)
        d2 = _perp_rotation(d, input_angle_deg, rng).apply(d)
        s = rng.normal(size=3)
        p2 = np.asarray(exc[j].position_m) + input_shift_m * s / np.linalg.norm(s)
        exc[j] = exc[j].model_copy(
            update={"direction_gcs": tuple(d2 / np.linalg.norm(d2)), "position_m": tuple(p2)}
        )
        bad_inputs.append((exc[j].node, exc[j].direction))
    true = nominal.model_copy(update={"responses": tuple(resp), "excitations": tuple(exc)})
    f = np.linspace(20.0, 200.0, 61) if freqs_hz is None else np.asarray(freqs_hz, float)
    frf = dc_replace(fm, setup=true).frf(f)
    H = frf.H
    if noise > 0:
        scale = np.sqrt(np.mean(np.abs(H) ** 2, axis=2, keepdims=True))
        H = H + noise * scale * (
            rng.normal(size=H.shape) + 1j * rng.normal(size=H.shape)
        ) / np.sqrt(2)
        frf = frf.replace(H=H)
    return ForwardCase(frf, nominal, true, fm.properties, bad_channels, bad_inputs)
