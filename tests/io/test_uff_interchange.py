"""UFF interchange: lossless round trips, pyuff reads what we write, refusals, units, samples.

Files for the refusal and unit tests are written with pyuff's own writer (not ours), so the reader
is checked against an independent producer; expected values are computed here by hand.
"""

from __future__ import annotations

import json
import logging
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import pyuff
from scipy.spatial.transform import Rotation

from dimacq.errors import DataError, SetupError
from dimacq.io.uff import read_frf_uff, read_uff_test, write_frf_uff, write_uff_test
from dimacq.model.frf import STANDARD_GRAVITY, Channel, FrfData
from dimacq.model.setup import Excitation, LoadCell, ResponseChannel, TestSetup


def _v(a: Any) -> tuple[float, float, float]:
    return (float(a[0]), float(a[1]), float(a[2]))


def _rot(*angles: float) -> np.ndarray:
    return Rotation.from_euler("zyx", angles, degrees=True).as_matrix()


# --------------------------------------------------------------------------------------------
# A synthetic test: aligned and skewed triaxes, a biaxial node, a single skewed channel, a
# driving point sharing a triax's node, skewed inputs, two rotated load cells (one "on_support").
# --------------------------------------------------------------------------------------------
def _setup(sign: str = "on_structure") -> TestSetup:
    r_skew = _rot(10, 20, 30)
    resp: list[ResponseChannel] = []
    for k in range(3):
        resp.append(
            ResponseChannel(
                node=1, direction=k + 1, position_m=(0.1, 0.2, 0.3), direction_gcs=_v(np.eye(3)[k])
            )
        )
    for k in range(3):
        resp.append(
            ResponseChannel(
                node=2,
                direction=k + 1,
                position_m=(-0.123456789012345, 0.2, 0.05),
                direction_gcs=_v(r_skew[:, k]),
            )
        )
    r_b = _rot(-40, 5, 0)
    resp.append(
        ResponseChannel(
            node=3, direction=1, position_m=(0.0, -0.2, 0.1), direction_gcs=_v(r_b[:, 0])
        )
    )
    resp.append(
        ResponseChannel(
            node=3, direction=-3, position_m=(0.0, -0.2, 0.1), direction_gcs=_v(-r_b[:, 2])
        )
    )
    d = np.array([1.0, -2.0, 0.5]) / np.linalg.norm([1.0, -2.0, 0.5])
    resp.append(
        ResponseChannel(node=4, direction=2, position_m=(0.3, 0.0, 0.0), direction_gcs=_v(d))
    )
    ex = (
        Excitation(
            node=1, direction=-3, position_m=(0.1, 0.2, 0.3), direction_gcs=(0.0, 0.0, -1.0)
        ),
        Excitation(
            node=21, direction=1, position_m=(0.2, 0.1, 0.0), direction_gcs=_v(_rot(30, 0, 0)[:, 0])
        ),
        Excitation(node=22, direction=2, position_m=(-0.2, 0.1, 0.0), direction_gcs=_v(-d)),
    )
    cells = (
        LoadCell(
            node=501, position_m=(0.0, 0.1, -0.06), rotation=tuple(_v(r) for r in _rot(45, 0, 0))
        ),  # type: ignore[arg-type]
        LoadCell(
            node=502,
            position_m=(0.0, -0.1, -0.06),
            rotation=tuple(_v(r) for r in _rot(-20, 10, 3)),  # type: ignore[arg-type]
            sign=sign,
        ),  # type: ignore[arg-type]
    )
    return TestSetup(name="synthetic", responses=tuple(resp), excitations=ex, load_cells=cells)


