"""Every command's help renders (argparse %-formats help strings: a stray % crashes ``--help``)."""

from __future__ import annotations

import argparse

import pytest

from dimacq.cli.main import build_parser


def _subparsers(parser: argparse.ArgumentParser) -> list[tuple[str, argparse.ArgumentParser]]:
    out: list[tuple[str, argparse.ArgumentParser]] = []
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                out.append((name, sub))
                out += [(f"{name} {n}", s) for n, s in _subparsers(sub)]
    return out


def test_every_command_has_help() -> None:
    parser = build_parser()
    names = [n for n, _ in _subparsers(parser)]
    for expected in (
        "solve",
        "simulate",
        "digitizer",
        "acquire",
        "loadcell",
        "sensitivity",
        "serve",
        "demo",
    ):
        assert expected in names, f"dimacq {expected} is missing"
    for name, sub in _subparsers(parser):
        text = sub.format_help()
        assert "usage:" in text, name
    assert "usage:" in parser.format_help()


@pytest.mark.parametrize("argv", [["--help"], ["solve", "--help"]])
def test_help_exits_zero(argv: list[str], capsys: pytest.CaptureFixture[str]) -> None:
    from dimacq.cli.main import main

    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 0
    assert "usage:" in capsys.readouterr().out
