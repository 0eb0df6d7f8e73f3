"""Progress of long command-line work, and help text from docstrings.

:class:`ProgressLine` writes to stderr: on a terminal one line that updates in place (``\\r``),
elsewhere (a pipe, a log file, CI) plain lines, at most one every few seconds and one per new
stage, so a log holds no carriage returns; each line has the fraction done and, once it can be
estimated, the time remaining. ``--quiet`` (:func:`add_quiet`) silences it; lines that must stay
(:meth:`ProgressLine.note`, e.g. a rejected hit) are kept on a terminal too.

:func:`plain` turns a module docstring (reStructuredText roles and literals) into the plain text of
``--help``.
"""

from __future__ import annotations

import argparse
import re
import shutil
import sys
import time
from collections.abc import Callable
from typing import TextIO

__all__ = ["ProgressLine", "add_quiet", "format_remaining", "plain"]


def format_remaining(seconds: float) -> str:
    """``"about 1 min 20 s left"``; seconds rounded to 5 s above a minute."""
    s = max(0, round(seconds))
    if s < 60:
        return f"about {s} s left"
    if s < 3600:
        m, r = divmod(5 * round(s / 5), 60)
        return f"about {m} min {r} s left" if r else f"about {m} min left"
    h, r = divmod(s, 3600)
    return f"about {h} h {r // 60} min left"


class ProgressLine:
    """Progress of one piece of work on ``stream`` (default stderr).

    Parameters
    ----------
    label : str
        Put before every line (e.g. ``"acquire"``).
    stream : text stream, optional
        Where to write; a terminal (``isatty()``) gets the updating line.
    quiet : bool
        Write nothing (notes too).
    every_s : float
        Plain-line mode: the least time between two lines of the same stage.
    clock : callable
        Seconds, monotonic (tests pass a fake clock).
    """

    def __init__(
        self,
        label: str = "",
        stream: TextIO | None = None,
        *,
        quiet: bool = False,
        every_s: float = 5.0,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.label = label
        self.stream = stream if stream is not None else sys.stderr
        self.quiet = quiet
        self.every_s = every_s
        self.clock = clock
        isatty = getattr(self.stream, "isatty", None)
        self.tty = bool(isatty and isatty())
        self._t0 = clock()
        self._last_t = -1e300
        self._last_stage = ""
        self._shown = 0  # characters of the updating line on screen

    # ------------------------------------------------------------------ text
    def _line(self, fraction: float, message: str) -> str:
        f = min(max(fraction, 0.0), 1.0)
        elapsed = self.clock() - self._t0
        parts = [f"{self.label}: " if self.label else "", f"{100 * f:5.1f} %"]
        if 0.02 <= f < 1.0 and elapsed >= 1.0:
            parts.append(f" ({format_remaining(elapsed * (1.0 - f) / f)})")
        if message:
            parts.append(f"  {message}")
        return "".join(parts)

    @staticmethod
    def _stage(message: str) -> str:
        """What makes a message a new stage (its text without numbers)."""
        return re.sub(r"[\d.]+", "#", message)

    # ------------------------------------------------------------------ writing
    def update(self, fraction: float, message: str = "") -> None:
        """Progress ``fraction`` (0..1) with the current ``message``."""
        if self.quiet:
            return
        now = self.clock()
        line = self._line(fraction, message)
        if self.tty:
            if now - self._last_t < 0.1 and fraction < 1.0:
                return  # a terminal redraws at most 10 times a second
            width = max(20, shutil.get_terminal_size((100, 20)).columns - 1)
            text = line[:width]
            self.stream.write("\r" + text + " " * max(0, self._shown - len(text)))
            self._shown = len(text)
        else:
            stage = self._stage(message)
            if stage == self._last_stage and now - self._last_t < self.every_s and fraction < 1.0:
                return
            self._last_stage = stage
            self.stream.write(line + "\n")
        self._last_t = now
        self.stream.flush()

    def note(self, text: str) -> None:
        """A line that stays (the updating line is redrawn below it on the next update)."""
        if self.quiet:
            return
        if self.tty and self._shown:
            self.stream.write("\r" + " " * self._shown + "\r")
            self._shown = 0
        self.stream.write(text + "\n")
        self.stream.flush()

    def close(self) -> None:
        """End the updating line (a terminal keeps its last state on its own line)."""
        if self.tty and self._shown and not self.quiet:
            self.stream.write("\n")
            self.stream.flush()
        self._shown = 0


def add_quiet(parser: argparse.ArgumentParser) -> None:
    """``-q/--quiet``: no progress output (results and errors still printed)."""
    parser.add_argument(
        "-q", "--quiet", action="store_true", help="no progress output (results and errors only)"
    )


_ROLE = re.compile(r":(?:func|class|meth|mod|data|attr|exc|obj|ref):`~?([^`]+)`")


def plain(doc: str | None) -> str:
    """A docstring as plain ``--help`` text: roles such as ``:func:`a.b``` become their target
    (its last part when written ``~a.b``), double-backquoted literals and ``**bold**`` their
    text, and a paragraph ending in ``::`` ends in ``:``."""
    if not doc:
        return ""

    def role(m: re.Match[str]) -> str:
        target = m.group(1)
        return target.rsplit(".", 1)[-1] if m.group(0).count("~") else target

    text = _ROLE.sub(role, doc)
    text = re.sub(r"``([^`]+)``", r"\1", text)
    text = re.sub(r"\*\*([^*]+)\*\*", r"\1", text)
    text = re.sub(r"(?m)::$", ":", text)
    return text
