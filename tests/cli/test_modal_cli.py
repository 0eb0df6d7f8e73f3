"""``dimacq solve --modal-correction``: the flag, the JSON key and the text on a flexible
vehicle written by ``dimacq simulate`` (model FRFs), as a user would run them."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from dimacq.cli.main import main


@pytest.mark.slow
def test_modal_correction_on_and_off_from_the_command_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    uff, truth_p = tmp_path / "v.uff", tmp_path / "t.json"
    assert main(["simulate", "x38-flexible-34", "--frf", str(uff), "--truth", str(truth_p)]) == 0
    capsys.readouterr()
    fast = ["--no-unbiased", "--no-geometry-uncertainty"]
    on, off = tmp_path / "on.json", tmp_path / "off.json"
    assert main(["solve", str(uff), "--json", str(on), "--modal-correction", "on", *fast]) == 0
    text = capsys.readouterr().out
    assert "modal correction (on): modal correction applied" in text
    assert "correction / accelerance per line" in text
    main(["solve", str(uff), "--json", str(off), "--modal-correction", "off", *fast])
    capsys.readouterr()
    d_on, d_off = json.loads(on.read_text()), json.loads(off.read_text())
    truth = json.loads(truth_p.read_text())
    mc = d_on["modal_correction"]
    assert mc["applied"] and mc["mode"] == "on"
    assert [round(f) for f in mc["modes_removed_hz"]] == [34, 48]
    assert {"poles", "modes_kept_hz", "fit_range_hz", "correction_size", "se_modal_fit"} <= set(mc)
    assert "modal_correction" not in d_off
    err_on = np.linalg.norm(np.subtract(d_on["cg_m"], truth["cg_m"]))
    err_off = np.linalg.norm(np.subtract(d_off["cg_m"], truth["cg_m"]))
    assert err_on < 1e-3 < err_off
    assert abs(d_on["mass_kg"] / truth["mass_kg"] - 1) < 1e-3


def test_modal_correction_flag_refuses_other_values(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit):
        main(["solve", "x.uff", "--modal-correction", "maybe"])
    assert "--modal-correction" in capsys.readouterr().err
