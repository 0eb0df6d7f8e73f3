"""Results files: the evidence a study or benchmark under ``tests/scripts`` or ``tests/benchmarks``
writes beside itself, and the manual links.

A results file is markdown: a title, the command that produced it, the date (UTC), the commit
(``with uncommitted changes`` when the tracked files differ from it), the machine's cores and load
average at the start and at the end of the run, then the script's tables. It is rewritten by each
run (git keeps the earlier ones), or, with ``append=True``, holds one ``##`` section per run,
newest last, under a title written once. A script takes ``--results PATH`` so that a short trial
run can write elsewhere and leave the evidence of the last complete run in place.

    from _results import Results        # tests/ on sys.path
    res = Results(__file__, "Cross-check against the truth")
    res.table(["case", "mass %"], rows)
    res.write()

``write`` may be called again as the run goes on (after each demo of a long study): each call
writes the whole run so far, so a run cut short keeps what it measured.
"""

from __future__ import annotations

import datetime as dt
import os
import shlex
import subprocess
import sys
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]


def commit(cwd: Path = ROOT) -> str:
    """The short commit of ``cwd``, with ``(with uncommitted changes)`` when tracked files differ."""
    rev = subprocess.run(
        ["git", "rev-parse", "--short", "HEAD"], cwd=cwd, capture_output=True, text=True
    ).stdout.strip()
    dirty = subprocess.run(
        ["git", "status", "--porcelain", "--untracked-files=no"],
        cwd=cwd,
        capture_output=True,
        text=True,
    ).stdout.strip()
    return (rev or "unknown") + (" (with uncommitted changes)" if dirty else "")


def load() -> str:
    """The load average (1 / 5 / 15 min)."""
    return " / ".join(f"{v:.2f}" for v in os.getloadavg())


def markdown_table(header: Sequence[str], rows: Iterable[Sequence[Any]]) -> str:
    """A markdown table; cells are written with ``str`` (format numbers before)."""
    out = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    out += ["| " + " | ".join(str(c).replace("|", "\\|") for c in r) + " |" for r in rows]
    return "\n".join(out)


class Results:
    """One run's results file: the header taken at the start, sections added, written at the end.

    ``script`` is the calling script's ``__file__``; ``path`` defaults to ``<script>_results.md``
    beside it. With ``append`` the run becomes a ``## <label>: <date> UTC, commit <commit>``
    section added after the file's earlier runs (the title and a line naming the script are
    written when the file is new); ``commit`` and ``command`` may be set after construction when
    the run measures another tree or command.
    """

    def __init__(
        self,
        script: str | Path,
        title: str,
        path: Path | None = None,
        *,
        append: bool = False,
        label: str = "",
    ) -> None:
        self.script = Path(script).resolve()
        self.path = Path(path) if path else self.script.with_name(self.script.stem + "_results.md")
        self.title = title
        self.append = append
        self.label = label
        try:
            self.shown = self.script.relative_to(ROOT).as_posix()
        except ValueError:
            self.shown = str(self.script)
        self.command = " ".join(["python", self.shown, *map(shlex.quote, sys.argv[1:])])
        self.started = dt.datetime.now(dt.UTC)
        self.load_start = load()
        self.commit = commit()
        self.notes: list[str] = []
        self.sections: list[str] = []
        self._earlier: str | None = None

    def note(self, text: str) -> None:
        """A header line (``- text``) after the command: what was run where, settings, a label."""
        self.notes.append(f"- {text}")

    def add(self, text: str) -> None:
        """A paragraph (markdown) after the header, in the order added."""
        self.sections.append(text.rstrip())

    def table(self, header: Sequence[str], rows: Iterable[Sequence[Any]], title: str = "") -> None:
        """A table, under a heading when ``title`` is given (``##``, ``###`` in append mode)."""
        body = markdown_table(header, rows)
        level = "###" if self.append else "##"
        self.add(f"{level} {title}\n\n{body}" if title else body)

    def header(self) -> str:
        """Title (a run's ``##`` heading in append mode), command, date, commit, cores and load."""
        ended = dt.datetime.now(dt.UTC)
        minutes = (ended - self.started).total_seconds() / 60
        date = f"{self.started:%Y-%m-%d %H:%M} UTC"
        if self.append:
            prefix = f"{self.label}: " if self.label else ""
            first = [f"## {prefix}{date}, commit {self.commit}"]
        else:
            first = [f"# {self.title}"]
        return "\n".join(
            [
                *first,
                "",
                f"- command: `{self.command}`",
                *self.notes,
                f"- date: {date} ({minutes:.0f} min)",
                f"- commit: {self.commit}",
                f"- machine: {os.cpu_count()} cores; load average (1 / 5 / 15 min) "
                f"{self.load_start} at the start, {load()} at the end",
            ]
        )

    def text(self) -> str:
        """The whole file as this run leaves it."""
        run = "\n\n".join([self.header(), *self.sections]) + "\n"
        if not self.append:
            return run
        if self._earlier is None:
            old = self.path.read_text(encoding="utf-8") if self.path.exists() else ""
            if not old.strip():
                old = (
                    f"# {self.title}\n\nWritten by `{self.shown}`; one section per run, "
                    "newest last.\n"
                )
            self._earlier = old.rstrip("\n") + "\n\n"
        return self._earlier + run

    def write(self) -> Path:
        """Write the file (replacing an earlier run's, or after them in append mode); say where."""
        text = self.text()
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.path.write_text(text, encoding="utf-8")
        print(f"wrote {self.path}", flush=True)
        return self.path


def add_results_argument(parser: Any, script: str | Path) -> None:
    """``--results PATH`` on an argparse parser, defaulting to ``<script>_results.md``."""
    default = Path(script).resolve().with_name(Path(script).stem + "_results.md")
    parser.add_argument(
        "--results",
        type=Path,
        default=default,
        help=f"the results file to write (default {default.name} beside the script)",
    )


def fmt(x: float | None, spec: str = ".3f", unit: str = "") -> str:
    """A number for a table cell, ``—`` when absent."""
    if x is None:
        return "—"
    return f"{x:{spec}}{unit}"


__all__ = ["Results", "add_results_argument", "commit", "fmt", "load", "markdown_table"]
