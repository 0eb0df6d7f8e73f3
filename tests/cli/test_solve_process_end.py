"""``dimacq solve`` run as the program ends its process itself (issue #27): the report, the
JSON file and the exit status are all there; called with arguments, ``main`` returns."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from dimacq.cli.main import FAST_EXIT_COMMANDS, main

EXAMPLES = Path(__file__).resolve().parents[2] / "config" / "examples"


@pytest.mark.slow
def test_solve_as_a_program_writes_everything_before_it_ends(tmp_path: Path) -> None:
    out = tmp_path / "sol.json"
    cmd = [sys.executable, "-m", "dimacq.cli.main", "solve"]
    files = [str(EXAMPLES / "six_triax_setup.toml"), str(EXAMPLES / "six_triax_frf.uff")]
    proc = subprocess.run(
        [*cmd, *files, "--json", str(out)], capture_output=True, text=True, timeout=300
    )
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.rstrip().endswith("verdict: OK")  # the last line of the report
    assert json.loads(out.read_text())["verdict"] == "ok"
    bad = subprocess.run(
        [*cmd, str(tmp_path / "missing.uff")], capture_output=True, text=True, timeout=300
    )
    assert bad.returncode == 2
    assert "missing.uff does not exist" in bad.stderr


def test_main_called_with_arguments_returns(tmp_path: Path, capsys) -> None:  # type: ignore[no-untyped-def]
    assert "solve" in FAST_EXIT_COMMANDS
    rc = main(["solve", str(tmp_path / "missing.uff")])
    assert rc == 2  # still running: the process was not ended
    assert "does not exist" in capsys.readouterr().err
