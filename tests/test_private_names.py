"""No module of the package imports another module's private name.

A name with a leading underscore is its module's own: ``from dimacq.x import _y`` (or the
relative ``from .x import _y``) in ``dimacq/``, ``drivers/`` or ``simulators/`` ties the importer
to a detail its home may change at will. A name another module needs is made public there.
Dunder names (``__version__``) and ``from __future__`` imports are not private names.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

#: The source trees of the installed package (``drivers`` and ``simulators`` are installed as
#: ``dimacq.drivers`` and ``dimacq.simulators``).
TREES = ("dimacq", "drivers", "simulators")


def _is_private(name: str) -> bool:
    return name.startswith("_") and not (name.startswith("__") and name.endswith("__"))


def private_imports(source: str, filename: str = "<source>") -> list[str]:
    """Each ``from X import _y`` of ``source`` whose ``X`` is a dimacq module (absolute
    ``dimacq``/``dimacq.…`` or any relative import), as ``"line: from X import _y"``."""
    found = []
    for node in ast.walk(ast.parse(source, filename)):
        if not isinstance(node, ast.ImportFrom):
            continue
        module = node.module or ""
        if node.level == 0 and module != "dimacq" and not module.startswith("dimacq."):
            continue
        for alias in node.names:
            if _is_private(alias.name):
                found.append(f"{node.lineno}: from {'.' * node.level}{module} import {alias.name}")
    return found


def test_the_finder_names_private_imports_and_passes_public_ones() -> None:
    source = (
        "from __future__ import annotations\n"
        "from dimacq.pipeline.fit import _lm, solve\n"
        "from .model import _Problem as P\n"
        "from . import _helpers\n"
        "from dimacq import __version__\n"
        "from numpy import _globals\n"
        "from dimacq.drivers.netft.rdt_stream import RdtRun as _Run\n"
        "def f():\n"
        "    from dimacq.io.uff import _Record\n"
    )
    assert private_imports(source) == [
        "2: from dimacq.pipeline.fit import _lm",
        "3: from .model import _Problem",
        "4: from . import _helpers",
        "9: from dimacq.io.uff import _Record",
    ]


@pytest.mark.parametrize("tree", TREES)
def test_no_module_imports_another_modules_private_name(tree: str) -> None:
    offenders = [
        f"{path.relative_to(ROOT)}:{hit}"
        for path in sorted((ROOT / tree).rglob("*.py"))
        for hit in private_imports(path.read_text(encoding="utf-8"), str(path))
    ]
    assert not offenders, (
        "private names imported from another module (make the name public in its module, "
        "or keep the use inside that module):\n" + "\n".join(offenders)
    )
