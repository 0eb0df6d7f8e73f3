"""DIM solver against the independent forward model (simulators/lab/forward.py)."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from dimacq.errors import SetupError, SolverError
from dimacq.model.frf import Channel
from dimacq.model.properties import RigidBodyProperties
from dimacq.model.setup import PARAMETERS, Excitation
from dimacq.pipeline import dim
from dimacq.simulators.lab.forward import ForwardModel, calibration_mass, cube, x38_like

BAND = np.linspace(20.0, 60.0, 21)


def _truth(props: RigidBodyProperties, p: np.ndarray) -> np.ndarray:
    v = props.parameter_vector(p)
    v[1:4] = props.cg_m
    return v


def _rel_errors(result: dim.DimResult, fm: ForwardModel) -> tuple[float, float, float]:
    t = fm.properties
    p = result.reference_point_m
    size = float(np.ptp(fm.setup.response_positions, axis=0).max())
    i_max = float(np.linalg.eigvalsh(t.inertia_about(p)).max())
    return (
        abs(result.mass_kg / t.mass_kg - 1),
        float(np.abs(result.cg_m - t.cg_m).max() / size),
        float(np.abs(result.inertia_p_kgm2 - t.inertia_about(p)).max() / i_max),
    )


CASES = {
    "calibration-mass": lambda: calibration_mass(0),
    "calibration-mass-air-ride": lambda: calibration_mass(3, support="air-ride"),
    "x38-like": lambda: x38_like(0),
    "cube-0.02": lambda: cube(0.01),
    "cube-2": lambda: cube(1.0),
    "cube-200": lambda: cube(100.0),
}


@pytest.mark.parametrize("name", list(CASES))
def test_noise_free_forward_model_returns_all_ten_properties(name: str) -> None:
    fm = CASES[name]()
    freqs = np.linspace(8.0, 20.0, 13) if name == "x38-like" else BAND
    frf = fm.frf(freqs)
    result = dim.solve(frf, fm.setup)
    errors = _rel_errors(result, fm)
    assert max(errors) < 1e-9, errors
    assert result.rank == 10
    # The spectrum of per-line estimates is flat and equal to the joint answer.
    assert np.allclose(result.per_line[:, 0], fm.properties.mass_kg, rtol=1e-9)
    assert result.band_stats["m"]["std"] < 1e-9 * fm.properties.mass_kg


def test_load_cells_matter_x38_fails_without_reactions() -> None:
    fm = x38_like(0)
    frf = fm.frf(np.linspace(1.0, 4.0, 7))  # near the suspension modes the reactions are large
    ok = dim.solve(frf, fm.setup)
    assert abs(ok.mass_kg / 8089.0 - 1) < 1e-9
    acc_only = frf.select(outputs=frf.output_index("acceleration"))
    wrong = dim.solve(acc_only, fm.setup)
    assert abs(wrong.mass_kg / 8089.0 - 1) > 0.05


def test_reference_point_and_length_units_give_the_same_clean_answer() -> None:
    fm = calibration_mass(1)
    frf = fm.frf(BAND)
    base = dim.solve(frf, fm.setup)
    for unit in ("cm", "mm"):
        r = dim.solve(frf, fm.setup, length_unit=unit, reference_point_m=[0.1, -0.2, 0.3])
        assert max(_rel_errors(r, fm)) < 1e-9
        assert np.allclose(
            r.properties.inertia_cg_kgm2, base.properties.inertia_cg_kgm2, rtol=0, atol=1e-10
        )


def test_length_unit_weights_rows_on_noisy_data() -> None:
    fm = calibration_mass(2)
    frf = fm.frf(BAND)
    rng = np.random.default_rng(0)
    noisy = frf.replace(
        H=frf.H * (1 + 0.02 * (rng.normal(size=frf.H.shape) + 1j * rng.normal(size=frf.H.shape)))
    )
    m = [dim.solve(noisy, fm.setup, length_unit=u).mass_kg for u in ("m", "mm")]
    assert m[0] != pytest.approx(m[1], rel=1e-9)  # different weighting, different estimate
    assert all(abs(x / 18.175 - 1) < 0.05 for x in m)


@pytest.mark.slow
def test_every_subset_of_known_properties_is_exact() -> None:
    fm = calibration_mass(4)
    frf = fm.frf(np.linspace(20.0, 60.0, 5))
    system = dim.assemble(frf, fm.setup)
    truth = dict(zip(PARAMETERS, _truth(fm.properties, np.zeros(3)), strict=True))
    scale = np.r_[18.0, [0.3] * 3, [0.3] * 6]
    worst = 0.0
    n = 0
    for k in range(1, 10):
        for subset in itertools.combinations(PARAMETERS, k):
            r = dim.solve_system(
                system, known={p: truth[p] for p in subset}, check_plausibility=False
            )
            assert r.n_unknowns == 10 - k
            worst = max(
                worst, float(np.max(np.abs(r.parameters - np.array(list(truth.values()))) / scale))
            )
            n += 1
    assert n == 1022
    assert worst < 1e-9


def test_known_mass_and_cg_leave_only_inertia() -> None:
    fm = calibration_mass(5)
    frf = fm.frf(BAND)
    t = fm.properties
    known = {"m": t.mass_kg, "cx": t.cg_m[0], "cy": t.cg_m[1], "cz": t.cg_m[2]}
    r = dim.solve(frf, fm.setup, known=known)
    assert r.unknowns == ("Ixx", "Ixy", "Ixz", "Iyy", "Iyz", "Izz")
    assert np.allclose(r.inertia_p_kgm2, t.inertia_about(np.zeros(3)), atol=1e-12)


@pytest.mark.parametrize("kinds", [("acceleration", "reaction"), ("acceleration",)])
def test_frf_scaling_recovers_an_applied_factor_with_reactions(kinds: tuple) -> None:
    fm = calibration_mass(6)
    frf = fm.frf(np.linspace(1.0, 6.0, 11))  # near the bungee modes: reactions are large
    assert np.abs(frf.H[:, frf.output_index("reaction")]).max() > 0.1
    applied = 0.83
    gamma, result = dim.scale_to_known_mass(
        frf.scaled(applied, kinds), fm.setup, 18.175, kinds=kinds
    )
    assert gamma * applied == pytest.approx(1.0, abs=1e-6)
    assert result.mass_kg == pytest.approx(18.175, rel=1e-6)
    assert result.extras["frf_scale_factor"] == gamma


def test_weights_and_mean_method() -> None:
    fm = calibration_mass(7)
    frf = fm.frf(BAND)
    r = dim.solve(
        frf,
        fm.setup,
        method="mean",
        input_weights=np.linspace(0.5, 2.0, 24),
        line_weights=np.ones(21),
    )
    assert max(_rel_errors(r, fm)) < 1e-9
    with pytest.raises(SetupError, match="input_weights must be 24"):
        dim.solve(frf, fm.setup, input_weights=np.ones(3))


def test_inputs_that_do_not_excite_every_dof_are_refused() -> None:
    # Free-free body struck 24 times at one point along one line: every input gives the same
    # (real, up to a scalar) motion, 6 independent equations for 10 unknowns.
    fm = calibration_mass(8, support="free")
    same = Excitation(
        node=101, direction=1, position_m=(0.05, 0.0, -0.2), direction_gcs=(0.0, 0.0, 1.0)
    )
    exc = tuple(same.model_copy(update={"node": e.node}) for e in fm.setup.excitations)
    fm = ForwardModel(fm.properties, fm.setup.model_copy(update={"excitations": exc}), ())
    with pytest.raises(SolverError, match=r"rank [1-9] < 10 unknowns"):
        dim.solve(fm.frf(BAND), fm.setup)


def test_mismatches_between_frfs_and_setup_name_the_item() -> None:
    fm = calibration_mass(9)
    frf = fm.frf(BAND)
    stray = frf.replace(inputs=(Channel(999, 1), *frf.inputs[1:]))
    with pytest.raises(SetupError, match=r"input 999\+X of the FRFs has no line of action"):
        dim.solve(stray, fm.setup)
    setup = fm.setup.model_copy(update={"responses": fm.setup.responses[:-1]})
    with pytest.raises(SetupError, match=r"response 8\+Z of the FRFs is not in the setup"):
        dim.solve(frf, setup)
    few = frf.select(outputs=np.r_[np.arange(5), frf.output_index("reaction")])
    with pytest.raises(SetupError, match="rigid-body rank"):
        dim.solve(few, fm.setup)


def test_plausibility_flags_a_sign_error_and_reports_every_check() -> None:
    fm = calibration_mass(10, support="free")
    frf = fm.frf(BAND)
    good = dim.solve(frf, fm.setup)
    assert {d.code for d in good.diagnostics} >= {
        "mass_positive",
        "inertia_cg_positive_definite",
        "triangle_inequality",
        "cg_inside_hull",
        "condition",
    }
    assert all(d.ok for d in good.diagnostics)
    flipped = dim.solve(frf.scaled(-1.0), fm.setup)  # e.g. hammer polarity reversed
    bad = {d.code for d in flipped.diagnostics if not d.ok}
    assert "mass_positive" in bad and "inertia_cg_positive_definite" in bad


def test_result_json_has_the_contract_keys() -> None:
    fm = calibration_mass(11)
    data = dim.solve(fm.frf(BAND), fm.setup, band_hz=(25.0, 50.0)).to_json()
    for key in (
        "mass_kg",
        "cg_m",
        "inertia_p_kgm2",
        "inertia_cg_kgm2",
        "principal_moments_kgm2",
        "principal_axes",
        "reference_point_m",
        "band_hz",
        "diagnostics",
    ):
        assert key in data
    assert data["band_hz"] == [26.0, 50.0]
    assert np.asarray(data["inertia_p_kgm2"]).shape == (3, 3)


def _assemble_per_channel(frf, setup, u, p):  # type: ignore[no-untyped-def]
    """The assembly as written before #27: dictionary look-ups per channel, fancy-indexed
    gathers, one matmul per block; the reference the vectorised :func:`dim.assemble` must keep."""
    from dimacq.pipeline.rigid_body import (
        condense,
        force_vectors,
        load_cell_transform,
        response_matrix,
    )

    by_key = {(c.node, c.direction): c for c in setup.responses}
    acc_idx = frf.output_index("acceleration")
    pos, dirs = [], []
    for i in acc_idx:
        ch = frf.outputs[i]
        rc = by_key.get((ch.node, ch.direction)) or by_key.get((ch.node, -ch.direction))
        sign = 1.0 if rc.direction == ch.direction else -1.0
        pos.append(rc.position_m)
        dirs.append(sign * np.asarray(rc.direction_gcs, float))
    psi = response_matrix(np.asarray(pos) / u, np.asarray(dirs), p / u)
    cond = condense(psi)
    K = np.einsum("kc,lcj->lkj", cond.transform / u, frf.H[:, acc_idx, :])
    ex_key = {(e.node, e.direction): e for e in setup.excitations}
    in_pos, in_dir = [], []
    for ch in frf.inputs:
        ex = ex_key.get((ch.node, ch.direction)) or ex_key.get((ch.node, -ch.direction))
        sign = 1.0 if ex.direction == ch.direction else -1.0
        in_pos.append(ex.position_m)
        in_dir.append(sign * np.asarray(ex.direction_gcs, float))
    phi = force_vectors(np.asarray(in_pos) / u, np.asarray(in_dir), p / u)
    F = np.broadcast_to(phi[None].astype(complex), K.shape).copy()
    for lc in setup.load_cells:
        got = {
            frf.outputs[i].direction: i
            for i in frf.output_index("reaction")
            if frf.outputs[i].node == lc.node
        }
        sel = [got[k] if k in got else got[-k] for k in range(1, 7)]
        sgn = np.array([1.0 if k in got else -1.0 for k in range(1, 7)])
        scale = np.array([1, 1, 1, 1 / u, 1 / u, 1 / u]) * sgn
        T = load_cell_transform(
            np.asarray(lc.position_m) / u, lc.rotation_matrix, p / u, lc.sign_factor
        )
        F += np.einsum("kc,lcj->lkj", T * scale[None, :], frf.H[:, sel, :])
    return K, F / u, psi, phi


@pytest.mark.parametrize("shuffle", [False, True])
def test_vectorised_assembly_equals_the_per_channel_reference(shuffle: bool) -> None:
    """Two load cells (one on its support, directions given negative), responses and inputs
    stated with the opposite direction in the FRFs, outputs interleaved when shuffled (the
    gathers then cannot read a consecutive run): K, F, Ψ, φ to 1e-12 of the reference."""
    from dimacq.model.frf import FrfData
    from dimacq.model.setup import LoadCell, ResponseChannel, TestSetup

    rng = np.random.default_rng(27)
    resp, outs = [], []
    for t in range(6):
        r = rng.uniform(-0.3, 0.3, 3)
        q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
        for k in range(3):
            resp.append(
                ResponseChannel(
                    node=t + 1, direction=k + 1, position_m=tuple(r), direction_gcs=tuple(q[:, k])
                )
            )
            outs.append(Channel(t + 1, -(k + 1) if (t + k) % 4 == 0 else k + 1))
    exc, ins = [], []
    for j in range(9):
        d = rng.normal(size=3)
        exc.append(
            Excitation(
                node=100 + j,
                direction=1,
                position_m=tuple(rng.uniform(-0.3, 0.3, 3)),
                direction_gcs=tuple(d / np.linalg.norm(d)),
            )
        )
        ins.append(Channel(100 + j, -1 if j % 3 == 0 else 1))
    rot, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    rot *= np.sign(np.linalg.det(rot))
    cells = (
        LoadCell(node=500, position_m=(0.0, 0.1, -0.4)),
        LoadCell(
            node=501,
            position_m=(0.2, -0.1, -0.4),
            rotation=tuple(tuple(row) for row in rot),  # type: ignore[arg-type]
            sign="on_support",
        ),
    )
    setup = TestSetup(
        responses=tuple(resp), excitations=tuple(exc), load_cells=cells, length_unit="mm"
    )
    outs += [Channel(500, k) for k in range(1, 7)] + [Channel(501, -k) for k in range(1, 7)]
    kinds = ["acceleration"] * 18 + ["reaction"] * 12
    order = rng.permutation(30) if shuffle else np.arange(30)
    n_lines = 37
    H = rng.normal(size=(n_lines, 30, 9)) + 1j * rng.normal(size=(n_lines, 30, 9))
    frf = FrfData(
        np.linspace(10.0, 90.0, n_lines),
        H[:, order],
        tuple(outs[i] for i in order),
        tuple(kinds[i] for i in order),  # type: ignore[misc]
        tuple(ins),
    )
    p = np.array([0.01, -0.02, 0.03])
    system = dim.assemble(frf, setup, reference_point_m=p)
    K, F, psi, phi = _assemble_per_channel(frf, setup, 1e-3, p)
    for got, ref in ((system.K, K), (system.F, F), (system.psi, psi), (system.phi, phi)):
        assert np.max(np.abs(got - ref)) <= 1e-12 * np.max(np.abs(ref))
    assert system.load_cells == (500, 501)
    assert system.responses == tuple(frf.outputs[i] for i in frf.output_index("acceleration"))


def test_assembly_names_the_unmatched_channel() -> None:
    fm = calibration_mass(0)
    frf = fm.frf(BAND)
    acc = frf.output_index("acceleration")
    stray = frf.outputs[int(acc[3])]
    renamed = tuple(Channel(9999, c.direction) if c == stray else c for c in frf.outputs)
    with pytest.raises(SetupError, match=r"response 9999\S* of the FRFs is not in the setup"):
        dim.assemble(frf.replace(outputs=renamed), fm.setup)
    bad_in = (Channel(8888, 1),) + frf.inputs[1:]
    with pytest.raises(SetupError, match=r"input 8888\S* of the FRFs has no line of action"):
        dim.assemble(frf.replace(inputs=bad_in), fm.setup)


@pytest.mark.parametrize(
    "known",
    [{}, {"m": 18.0}, {"m": 18.0, "cx": 0.03}, {"cz": -0.08, "Ixy": 0.0}],
)
def test_solve_joint_is_solve_systems_joint_answer_to_the_bit(known: dict[str, float]) -> None:
    """The jackknife's joint-only solve: the same numbers, leave-one-out weights included."""
    fm = calibration_mass(0)
    rng = np.random.default_rng(5)
    frf = fm.frf(BAND)
    frf = frf.replace(H=frf.H * (1 + 0.01 * rng.standard_normal(frf.H.shape)))
    system = dim.assemble(frf, fm.setup)
    n_in = system.K.shape[2]
    for w in (None, np.r_[0.0, np.ones(n_in - 1)], rng.uniform(0.2, 2.0, n_in)):
        full = dim.solve_system(system, known=known, input_weights=w, check_plausibility=False)
        np.testing.assert_array_equal(
            dim.solve_joint(system, known=known, input_weights=w), full.parameters
        )


def test_solve_joint_refuses_what_solve_system_refuses() -> None:
    fm = calibration_mass(0)
    system = dim.assemble(fm.frf(BAND), fm.setup)
    none = np.zeros(system.K.shape[2])  # every input weighted out: rank 0
    for fn in (dim.solve_system, dim.solve_joint):
        with pytest.raises(SolverError, match="rank 0 < 10"):
            fn(system, input_weights=none)
        with pytest.raises(SetupError, match="every property is known"):
            fn(system, known=dict.fromkeys(PARAMETERS, 1.0))