def _frf(setup: TestSetup, freqs: np.ndarray | None = None, seed: int = 1) -> FrfData:
    rng = np.random.default_rng(seed)
    f = np.arange(10.0, 150.0, 1.0) if freqs is None else freqs
    outputs = [Channel(c.node, c.direction) for c in setup.responses]
    kinds = ["acceleration"] * len(outputs)
    # interleave a reaction cell between accelerometers to check that order survives
    cell_out = [Channel(lc.node, k) for lc in setup.load_cells for k in (1, 2, 3, 4, 5, -6)]
    outputs = outputs[:4] + cell_out[:6] + outputs[4:] + cell_out[6:]
    kinds = kinds[:4] + ["reaction"] * 6 + kinds[4:] + ["reaction"] * 6
    inputs = [Channel(e.node, e.direction) for e in setup.excitations]
    shape = (f.size, len(outputs), len(inputs))
    mag = 10.0 ** rng.uniform(-9, 4, size=shape)
    H = mag * (rng.standard_normal(shape) + 1j * rng.standard_normal(shape))
    return FrfData(f, H, tuple(outputs), tuple(kinds), tuple(inputs))  # type: ignore[arg-type]


def _same_frf(a: FrfData, b: FrfData) -> None:
    assert a.outputs == b.outputs
    assert a.output_kinds == b.output_kinds
    assert a.inputs == b.inputs
    np.testing.assert_array_equal(a.frequencies_hz, b.frequencies_hz)


@pytest.mark.parametrize("binary", [True, False], ids=["binary", "ascii"])
def test_round_trip(tmp_path: Path, binary: bool) -> None:
    setup, frf = _setup(), None
    frf = _frf(setup)
    path = tmp_path / "test.uff"
    write_uff_test(path, setup, frf, binary=binary)
    setup2, frf2 = read_uff_test(path)
    assert setup2 == setup
    _same_frf(frf2, frf)
    if binary:
        np.testing.assert_array_equal(frf2.H, frf.H)
    else:  # UFF 4E20 layout, 14 significant digits
        np.testing.assert_allclose(frf2.H.real, frf.H.real, rtol=6e-14, atol=0)
        np.testing.assert_allclose(frf2.H.imag, frf.H.imag, rtol=6e-14, atol=0)


