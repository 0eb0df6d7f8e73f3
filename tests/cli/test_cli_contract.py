"""The command line a lab can live with (issue 13): help text without docstring markup on every
subcommand, one progress line on a terminal and plain lines elsewhere with the time remaining,
``--quiet``, every scenario listed with its nodes on request, one name per concept."""

from __future__ import annotations

import argparse
import io
import re
from pathlib import Path

import pytest

from dimacq.cli.main import build_parser, main
from dimacq.cli.progress import ProgressLine, format_remaining, plain
from dimacq.simulators.lab.scenarios import SCENARIO_DIR, build_scenario

MARKUP = re.compile(r"``|:(?:func|class|meth|mod|data|attr|exc|obj):`|::\s*$|\*\*\w", re.M)


def _subparsers(parser: argparse.ArgumentParser, path: tuple[str, ...] = ()):
    yield path, parser
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield from _subparsers(sub, (*path, name))


def test_every_help_is_plain_text(capsys: pytest.CaptureFixture[str]) -> None:
    seen = []
    for path, _parser in _subparsers(build_parser()):
        with pytest.raises(SystemExit) as ex:
            main([*path, "--help"])
        assert ex.value.code == 0
        text = capsys.readouterr().out
        bad = MARKUP.findall(text)
        assert not bad, (path, bad, text[:400])
        seen.append(" ".join(path))
    for must in ("acquire", "demo", "serve", "simulate", "solve", "loadcell calibrate"):
        assert must in seen, seen


def test_plain_turns_roles_and_literals_into_text() -> None:
    doc = "Uses :func:`dimacq.services.acquisition.rig.build_rig` and :class:`~a.b.Rig`; ``--data-dir``.\n\n    x::"
    assert (
        plain(doc)
        == "Uses dimacq.services.acquisition.rig.build_rig and Rig; --data-dir.\n\n    x:"
    )


class _Clock:
    def __init__(self) -> None:
        self.t = 0.0

    def __call__(self) -> float:
        return self.t


class _Tty(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_progress_is_plain_lines_off_a_terminal_with_the_time_left() -> None:
    out, clock = io.StringIO(), _Clock()
    p = ProgressLine("acquire", out, clock=clock, every_s=5.0)
    for k in range(101):  # one update a second, the same stage
        clock.t = float(k)
        p.update(k / 100, f"strike input 1 (average {k})")
    p.close()
    text = out.getvalue()
    assert "\r" not in text
    lines = text.splitlines()
    assert 15 <= len(lines) <= 25, lines  # throttled to one line every 5 s, and the last one
    assert lines[0].startswith("acquire:   0.0 %")
    assert "(about 50 s left)" in next(x for x in lines if " 50.0 %" in x)
    assert lines[-1].startswith("acquire: 100.0 %") and "left" not in lines[-1]
    # a new stage is written at once
    out2 = io.StringIO()
    q = ProgressLine("", out2, clock=clock)
    q.update(0.1, "input 1")
    q.update(0.2, "input 1")
    q.update(0.3, "load cell 2")
    assert [x.split("%")[1].strip() for x in out2.getvalue().splitlines()] == [
        "input 1",
        "load cell 2",
    ]


def test_progress_is_one_updating_line_on_a_terminal() -> None:
    out, clock = _Tty(), _Clock()
    p = ProgressLine("demo", out, clock=clock)
    for k in range(1, 11):
        clock.t = float(k)
        p.update(k / 10, "working")
        if k == 5:
            p.note("input 3 rejected: double hit")
    p.close()
    text = out.getvalue()
    assert text.count("\n") == 2  # the note, and the end of the line
    assert text.count("\r") >= 10
    assert "input 3 rejected: double hit\n" in text
    assert text.rstrip("\n").split("\r")[-1].startswith("demo: 100.0 %")


def test_quiet_writes_nothing() -> None:
    out = _Tty()
    p = ProgressLine("x", out, quiet=True)
    p.update(0.5, "half")
    p.note("a note")
    p.close()
    assert out.getvalue() == ""


def test_format_remaining() -> None:
    assert format_remaining(42.4) == "about 42 s left"
    assert format_remaining(83) == "about 1 min 25 s left"
    assert format_remaining(3 * 3600 + 600) == "about 3 h 10 min left"


def test_every_scenario_is_listed_with_its_nodes_on_request(
    capsys: pytest.CaptureFixture[str],
) -> None:
    assert main(["simulate", "--list"]) == 0
    listed = capsys.readouterr().out
    files = sorted(p.stem for p in Path(SCENARIO_DIR).glob("*.toml"))
    assert len(files) >= 9
    for name in files:
        assert re.search(rf"^{re.escape(name)}\s", listed, re.M), name
    assert main(["simulate", "calibration-mass-bungee", "--nodes"]) == 0
    text = capsys.readouterr().out
    setup = build_scenario("calibration-mass-bungee").setup
    for e in setup.excitations:
        assert re.search(rf"^\s+{e.node}\s+\(", text, re.M), e.node
    for c in setup.responses:
        assert f"({c.node}{'+-'[c.direction < 0]}{'XYZ'[abs(c.direction) - 1]})" in text
    for lc in setup.load_cells:
        assert re.search(rf"^\s+{lc.node}\s+\(", text, re.M)
    assert "−X" in text  # where to strike, in words
    assert main(["simulate", "--nodes"]) == 2


def test_one_name_per_concept_on_the_command_line(capsys: pytest.CaptureFixture[str]) -> None:
    parser = build_parser()
    acquire = dict(_subparsers(parser))[("acquire",)]
    args = acquire.parse_args(
        ["s", "--averages-per-input", "3", "--frf", "a.uff", "--data-dir", "d"]
    )
    old = acquire.parse_args(["s", "--impacts-per-input", "3", "--frf", "a.uff", "--data", "d"])
    assert (
        (args.impacts_per_input, args.data) == (old.impacts_per_input, old.data) == (3, Path("d"))
    )
    demo = dict(_subparsers(parser))[("demo",)]
    assert demo.parse_args(["--averages-per-input", "2"]).averages == 2
    assert demo.parse_args(["--averages", "2"]).averages == 2
    for path in (("acquire",), ("demo",), ("loadcell", "calibrate")):
        sub = dict(_subparsers(parser))[path]
        assert "--quiet" in sub.format_help(), path
