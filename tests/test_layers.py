"""Architecture contracts (the import-linter idea, checked with ast so it needs no extra tool).

- numerical and model code (``dimacq/pipeline``, ``dimacq/model``) does no I/O, threading or HTTP
  and imports no device, service or API layer;
- nothing outside ``dimacq/api`` (and the CLI commands that start or drive the server) imports
  FastAPI, Starlette or uvicorn;
- drivers and simulators meet at the wire: a driver never imports a simulator; a simulator may
  import only a driver's documented wire codec (``drivers/<device>/protocol.py``);
- only the device backend table (``dimacq/backends``) and the command-line tools that are
  simulators by nature import ``dimacq.simulators``.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _modules(folder: str) -> list[Path]:
    return sorted(p for p in (ROOT / folder).rglob("*.py") if "__pycache__" not in p.parts)


def _imports(path: Path) -> set[str]:
    tree = ast.parse(path.read_text(encoding="utf-8"))
    out: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            out.update(f"{node.module}.{a.name}" for a in node.names)
    return out


def _hits(imports: set[str], banned: tuple[str, ...]) -> list[str]:
    return sorted(i for i in imports if any(i == b or i.startswith(b + ".") for b in banned))


NUMERIC_BANNED = (
    "fastapi",
    "starlette",
    "uvicorn",
    "serial",
    "can",
    "usb",
    "threading",
    "socket",
    "sqlalchemy",
    "h5py",
    "dimacq.api",
    "dimacq.services",
    "dimacq.drivers",
    "dimacq.simulators",
    "dimacq.persistence",
    "dimacq.io",
)


@pytest.mark.parametrize(
    "path",
    _modules("dimacq/pipeline") + _modules("dimacq/model"),
    ids=lambda p: str(p.relative_to(ROOT)),
)
def test_numerical_code_is_pure(path: Path) -> None:
    assert not _hits(_imports(path), NUMERIC_BANNED), (
        f"{path.relative_to(ROOT)} imports {_hits(_imports(path), NUMERIC_BANNED)}"
    )


WEB = ("fastapi", "starlette", "uvicorn")
WEB_ALLOWED = {"serve.py", "demo.py"}


@pytest.mark.parametrize(
    "path",
    [
        p
        for p in _modules("dimacq") + _modules("drivers") + _modules("simulators")
        if "api" not in p.relative_to(ROOT).parts[:2]
    ],
    ids=lambda p: str(p.relative_to(ROOT)),
)
def test_only_the_api_imports_the_web_framework(path: Path) -> None:
    if path.parent.name == "commands" and path.name in WEB_ALLOWED:
        return
    assert not _hits(_imports(path), WEB), (
        f"{path.relative_to(ROOT)} imports {_hits(_imports(path), WEB)}"
    )


@pytest.mark.parametrize("path", _modules("drivers"), ids=lambda p: str(p.relative_to(ROOT)))
def test_drivers_never_import_simulators(path: Path) -> None:
    assert not _hits(_imports(path), ("dimacq.simulators",))


@pytest.mark.parametrize("path", _modules("simulators"), ids=lambda p: str(p.relative_to(ROOT)))
def test_simulators_import_only_driver_codecs(path: Path) -> None:
    bad = [i for i in _hits(_imports(path), ("dimacq.drivers",)) if not i.endswith(".protocol")]
    assert not bad, f"{path.relative_to(ROOT)} imports driver internals {bad}"


#: Command-line tools that are simulators by nature (they play the virtual lab or its engineer).
SIMULATOR_TOOLS = {
    "dimacq/cli/simulated_lab.py",
    "dimacq/cli/commands/acquire.py",
    "dimacq/cli/commands/demo.py",
    "dimacq/cli/commands/digitizer.py",
    "dimacq/cli/commands/loadcell.py",
    "dimacq/cli/commands/simulate.py",
}


@pytest.mark.parametrize("path", _modules("dimacq"), ids=lambda p: str(p.relative_to(ROOT)))
def test_only_the_backend_table_reaches_the_simulators(path: Path) -> None:
    """The service layer reaches a simulator only through its device backend table entry
    (``dimacq/backends``), i.e. through its wire (also an import-linter contract in
    ``pyproject.toml``)."""
    rel = path.relative_to(ROOT).as_posix()
    if rel.startswith("dimacq/backends/") or rel in SIMULATOR_TOOLS:
        return
    assert not _hits(_imports(path), ("dimacq.simulators",)), f"{rel} imports the simulators"
