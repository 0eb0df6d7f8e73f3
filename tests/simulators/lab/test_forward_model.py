"""The forward model against independent answers: Newton's law, the mass line, vanishing
supports, closed-form mode shapes, and its own state-space form."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from dimacq.errors import SetupError
from dimacq.simulators.lab.forward import (
    CALIBRATION_MASS,
    FlexibleMode,
    Support,
    beam_bending_mode,
    calibration_mass,
    cube,
    cube_unit_loads,
    subsystem_mode,
    x38_like,
)
from dimacq.simulators.lab.timedomain import state_space


def _skew(v):
    return np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])


def _mass_matrix_by_hand(props):
    """[[m E, −m[c]x], [m[c]x, I_O]] about the origin, written out independently."""
    m, c = props.mass_kg, props.cg_m
    I_o = props.inertia_cg_kgm2 + m * (c @ c * np.eye(3) - np.outer(c, c))
    return np.block([[m * np.eye(3), -m * _skew(c)], [m * _skew(c), I_o]])


def test_far_above_the_suspension_the_accelerance_is_the_rigid_mass_line() -> None:
    fm = calibration_mass(0)
    f = np.array([2000.0, 8000.0])
    H = fm.frf(f).H[:, : len(fm.setup.responses)]
    s = fm.setup
    psi = np.hstack([s.response_directions, np.cross(s.response_positions, s.response_directions)])
    phi = np.hstack([s.input_directions, np.cross(s.input_positions, s.input_directions)]).T
    mass_line = psi @ np.linalg.solve(_mass_matrix_by_hand(CALIBRATION_MASS), phi)
    # suspension ≤ 2.1 Hz, ζ ≤ 16 %: the deviation falls as 2ζ f_s / f (damping) + (f_s / f)²
    err = [np.abs(H[k] - mass_line).max() / np.abs(mass_line).max() for k in range(2)]
    assert err[0] < 1e-3 and err[1] == pytest.approx(err[0] / 4, rel=0.05)


def test_reactions_vanish_with_the_support_stiffness() -> None:
    fm = calibration_mass(0)
    n_acc = len(fm.setup.responses)
    f = np.array([30.0])
    levels = []
    for eps in (1.0, 1e-2, 1e-4):
        sup = tuple(
            replace(s, stiffness=eps * s.stiffness, damping=eps * s.damping) for s in fm.supports
        )
        levels.append(np.abs(replace(fm, supports=sup).frf(f).H[:, n_acc:]).max())
    assert levels[1] == pytest.approx(1e-2 * levels[0], rel=1e-2)
    assert levels[2] == pytest.approx(1e-4 * levels[0], rel=1e-2)


@pytest.mark.parametrize("build", [lambda: calibration_mass(2), lambda: x38_like(1)])
def test_newton_excitation_plus_measured_reactions_equal_mass_times_acceleration(build) -> None:
    """Σ loads on the body at O (input + each cell's output, un-signed and turned to the GCS) = M Ü."""
    fm = build()
    f = np.array([3.0, 17.0])
    w = 2 * np.pi * f
    U = fm.motion(f)  # (L, 6, n_in)
    H = fm.frf(f).H
    s = fm.setup
    phi = np.hstack([s.input_directions, np.cross(s.input_positions, s.input_directions)]).T
    total = np.broadcast_to(phi, (f.size, *phi.shape)).astype(complex).copy()
    row = len(s.responses)
    for lc in s.load_cells:
        R = lc.rotation_matrix
        loc = lc.sign_factor * H[:, row : row + 6]
        fg = np.einsum("ab,lbj->laj", R, loc[:, :3])
        mg = np.einsum("ab,lbj->laj", R, loc[:, 3:]) + np.cross(
            np.asarray(lc.position_m)[None, :, None], fg, axis=1
        )
        total[:, :3] += fg
        total[:, 3:] += mg
        row += 6
    inertia = np.einsum(
        "ab,lbj->laj", _mass_matrix_by_hand(fm.properties), -(w**2)[:, None, None] * U
    )
    assert np.abs(total - inertia).max() < 1e-9 * np.abs(inertia).max()


def test_free_free_beam_mode_is_mass_normalised_and_orthogonal_to_rigid_motion() -> None:
    L, m = 9.0, 8000.0
    x = np.linspace(0, L, 20001)
    nodes = {k: np.array([xi, 0.0, 0.0]) for k, xi in enumerate(x)}
    mode = beam_bending_mode("b", 23.0, 0.02, mass_kg=m, x_range_m=(0.0, L), nodes=nodes)
    wz = np.array([mode.shape_at(k)[2] for k in range(x.size)])
    mu = m / L
    assert np.trapezoid(mu * wz**2, x) == pytest.approx(1.0, rel=1e-6)
    assert abs(np.trapezoid(mu * wz, x)) < 1e-6 * np.sqrt(m)  # no net momentum
    assert abs(np.trapezoid(mu * x * wz, x)) < 1e-6 * np.sqrt(m) * L  # no angular momentum
    # rotation is −dw/dx
    ry = np.array([mode.shape_at(k)[4] for k in range(x.size)])
    assert np.allclose(ry[1:-1], -np.gradient(wz, x)[1:-1], atol=1e-4 * np.abs(ry).max())


def test_subsystem_mode_carries_no_momentum_and_has_unit_modal_mass() -> None:
    """Lump the rest of the body as its 6×6 mass matrix: part momentum + rest momentum = 0."""
    props = CALIBRATION_MASS
    rp, mp, e = np.array([0.1, 0.05, -0.1]), 1.5, np.array([0.0, 1.0, 0.0])
    nodes = {1: np.zeros(3), 2: np.array([0.2, 0.0, 0.0]), 3: np.array([0.0, 0.0, 0.3]), 9: rp}
    mode = subsystem_mode(
        "part",
        50.0,
        0.02,
        body=props,
        part_mass_kg=mp,
        part_position_m=rp,
        direction=e,
        part_nodes=[9],
        nodes=nodes,
    )
    V = mode.shape_at(1)  # rigid motion of the rest, read at the origin
    G = np.eye(6)
    G[:3, 3:] = -_skew(rp)
    Mp = G[:3].T @ (mp * G[:3])
    Mr = _mass_matrix_by_hand(props) - Mp
    part = mode.shape_at(9)
    momentum = Mr @ V + Mp @ np.concatenate([part[:3], np.zeros(3)])
    assert np.abs(momentum).max() < 1e-12
    assert mp * part[:3] @ part[:3] + V @ Mr @ V == pytest.approx(1.0, rel=1e-12)
    # every other node moves rigidly with the rest
    for n in (2, 3):
        Gn = np.eye(6)
        Gn[:3, 3:] = -_skew(nodes[n])
        assert np.allclose(mode.shape_at(n), Gn @ V, atol=1e-15)


def test_flexible_x38_has_its_modes_and_a_resonance_in_the_chute_triaxes() -> None:
    fm = x38_like(0, flexible=True)
    fn = fm.natural_frequencies_hz()
    assert fn[:6].max() < 2.5
    assert np.any(np.abs(fn - 4.8) < 0.1) and np.any(np.abs(fn - 5.3) < 0.1)
    assert np.any(np.abs(fn - 23.0) < 0.3)
    f = np.array([3.0, 4.8, 6.5])
    chute = [i for i, c in enumerate(fm.setup.responses) if c.node in (1019, 1020, 1021)]
    flex, rigid = np.abs(fm.frf(f).H[:, chute]), np.abs(fm.rigid().frf(f).H[:, chute])
    assert (flex[1] / rigid[1]).max() > 3  # the chute pack resonates
    assert fm.rigid().frf(f).H.shape == fm.frf(f).H.shape


@pytest.mark.parametrize(
    "build",
    [
        lambda: calibration_mass(0),
        lambda: calibration_mass(1, support="ground"),
        lambda: x38_like(0, flexible=True),
        lambda: replace(
            cube(1.0),
            modes=(
                FlexibleMode(
                    "m", 40.0, 0.03, {1: np.array([0.1, 0, 0, 0, 0, 0]), 101: np.ones(6) * 0.05}
                ),
            ),
        ),
    ],
)
def test_state_space_reproduces_the_frequency_model(build) -> None:
    fm = build()
    A, B, C, D, _ = state_space(fm)
    s = 2j * np.pi * np.array([1.3, 7.0, 41.0]) + 0.4
    if A.shape[0]:
        H = np.array([C @ np.linalg.solve(si * np.eye(A.shape[0]) - A, B) + D for si in s])
    else:
        H = np.broadcast_to(D, (s.size, *D.shape))
    H0 = fm.transfer(s)
    assert np.abs(H - H0).max() < 1e-10 * np.abs(H0).max()
    assert np.allclose(fm.transfer(s[:1].imag * 1j), fm.frf(s[:1].imag / (2 * np.pi)).H, rtol=1e-12)


def test_cube_pure_moments_equal_their_force_couples() -> None:
    fm = cube(1.0)
    f = np.array([10.0])
    loads = cube_unit_loads(fm)
    H = fm.load_frf(f, loads)
    # a unit moment about Z = forces +Y at x = +a/2 and −Y at x = −a/2 (one unit couple)
    a = 0.3
    couple = fm.generalised_loads(
        [0, 0], np.array([[a / 2, 0, 0], [-a / 2, 0, 0]]), np.array([[0, 1 / a, 0], [0, -1 / a, 0]])
    ).sum(axis=1, keepdims=True)
    assert np.allclose(fm.load_frf(f, couple)[..., 0], H[..., 5], rtol=1e-12, atol=0)


def test_bad_frequencies_and_modes_are_refused() -> None:
    with pytest.raises(SetupError, match="positive"):
        cube(1.0).frf([0.0, 1.0])
    with pytest.raises(SetupError, match="frequency_hz"):
        FlexibleMode("bad", -1.0, 0.01, {})
    with pytest.raises(SetupError, match="damping_ratio"):
        FlexibleMode("bad", 10.0, 1.5, {})
    with pytest.raises(SetupError, match="support"):
        calibration_mass(0, support="trampoline")  # type: ignore[arg-type]
    assert isinstance(calibration_mass(0).supports[0], Support)