def test_uneven_axis_is_exact_in_binary(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    setup = _setup()
    f = 3.3 + np.arange(50) * 0.1234567891234
    frf = _frf(setup, f)
    with caplog.at_level(logging.WARNING, logger="dimacq.io.uff"):
        write_uff_test(tmp_path / "b.uff", setup, frf, binary=True)
    assert "uneven abscissa" in caplog.text
    _, frf2 = read_uff_test(tmp_path / "b.uff")
    np.testing.assert_array_equal(frf2.frequencies_hz, f)
    np.testing.assert_array_equal(frf2.H, frf.H)
    write_uff_test(tmp_path / "a.uff", setup, frf, binary=False)
    _, frf3 = read_uff_test(tmp_path / "a.uff")
    np.testing.assert_allclose(frf3.frequencies_hz, f, rtol=5e-8)  # 8 digits


def test_on_support_cell_is_written_as_on_structure(tmp_path: Path) -> None:
    setup = _setup(sign="on_support")
    frf = _frf(setup)
    write_uff_test(tmp_path / "t.uff", setup, frf)
    setup2, frf2 = read_uff_test(tmp_path / "t.uff")
    assert [lc.sign for lc in setup2.load_cells] == ["on_structure", "on_structure"]
    flip = np.array([-1.0 if c.node == 502 else 1.0 for c in frf.outputs])
    np.testing.assert_array_equal(frf2.H, frf.H * flip[None, :, None])


@pytest.mark.parametrize("binary", [True, False], ids=["binary", "ascii"])
def test_pyuff_reads_what_we_write(tmp_path: Path, binary: bool) -> None:
    setup = _setup()
    frf = _frf(setup)
    path = tmp_path / "t.uff"
    write_uff_test(path, setup, frf, binary=binary)
    sets = pyuff.UFF(str(path)).read_sets()
    types = [s["type"] for s in sets]
    assert types[:3] == [164, 2420, 2411]
    assert types[3:] == [58] * (len(frf.outputs) * len(frf.inputs))
    cs = {
        int(lab): m for lab, m in zip(sets[1]["CS_sys_labels"], sets[1]["CS_matrices"], strict=True)
    }
    nodes = sets[2]
    for ch in setup.responses:
        i = list(nodes["node_nums"]).index(ch.node)
        assert int(nodes["def_cs"][i]) == 0
        m = cs[int(nodes["disp_cs"][i])]
        np.testing.assert_array_equal([nodes["x"][i], nodes["y"][i], nodes["z"][i]], ch.position_m)
        np.testing.assert_array_equal(
            np.sign(ch.direction) * m[abs(ch.direction) - 1], ch.direction_gcs
        )
        np.testing.assert_allclose(m[:3] @ m[:3].T, np.eye(3), atol=1e-12)
    lc = setup.load_cells[0]
    i = list(nodes["node_nums"]).index(lc.node)
    np.testing.assert_array_equal(cs[int(nodes["disp_cs"][i])][:3], lc.rotation_matrix.T)
    rec = sets[3 + 5]  # input 0, output 5
    assert (rec["rsp_node"], rec["rsp_dir"]) == (frf.outputs[5].node, frf.outputs[5].direction)
    assert (rec["ref_node"], rec["ref_dir"]) == (frf.inputs[0].node, frf.inputs[0].direction)
    assert rec["func_type"] == 4 and rec["orddenom_spec_data_type"] == 13
    assert rec["ordinate_spec_data_type"] == 9  # outputs[5] is a load cell channel
    np.testing.assert_array_equal(rec["x"], frf.frequencies_hz)
    np.testing.assert_allclose(rec["data"], frf.H[:, 5, 0], rtol=0 if binary else 6e-14)


def test_write_frf_only_and_read_with_setup(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    setup = _setup()
    frf = _frf(setup)
    write_frf_uff(tmp_path / "f.uff", frf, binary=True)
    with pytest.raises(DataError, match="no coordinates"):
        read_uff_test(tmp_path / "f.uff")
    got = read_frf_uff(tmp_path / "f.uff", setup)
    # ordered as the setup: responses, then load cell records; inputs as excitations
    assert got.outputs[: len(setup.responses)] == tuple(
        Channel(c.node, c.direction) for c in setup.responses
    )
    for o, ch in enumerate(got.outputs):
        np.testing.assert_array_equal(got.H[:, o], frf.H[:, frf.outputs.index(ch)])
    # a setup with fewer channels: extra channels are ignored with a warning
    small = setup.model_copy(
        update={"responses": setup.responses[:6], "excitations": setup.excitations[1:]}
    )
    with caplog.at_level(logging.WARNING, logger="dimacq.io.uff"):
        got = read_frf_uff(tmp_path / "f.uff", small)
    assert "ignoring channels not in the setup" in caplog.text and "4+Y" in caplog.text
    assert got.H.shape == (frf.n_lines, 6 + 12, 2)
    # a setup channel without records is refused
    extra = ResponseChannel(node=9, direction=1, position_m=(0, 0, 0), direction_gcs=(1, 0, 0))
    bigger = setup.model_copy(update={"responses": (*setup.responses, extra)})
    with pytest.raises(DataError, match=r"response 9\+X has no FRF record"):
        read_frf_uff(tmp_path / "f.uff", bigger)


# --------------------------------------------------------------------------------------------
# Writer refusals
# --------------------------------------------------------------------------------------------
def test_writer_refuses_non_orthogonal_triax(tmp_path: Path) -> None:
    setup = _setup()
    bad = list(setup.responses)
    tilted = np.array([0.05, 1.0, 0.0]) / np.linalg.norm([0.05, 1.0, 0.0])  # 2.9° off +Y
    bad[1] = bad[1].model_copy(update={"direction_gcs": _v(tilted)})
    s = setup.model_copy(update={"responses": tuple(bad)})
    with pytest.raises(SetupError, match=r"node 1: the directions of .*1\+Y.* are not orthogonal"):
        write_uff_test(tmp_path / "x.uff", s, _frf(s))


def test_writer_refuses_left_handed_and_conflicts(tmp_path: Path) -> None:
    setup = _setup()
    bad = list(setup.responses)
    bad[5] = bad[5].model_copy(update={"direction_gcs": _v(-np.array(bad[5].direction_gcs))})
    s = setup.model_copy(update={"responses": tuple(bad)})
    with pytest.raises(SetupError, match=r"node 2: .*left-handed"):
        write_uff_test(tmp_path / "x.uff", s, _frf(s))
    bad = list(setup.responses)
    bad[1] = bad[1].model_copy(update={"position_m": (0.1, 0.2, 0.31)})
    s = setup.model_copy(update={"responses": tuple(bad)})
    with pytest.raises(SetupError, match=r"node 1: .* separate node numbers"):
        write_uff_test(tmp_path / "x.uff", s, _frf(s))
    frf = _frf(setup)
    with pytest.raises(SetupError, match=r"setup response 4\+Y has no FRF"):
        write_uff_test(
            tmp_path / "x.uff", setup, frf.select(outputs=np.arange(len(frf.outputs) - 7))
        )


# --------------------------------------------------------------------------------------------
# Files from pyuff's writer: refusals and units
# --------------------------------------------------------------------------------------------
def _rec(
    node: int,
    d: int,
    ref: int,
    rd: int,
    data: np.ndarray,
    f: np.ndarray,
    *,
    o_type: int = 12,
    unit: str = "NONE",
    binary: int = 0,
) -> dict[str, Any]:
    return {
        "type": 58,
        "binary": binary,
        "func_type": 4,
        "rsp_node": node,
        "rsp_dir": d,
        "ref_node": ref,
        "ref_dir": rd,
        "ordinate_spec_data_type": o_type,
        "orddenom_spec_data_type": 13,
        "abscissa_spec_data_type": 18,
        "ordinate_axis_units_lab": unit,
        "abscissa_spacing": 1,
        "data": np.asarray(data, dtype=complex),
        "x": f,
        "id1": "t",
        "rsp_ent_name": "a",
        "ref_ent_name": "a",
    }


def _nodes(
    nums: list[int], xyz: np.ndarray, disp: list[int] | None = None, dfn: list[int] | None = None
) -> dict[str, Any]:
    n = len(nums)
    return {
        "type": 2411,
        "node_nums": np.array(nums),
        "def_cs": np.array(dfn or [0] * n),
        "disp_cs": np.array(disp or [0] * n),
        "color": np.ones(n, dtype=int),
        "x": xyz[:, 0],
        "y": xyz[:, 1],
        "z": xyz[:, 2],
    }


def _cs2420(labels: list[int], mats: list[np.ndarray]) -> dict[str, Any]:
    return {
        "type": 2420,
        "Part_UID": 1,
        "Part_Name": "p",
        "CS_sys_labels": labels,
        "CS_types": [0] * len(labels),
        "CS_colors": [8] * len(labels),
        "CS_names": [f"cs{k}" for k in labels],
        "CS_matrices": mats,
    }


def _pyuff_write(path: Path, sets: list[dict[str, Any]]) -> Path:
    pyuff.UFF(str(path)).write_sets(sets, mode="overwrite")
    return path


F = np.arange(1.0, 9.0)


def test_record_node_without_coordinates_is_refused(tmp_path: Path) -> None:
    p = _pyuff_write(
        tmp_path / "x.uff",
        [
            _nodes([1, 21], np.zeros((2, 3))),
            _rec(1, 1, 21, 1, F, F),
            _rec(7, 2, 21, 1, F, F),
        ],
    )
    with pytest.raises(DataError, match=r"record #3 .* node 7, which has no coordinates"):
        read_uff_test(p)


def test_mismatched_frequency_axes_name_both_records(tmp_path: Path) -> None:
    p = _pyuff_write(
        tmp_path / "x.uff",
        [
            _nodes([1, 21], np.zeros((2, 3))),
            _rec(1, 1, 21, 1, F, F),
            _rec(1, 2, 21, 1, F, F + 0.5),
        ],
    )
    with pytest.raises(
        DataError, match=r"record #3 .* has 8 lines 1\.5–8\.5 Hz .* record #2 .* 1–8 Hz"
    ):
        read_uff_test(p)


def test_nan_is_refused(tmp_path: Path) -> None:
    setup = _setup()
    frf = _frf(setup)
    path = tmp_path / "t.uff"
    write_uff_test(path, setup, frf, binary=False)
    text = path.read_text()
    head = f"{frf.outputs[1].name}/{frf.inputs[0].name}"
    i = text.index(head)
    first_data = text.index("\n", text.index("\n         0    0    0    0 NONE", i) + 1) + 1
    text = text[:first_data] + f"{'nan':>20}" + text[first_data + 20 :]
    path.write_text(text)
    with pytest.raises(DataError, match=r"t\.uff: FRF 1\+Y/1-Z has NaN or inf at 10 Hz"):
        read_uff_test(path)


def test_unknown_ordinate_type_is_refused(tmp_path: Path) -> None:
    p = _pyuff_write(
        tmp_path / "x.uff",
        [
            _nodes([1, 21], np.zeros((2, 3))),
            _rec(1, 1, 21, 1, F, F, o_type=2),
        ],
    )
    with pytest.raises(DataError, match=r"ordinate type 2 \(stress\) is not acceleration"):
        read_uff_test(p)


def test_missing_pair_is_refused(tmp_path: Path) -> None:
    p = _pyuff_write(
        tmp_path / "x.uff",
        [
            _nodes([1, 21, 22], np.zeros((3, 3))),
            _rec(1, 1, 21, 1, F, F),
            _rec(1, 2, 21, 1, F, F),
            _rec(1, 1, 22, 1, F, F),
        ],
    )
    with pytest.raises(DataError, match=r"no FRF for response 1\+Y / reference 22\+X"):
        read_uff_test(p)


def test_units_164_g_velocity_displacement_and_frames(tmp_path: Path) -> None:
    """mm/N units via 164, a g-labelled record, velocity and displacement FRFs, a node defined in a
    rotated system (def_cs) and a 2420 displacement system; expectations computed by hand."""
    L = 1000.0  # file length unit: mm (value_SI = value_file / 1000)
    rot = _rot(30, 0, 0)  # rows of the UFF matrix are local axes → matrix = rot.T
    origin_mm = np.array([100.0, 0.0, 50.0])
    cs = _cs2420([7], [np.vstack([rot.T, origin_mm])])
    nodes = _nodes(
        [1, 2, 501, 21],
        np.array([[10.0, 20.0, 30.0], [0.0, 0.0, 0.0], [5.0, 0.0, 0.0], [0.0, 0.0, 100.0]]),
        disp=[7, 0, 7, 0],
        dfn=[0, 7, 0, 0],
    )
    u164 = {
        "type": 164,
        "units_code": 9,
        "units_description": "mm newton",
        "temp_mode": 1,
        "length": L,
        "force": 1.0,
        "temp": 1.0,
        "temp_offset": 273.15,
    }
    w = 2 * np.pi * F
    a = np.linspace(1, 2, F.size) * (1 + 0.5j)
    sets = [
        u164,
        cs,
        nodes,
        _rec(1, 1, 21, 3, a, F),  # mm/s²/N
        _rec(1, 2, 21, 3, a, F, unit="g"),  # g/N
        _rec(1, 3, 21, 3, a, F, o_type=11),  # mm/s/N
        _rec(2, 1, 21, 3, a, F, o_type=8),  # mm/N
        _rec(501, 1, 21, 3, a, F, o_type=9),  # N/N
        _rec(501, 4, 21, 3, a, F, o_type=9),
    ]  # N·mm/N
    # the remaining directions of node 2 so it is a plain record set; load cell dirs 1 and 4 only
    p = _pyuff_write(tmp_path / "u.uff", sets)
    setup, frf = read_uff_test(p)
    H = frf.H[:, :, 0]
    np.testing.assert_allclose(H[:, 0], a / L, rtol=1e-10)
    np.testing.assert_allclose(H[:, 1], a * STANDARD_GRAVITY, rtol=1e-10)
    np.testing.assert_allclose(H[:, 2], 1j * w * a / L, rtol=1e-10)
    np.testing.assert_allclose(H[:, 3], -(w**2) * a / L, rtol=1e-10)
    np.testing.assert_allclose(H[:, 4], a, rtol=1e-10)
    np.testing.assert_allclose(H[:, 5], a / L, rtol=1e-10)
    assert frf.output_kinds == ("acceleration",) * 4 + ("reaction",) * 2
    r1 = setup.responses[0]
    np.testing.assert_allclose(r1.position_m, [0.01, 0.02, 0.03], rtol=1e-12)
    np.testing.assert_allclose(r1.direction_gcs, rot[:, 0], atol=1e-12)  # local x of system 7
    np.testing.assert_allclose(setup.responses[1].direction_gcs, rot[:, 1], atol=1e-12)
    # node 2 is defined at (0,0,0) of system 7 → GCS origin of that system, in metres
    np.testing.assert_allclose(setup.responses[3].position_m, origin_mm / L, atol=1e-12)
    np.testing.assert_allclose(setup.responses[3].direction_gcs, [1, 0, 0], atol=1e-12)
    lc = setup.load_cells[0]
    np.testing.assert_allclose(lc.rotation_matrix, rot, atol=1e-12)
    np.testing.assert_allclose(lc.position_m, [0.005, 0, 0], atol=1e-12)
    ex = setup.excitations[0]
    assert (ex.node, ex.direction) == (21, 3)
    np.testing.assert_allclose(ex.position_m, [0, 0, 0.1], atol=1e-12)


def test_dataset_18_systems(tmp_path: Path) -> None:
    """Node systems from dataset 18 (origin, +x point, +xz-plane point), nested in another one."""
    s18 = {
        "type": 18,
        "cs_num": [3, 4],
        "cs_type": [0, 0],
        "ref_cs_num": [0, 3],
        "color": [1, 1],
        "method": [1, 1],
        "cs_name": ["a", "b"],
        "ref_o": [[1.0, 0.0, 0.0], [0.0, 0.0, 0.0]],
        "x_point": [[1.0, 1.0, 0.0], [0.0, 0.0, 1.0]],  # system 3: x = +Y; system 4: x = its z
        "xz_point": [[1.0, 0.0, 1.0], [1.0, 0.0, 0.0]],
    }  # 3: z = +Z (y = -X); 4: xz-point on x_3
    p = _pyuff_write(
        tmp_path / "s.uff",
        [
            s18,
            _nodes(
                [1, 2, 21],
                np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0, 0, 1.0]]),
                disp=[3, 4, 0],
            ),
            _rec(1, 1, 21, 1, F, F),
            _rec(1, 2, 21, 1, F, F),
            _rec(2, 1, 21, 1, F, F),
            _rec(2, 3, 21, 1, F, F),
        ],
    )
    setup, _ = read_uff_test(p)
    d = {(c.node, c.direction): np.array(c.direction_gcs) for c in setup.responses}
    np.testing.assert_allclose(d[1, 1], [0, 1, 0], atol=1e-12)
    np.testing.assert_allclose(d[1, 2], [-1, 0, 0], atol=1e-12)
    # system 4 in system 3: x4 = z3 = +Z; its xz point lies along x3 = +Y, so z4 = +Y
    np.testing.assert_allclose(d[2, 1], [0, 0, 1], atol=1e-12)
    np.testing.assert_allclose(d[2, 3], [0, 1, 0], atol=1e-12)


