"""``dimacq digitizer selftest``: JSON keys and pass/fail, over the URL handler and a real pty."""

import json

import pytest
from _digitizer_support import make_device

from dimacq.cli.main import main
from dimacq.simulators.digitizer.pty import PtyServer

KEYS = {
    "tip_rms_mm",
    "echoes_injected",
    "echoes_accepted",
    "jig_orientation_rms_deg",
    "triangulation_shots_per_second",
}


@pytest.mark.slow
def test_selftest_json(tmp_path, capsys):
    out = tmp_path / "st.json"
    rc = main(
        [
            "digitizer",
            "selftest",
            "--shots",
            "500",
            "--echo-rate",
            "0.1",
            "--jigs",
            "2",
            "--json",
            str(out),
        ]
    )
    data = json.loads(out.read_text())
    assert KEYS <= data.keys()
    assert rc == 0, capsys.readouterr().out
    assert data["shots"] == 500 and data["echoes_injected"] > 10 and data["echoes_accepted"] == 0
    assert data["tip_rms_mm"] <= 0.5 and data["jig_orientation_rms_deg"] <= 0.1
    text = capsys.readouterr().out
    assert "tip_rms_mm" in text and "PASS" in text and "Table 1" in text


@pytest.mark.slow
def test_selftest_over_a_pty(tmp_path, no_thread_leaks):
    with PtyServer(make_device(seed=4)) as server:
        out = tmp_path / "st.json"
        rc = main(
            [
                "digitizer",
                "selftest",
                "--port",
                server.path,
                "--shots",
                "100",
                "--jigs",
                "1",
                "--json",
                str(out),
            ]
        )
    assert rc == 0
    assert json.loads(out.read_text())["points"] == 20


def test_bad_input_is_one_clear_line(capsys):
    assert main(["digitizer", "selftest", "--echo-rate", "2"]) == 2
    assert "--echo-rate" in capsys.readouterr().err
    assert main(["digitizer", "selftest", "--port", "/dev/does-not-exist"]) == 2
    assert "cannot open '/dev/does-not-exist'" in capsys.readouterr().err
