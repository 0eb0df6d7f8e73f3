"""Where the independent sample files live (``../shared/samples`` of the checkout or of its
worktree folder, or ``DIMACQ_SAMPLES_DIR``). Under CI (``CI=true``) they must be there: the tests
against them run, never skip, and a missing folder fails loudly."""

from __future__ import annotations

import os
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def samples_dir() -> Path:
    env = os.environ.get("DIMACQ_SAMPLES_DIR")
    cands = (
        [Path(env)]
        if env
        else [ROOT.parent / "shared" / "samples", ROOT.parents[1] / "shared" / "samples"]
    )
    for c in cands:
        if (c / "bracket_clean_binary.uff").is_file():
            return c
    if os.environ.get("CI", "").lower() in ("1", "true", "yes"):
        raise RuntimeError(
            f"CI=true but the shared sample files are not at {', '.join(map(str, cands))}; "
            "check out ../shared/samples or set DIMACQ_SAMPLES_DIR"
        )
    return cands[0]