def test_non_cartesian_and_missing_system_are_refused(tmp_path: Path) -> None:
    cs = _cs2420([5], [np.vstack([np.eye(3), np.zeros(3)])])
    cs["CS_types"] = [1]
    p = _pyuff_write(
        tmp_path / "c.uff",
        [cs, _nodes([1, 21], np.zeros((2, 3)), disp=[5, 0]), _rec(1, 1, 21, 1, F, F)],
    )
    with pytest.raises(DataError, match="system 5 is not Cartesian"):
        read_uff_test(p)
    p = _pyuff_write(
        tmp_path / "m.uff",
        [_nodes([1, 21], np.zeros((2, 3)), disp=[6, 0]), _rec(1, 1, 21, 1, F, F)],
    )
    with pytest.raises(DataError, match="node 1 uses displacement coordinate system 6, which no"):
        read_uff_test(p)


# --------------------------------------------------------------------------------------------
# Samples from an independent writer
# --------------------------------------------------------------------------------------------
def _samples_dir() -> Path:
    from _samples import samples_dir

    return samples_dir()


SAMPLES = _samples_dir()
needs_samples = pytest.mark.skipif(
    not (SAMPLES / "bracket_clean_binary.uff").is_file(), reason=f"samples not found at {SAMPLES}"
)


