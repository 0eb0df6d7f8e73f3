"""The chain calibration recorded in a rig file: the hammer's used sensitivity, compounding of a
re-calibration, comments kept, ambiguous rigs refused."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from dimacq.errors import SetupError
from dimacq.io.rig_file import load_rig_file, write_chain_calibration

CONFIG = Path(__file__).resolve().parents[2] / "config"


def test_write_compound_and_keep_comments(tmp_path: Path) -> None:
    rig = tmp_path / "rig.toml"
    shutil.copy(CONFIG / "rig.toml", rig)
    (tmp_path / "calibrations").mkdir()
    shutil.copy(CONFIG / "calibrations" / "lc-501.json", tmp_path / "calibrations")
    # the shipped rig file records the lab's chain calibration: start from the certificate alone
    lines = rig.read_text().splitlines()
    rig.write_text("\n".join(ln for ln in lines if not ln.startswith("chain_calibration")) + "\n")
    base = load_rig_file(rig).hammers[0]
    assert base.chain_calibration is None
    assert base.effective_sensitivity_mv_per_n == base.sensitivity_mv_per_n
    first = write_chain_calibration(rig, 1.02, 0.0015, source="block A", date="2026-01-02")
    h = first.hammers[0]
    assert h.chain_calibration is not None and h.chain_calibration.factor == pytest.approx(1.02)
    assert h.effective_sensitivity_mv_per_n == pytest.approx(1.02 * base.sensitivity_mv_per_n)
    # measured again on data the rig already scaled by 1.02: the factors compound
    again = write_chain_calibration(rig, 0.999, 0.0012, source="block A", date="2026-02-03")
    c = again.hammers[0].chain_calibration
    assert c is not None and c.factor == pytest.approx(1.02 * 0.999, rel=1e-7)
    assert c.u_rel == pytest.approx(0.0012) and c.date == "2026-02-03"
    after = rig.read_text()
    assert after.count("chain_calibration") == 1  # replaced, not appended
    assert after.splitlines()[0].startswith("# Channel map")  # the file's comments stay
    with pytest.raises(SetupError, match="outside"):
        write_chain_calibration(rig, 1.09, 0.001, source="x", date="d")
    assert load_rig_file(rig).hammers[0].chain_calibration == c  # unchanged after a refusal


def test_two_hammers_refused(tmp_path: Path) -> None:
    rig = tmp_path / "rig.toml"
    text = (CONFIG / "rigs" / "cube.toml").read_text()
    block = text[text.index("[[hammers]]") : text.index("[acquisition]")]
    rig.write_text(
        text.replace(
            block, block + block.replace("physical_channel = 0", "physical_channel = 30", 1)
        )
    )
    with pytest.raises(SetupError, match="2 \\[\\[hammers\\]\\]"):
        write_chain_calibration(rig, 1.01, 0.001, source="x", date="d")
