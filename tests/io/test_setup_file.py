"""Setup files: TOML/JSON round trips, the bundled example, and refusals naming file, item, fix."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from dimacq.errors import SetupError
from dimacq.io.setup_file import dump_setup_dict, load_setup, parse_setup, save_setup
from dimacq.model.setup import (
    Excitation,
    KnownProperties,
    LoadCell,
    ResponseChannel,
    TestSetup,
)

EXAMPLE = Path(__file__).resolve().parents[2] / "config" / "examples" / "six_triax_setup.toml"


def _v(a: np.ndarray) -> tuple[float, float, float]:
    return (float(a[0]), float(a[1]), float(a[2]))


def _setup() -> TestSetup:
    rot = Rotation.from_euler("zyx", [10, 20, 30], degrees=True).as_matrix()
    responses = [
        ResponseChannel(
            node=1 + k // 3,
            direction=k % 3 + 1,
            position_m=(0.1 * k, -0.2, 0.3),
            direction_gcs=_v(rot[:, k % 3]),
            label=f"r{k}",
        )
        for k in range(6)
    ]
    return TestSetup(
        name="round trip",
        reference_point_m=(0.1, 0.2, -0.3),
        length_unit="mm",
        responses=tuple(responses),
        excitations=(
            Excitation(
                node=21, direction=-2, position_m=(0.0, 0.1, 0.2), direction_gcs=(0.6, 0.8, 0.0)
            ),
        ),
        load_cells=(
            LoadCell(
                node=501,
                position_m=(0.0, 0.0, -0.1),
                rotation=tuple(_v(r) for r in rot),  # type: ignore[arg-type]
                sign="on_support",
            ),
        ),
        known=KnownProperties(m=3.2, cx=0.01, cz=-0.02, Ixy=-0.001),
    )


@pytest.mark.parametrize("suffix", [".toml", ".json"])
def test_round_trip_is_equal(tmp_path: Path, suffix: str) -> None:
    setup = _setup()
    path = tmp_path / f"setup{suffix}"
    save_setup(setup, path)
    assert load_setup(path) == setup


def test_round_trip_without_known(tmp_path: Path) -> None:
    setup = _setup().model_copy(update={"known": KnownProperties()})
    save_setup(setup, tmp_path / "s.toml")
    assert "known" not in (tmp_path / "s.toml").read_text()
    assert load_setup(tmp_path / "s.toml") == setup


def test_old_keys_are_read_as_the_parameter_names(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """Setup files of the first vocabulary (``[[excitations]]``, ``mass_kg``, ``cg_m`` as a TOML
    table or a JSON list with nulls, ``inertia_kgm2``) mean what the parameter names say, with a
    deprecation message naming the new keys; a setup is written in the new keys only."""
    responses = (
        "[[responses]]\nnode = 1\ndirection = 1\nposition_m = [0, 0, 0]\n"
        "direction_gcs = [1, 0, 0]\n"
    )
    inp = "node = 2\nposition_m = [0, 0, 0]\ndirection_gcs = [0, 0, 1]\n"
    new = responses + "[[inputs]]\n" + inp + "[known]\nm = 2.0\ncx = 0.5\ncz = -1.0\nIxy = 0.25\n"
    old = (
        responses
        + "[[excitations]]\n"
        + inp
        + "[known]\nmass_kg = 2.0\ncg_m = {x = 0.5, z = -1.0}\ninertia_kgm2 = {Ixy = 0.25}\n"
    )
    (tmp_path / "new.toml").write_text(new)
    (tmp_path / "old.toml").write_text(old)
    with caplog.at_level("WARNING"):
        a = load_setup(tmp_path / "old.toml")
    assert "[[excitations]] is the old name of [[inputs]]" in caplog.text
    assert "mass_kg, cg_m, inertia_kgm2 are the old keys" in caplog.text and "cx" in caplog.text
    caplog.clear()
    with caplog.at_level("WARNING"):
        b = load_setup(tmp_path / "new.toml")
    assert caplog.text == ""
    assert a == b and b.known.as_dict() == {"m": 2.0, "cx": 0.5, "cz": -1.0, "Ixy": 0.25}
    assert b.known.cg_m == (0.5, None, -1.0)  # the grouped view for Python callers
    # JSON of the first vocabulary: cg_m as a list with null
    doc = json.loads(json.dumps(dump_setup_dict(b)))
    assert doc["known"] == {"m": 2.0, "cx": 0.5, "cz": -1.0, "Ixy": 0.25} and "inputs" in doc
    doc["excitations"] = doc.pop("inputs")
    doc["known"] = {"mass_kg": 2.0, "cg_m": [0.5, None, -1.0], "inertia_kgm2": {"Ixy": 0.25}}
    (tmp_path / "old.json").write_text(json.dumps(doc))
    assert load_setup(tmp_path / "old.json") == b
    save_setup(a, tmp_path / "again.toml")
    text = (tmp_path / "again.toml").read_text()
    assert "[[inputs]]" in text and "excitations" not in text and "mass_kg" not in text
    with pytest.raises(SetupError, match="both inputs and excitations"):
        load_setup(_write(tmp_path, responses + "[[inputs]]\n" + inp + "[[excitations]]\n" + inp))


def test_bundled_example_loads() -> None:
    setup = load_setup(EXAMPLE)
    assert len(setup.responses) == 18
    assert len({c.node for c in setup.responses}) == 6
    assert len(setup.excitations) == 12
    assert len(setup.load_cells) == 2
    # each triax is a proper rotation (the UFF writer needs it)
    for node in range(1, 7):
        m = np.array([c.direction_gcs for c in setup.responses if c.node == node])
        assert np.allclose(m @ m.T, np.eye(3), atol=1e-12)
        assert np.linalg.det(m) > 0


def _write(tmp_path: Path, text: str, name: str = "bad.toml") -> Path:
    p = tmp_path / name
    p.write_text(text)
    return p


def _example_with(tmp_path: Path, old: str, new: str) -> Path:
    text = EXAMPLE.read_text()
    assert old in text
    return _write(tmp_path, text.replace(old, new, 1))


def test_non_unit_direction_names_file_item_and_fix(tmp_path: Path) -> None:
    # the 4th response (index 3) is node 2 direction 1
    p = _example_with(
        tmp_path,
        "node = 2\ndirection = 1\nposition_m = [-0.25, 0.2, 0.3]\ndirection_gcs = [1.0, 0.0, 0.0]",
        "node = 2\ndirection = 1\nposition_m = [-0.25, 0.2, 0.3]\ndirection_gcs = [2.0, 0.0, 0.0]",
    )
    with pytest.raises(SetupError) as exc:
        load_setup(p)
    msg = str(exc.value)
    assert str(p) in msg
    assert "responses[3]" in msg
    assert "unit vector" in msg


def test_missing_key_and_unknown_key(tmp_path: Path) -> None:
    p = _example_with(tmp_path, "position_m = [0.25, 0.2, 0.3]\n", "")
    with pytest.raises(
        SetupError, match=r"responses\[0\]\.position_m: Field required; add this key"
    ):
        load_setup(p)
    p = _example_with(
        tmp_path, "[[load_cells]]\nnode = 501\n", "[[load_cells]]\nnode = 501\nsgn = 1\n"
    )
    with pytest.raises(SetupError, match=r"load_cells\[0\]\.sgn: .*remove this key"):
        load_setup(p)


def test_wrong_vector_length_and_type(tmp_path: Path) -> None:
    p = _example_with(
        tmp_path, "reference_point_m = [0.0, 0.0, 0.0]", "reference_point_m = [0.0, 0.0]"
    )
    with pytest.raises(SetupError, match=r"reference_point_m.*3 numbers"):
        load_setup(p)
    p = _example_with(tmp_path, 'length_unit = "m"', 'length_unit = "inch"')
    with pytest.raises(SetupError, match=r"length_unit"):
        load_setup(p)


def test_left_handed_load_cell_is_refused(tmp_path: Path) -> None:
    p = _example_with(
        tmp_path,
        "rotation = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]",
        "rotation = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, -1.0]]",
    )
    with pytest.raises(SetupError, match=r"load_cells\[0\].*proper rotation"):
        load_setup(p)


def test_syntax_errors_and_paths(tmp_path: Path) -> None:
    with pytest.raises(SetupError, match="not valid TOML"):
        load_setup(_write(tmp_path, "name = \n"))
    with pytest.raises(SetupError, match=r"not valid JSON.*line 1"):
        load_setup(_write(tmp_path, "{name: 1}", "bad.json"))
    with pytest.raises(SetupError, match=r"use a .toml or .json"):
        load_setup(_write(tmp_path, "", "setup.yaml"))
    with pytest.raises(SetupError, match="cannot read"):
        load_setup(tmp_path / "missing.toml")
    with pytest.raises(SetupError, match="top level must be a table"):
        parse_setup([1, 2], "x")  # type: ignore[arg-type]
    with pytest.raises(SetupError, match=r"known.cg_m has unknown key"):
        load_setup(_write(tmp_path, "[known]\ncg_m = {w = 1.0}\n"))
