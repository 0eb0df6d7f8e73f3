"""The package layout: the two mapped folders install under dimacq, never as top-level names."""

from __future__ import annotations

import os
import subprocess
import sys
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _packages_on_disk() -> set[str]:
    found: set[str] = set()
    for top, name in (
        ("dimacq", "dimacq"),
        ("drivers", "dimacq.drivers"),
        ("simulators", "dimacq.simulators"),
    ):
        base = ROOT / top
        for init in base.rglob("__init__.py"):
            rel = init.parent.relative_to(base)
            found.add(".".join((name, *rel.parts)) if rel.parts else name)
    return found


def test_every_package_is_listed_in_pyproject() -> None:
    config = tomllib.loads((ROOT / "pyproject.toml").read_text())
    listed = set(config["tool"]["setuptools"]["packages"])
    missing = _packages_on_disk() - listed
    assert not missing, (
        f"add these to [tool.setuptools] packages in pyproject.toml: {sorted(missing)}"
    )
    stale = listed - _packages_on_disk()
    assert not stale, f"pyproject lists packages that do not exist: {sorted(stale)}"


def test_mapped_folders_import_under_dimacq_only(tmp_path: Path) -> None:
    # In a fresh interpreter outside the checkout (the checkout root on sys.path, as with
    # ``python -m pytest``, would make the bare folders importable by accident).
    code = (
        "import importlib.util as u, sys;"
        "assert u.find_spec('dimacq.drivers') and u.find_spec('dimacq.simulators');"
        "assert u.find_spec('drivers') is None, 'bare drivers resolves';"
        "assert u.find_spec('simulators') is None, 'bare simulators resolves'"
    )
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    proc = subprocess.run(
        [sys.executable, "-c", code], cwd=tmp_path, env=env, capture_output=True, text=True
    )
    assert proc.returncode == 0, proc.stderr


def test_top_level_is_fixed() -> None:
    allowed = {"pyproject.toml", "dimacq", "drivers", "simulators", "tests", "config", "README.md"}
    tracked = {p.name for p in ROOT.iterdir() if not p.name.startswith(".")}
    extra = tracked - allowed - {"dimacq.egg-info", "build", "dist", "data"}
    assert not extra, f"unexpected top-level entries: {sorted(extra)}"