@needs_samples
def test_samples_structure_and_binary_equals_ascii() -> None:
    sb, fb = read_uff_test(SAMPLES / "bracket_clean_binary.uff")
    sa, fa = read_uff_test(SAMPLES / "bracket_clean_ascii.uff")
    for s, f in ((sb, fb), (sa, fa)):
        assert len(s.responses) == 18 and len({c.node for c in s.responses}) == 6
        assert len(s.excitations) == 12 and len(s.load_cells) == 2
        assert f.H.shape == (140, 18 + 12, 12)
        np.testing.assert_array_equal(f.frequencies_hz, np.arange(10.0, 150.0))
        assert [lc.sign for lc in s.load_cells] == ["on_structure"] * 2
        assert {c.node for c in f.outputs if c.node > 500} == {501, 502}
    assert sa == sb
    assert fa.outputs == fb.outputs and fa.inputs == fb.inputs
    # the ASCII sample carries 12 significant digits (pyuff's E20.11)
    np.testing.assert_allclose(fa.H, fb.H, rtol=1e-10, atol=1e-11 * np.abs(fb.H).max())


@needs_samples
def test_sample_geometry_against_raw_pyuff() -> None:
    setup, _ = read_uff_test(SAMPLES / "bracket_clean_binary.uff")
    sets = pyuff.UFF(str(SAMPLES / "bracket_clean_binary.uff")).read_sets([0, 1])
    cs = {int(k): m for k, m in zip(sets[0]["CS_sys_labels"], sets[0]["CS_matrices"], strict=True)}
    nodes = sets[1]
    idx = {int(n): i for i, n in enumerate(nodes["node_nums"])}
    for c in setup.responses:
        m = cs[int(nodes["disp_cs"][idx[c.node]])]
        np.testing.assert_array_equal(c.direction_gcs, m[c.direction - 1])
        np.testing.assert_array_equal(c.position_m, [nodes[k][idx[c.node]] for k in "xyz"])
    for e in setup.excitations:
        np.testing.assert_array_equal(e.direction_gcs, cs[int(nodes["disp_cs"][idx[e.node]])][0])
    for lc in setup.load_cells:
        np.testing.assert_array_equal(
            lc.rotation_matrix, cs[int(nodes["disp_cs"][idx[lc.node]])][:3].T
        )
    truth = json.loads((SAMPLES / "bracket_truth.json").read_text())
    assert truth["mass_kg"] > 0


@needs_samples
def test_noisy_sample_reads() -> None:
    s, f = read_uff_test(SAMPLES / "bracket_noisy_ascii.uff")
    assert f.H.shape == (140, 30, 12)
    assert len(s.responses) == 18


@needs_samples
@pytest.mark.parametrize("name", ["bracket_clean_binary.uff", "bracket_clean_ascii.uff"])
def test_samples_solve_to_truth(name: str) -> None:
    """End to end with the DIM solver: the geometry read from the file must be the truth's."""
    from dimacq.pipeline.dim import solve

    truth = json.loads((SAMPLES / "bracket_truth.json").read_text())
    setup, frf = read_uff_test(SAMPLES / name)
    res = solve(frf, setup).to_json()
    assert res["mass_kg"] == pytest.approx(truth["mass_kg"], rel=1e-9)
    np.testing.assert_allclose(res["cg_m"], truth["cg_m"], atol=1e-9 * 0.2)
    scale = np.abs(truth["inertia_p_kgm2"]).max()
    np.testing.assert_allclose(res["inertia_p_kgm2"], truth["inertia_p_kgm2"], atol=1e-9 * scale)
