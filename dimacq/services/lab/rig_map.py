"""The rig's channel map (``rig.toml``, :mod:`dimacq.io.rig_file`): read, check and replace it.

The lab page shows the file (hammers, responses with their sensitivities, load cells) and lets
the engineer edit it as text: comments and layout are the engineer's, so the service keeps the
text as given; it is checked exactly as an acquisition would read it (:func:`load_rig_file`,
relative calibration paths resolved from the file's folder) before it replaces the file. The
previous version is kept beside it (``rig.toml.previous``). Every DAQ input the file names must
exist on the DAQ, when the DAQ has told how many it has. Once a file is written the DAQ and the
load cells are opened again with it (``on_written``): a device a bad file left disconnected is
back for the next acquisition.
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

from dimacq.config import Settings
from dimacq.errors import SetupError
from dimacq.io.rig_file import RigFile, parse_rig_text

__all__ = ["RigMapService", "dump_rig"]


class RigMapService:
    """The configured rig file (``settings.rig_path``)."""

    def __init__(
        self,
        settings: Settings,
        daq_inputs: Callable[[], int | None] = lambda: None,
        on_written: Callable[[], None] = lambda: None,
    ) -> None:
        self.path = settings.rig_path
        #: how many analogue inputs the DAQ has (its identity), None when not known
        self.daq_inputs = daq_inputs
        #: called after a new file replaced the old one
        self.on_written = on_written

    def read(self) -> dict[str, Any]:
        """``path``, ``text``, ``rig`` (the parsed map, or None) and ``error`` ("" when valid)."""
        try:
            text = self.path.read_text(encoding="utf-8")
        except OSError as err:
            return {"path": str(self.path), "text": "", "rig": None, "error": str(err)}
        try:
            rig = self.check(text)
        except SetupError as err:
            return {"path": str(self.path), "text": text, "rig": None, "error": str(err)}
        return {"path": str(self.path), "text": text, "rig": dump_rig(rig), "error": ""}

    def check(self, text: str) -> RigFile:
        """The map ``text`` describes, read as an acquisition reads it (nothing is written).

        Raises
        ------
        SetupError
            Not UTF-8 text, TOML syntax, an item that fails its check, or a DAQ input the DAQ
            does not have (the message names the item and the fix).
        """
        try:
            text.encode("utf-8")
        except UnicodeEncodeError as err:
            raise SetupError(
                f"text: not UTF-8 text at character {err.start}; send the rig file as written"
            ) from err
        rig = parse_rig_text(text, self.path)
        n = self.daq_inputs()
        if n is not None:
            for item, channel in _daq_inputs_used(rig):
                if not 0 <= channel < n:
                    raise SetupError(
                        f"rig file {rig.name}: item '{item}' = {channel}: the DAQ has {n} inputs "
                        f"(0..{n - 1}); fix: give an input 0..{n - 1}, the one the signal is "
                        "cabled to"
                    )
        return rig

    def write(self, text: str) -> dict[str, Any]:
        """Check ``text`` and replace the rig file with it (the old one kept as
        ``<name>.previous``); returns :meth:`read`'s answer for the new file.

        Raises
        ------
        SetupError
            The text fails its check, or the file's folder cannot be written (the message names
            the folder).
        """
        self.check(text)
        folder = self.path.parent
        tmp = ""
        try:
            fd, tmp = tempfile.mkstemp(prefix=".rig-new-", suffix=".toml", dir=folder)
            with os.fdopen(fd, "w", encoding="utf-8") as fh:
                fh.write(text)
                fh.flush()
                os.fsync(fh.fileno())
            if self.path.exists():
                _keep_previous(self.path)
            os.replace(tmp, self.path)
            tmp = ""
        except OSError as err:
            raise SetupError(
                f"rig file {self.path}: cannot write it ({err.strerror}); give the service write "
                f"access to {folder} or set rig_file (DIMACQ_RIG_FILE) to a writable copy"
            ) from err
        finally:
            if tmp:
                Path(tmp).unlink(missing_ok=True)
        self.on_written()
        return self.read()


def _daq_inputs_used(rig: RigFile) -> Iterator[tuple[str, int]]:
    """``(item, input)`` for every DAQ input the rig file names."""
    for i, h in enumerate(rig.hammers):
        yield f"hammers.{i}.physical_channel", h.physical_channel
    for i, r in enumerate(rig.responses):
        yield f"responses.{i}.physical_channel", r.physical_channel
    for i, lc in enumerate(rig.load_cells):
        for k, channel in enumerate(lc.daq_channels):
            yield f"load_cells.{i}.daq_channels.{k}", channel


def _keep_previous(path: Path) -> None:
    """Copy ``path`` to ``<name>.previous`` atomically: written to a new private file in the same
    folder, then renamed over it (a rename replaces a symbolic link planted at ``.previous``
    instead of writing through it)."""
    previous = path.with_name(path.name + ".previous")
    fd, tmp = tempfile.mkstemp(prefix=".rig-previous-", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(path.read_bytes())
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, previous)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def dump_rig(rig: RigFile) -> dict[str, Any]:
    out: dict[str, Any] = rig.model_dump(mode="json")
    out["responses"] = [
        {**r, "key": e.key} for r, e in zip(out["responses"], rig.responses, strict=True)
    ]
    return out
