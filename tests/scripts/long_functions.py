"""List the functions longer than a limit in ``dimacq/``, ``drivers/`` and ``simulators/``.

    python tests/scripts/long_functions.py [--limit 120] [ROOT ...]

A function's length is the number of source lines from its ``def`` (decorators excluded) to its
last line, nested functions included. Prints ``lines  path:line  qualified.name``, longest first,
and exits 1 when any is found (0 otherwise). ``tests/test_layout.py`` holds ``dimacq/`` to the
limit with the same function.
"""

from __future__ import annotations

import argparse
import ast
import sys
from collections.abc import Iterator
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
LIMIT = 120


def long_functions(root: Path, limit: int = LIMIT) -> Iterator[tuple[int, str, int, str]]:
    """``(lines, path, line, qualified name)`` of every function in ``root`` over ``limit``."""
    for path in sorted(root.rglob("*.py")):
        if ".venv" in path.parts:
            continue
        tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
        stack: list[tuple[ast.AST, str]] = [(tree, "")]
        while stack:
            node, prefix = stack.pop()
            for child in ast.iter_child_nodes(node):
                if isinstance(child, ast.FunctionDef | ast.AsyncFunctionDef | ast.ClassDef):
                    name = f"{prefix}{child.name}"
                    if not isinstance(child, ast.ClassDef):
                        n = (child.end_lineno or child.lineno) - child.lineno + 1
                        if n > limit:
                            yield n, str(path.relative_to(REPO)), child.lineno, name
                    stack.append((child, name + "."))
                else:
                    stack.append((child, prefix))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--limit", type=int, default=LIMIT)
    ap.add_argument("roots", nargs="*", default=["dimacq", "drivers", "simulators"])
    args = ap.parse_args(argv)
    found = sorted(
        (f for r in args.roots for f in long_functions(REPO / r, args.limit)), reverse=True
    )
    for n, path, line, name in found:
        print(f"{n:5d}  {path}:{line}  {name}")
    print(f"{len(found)} function(s) over {args.limit} lines")
    return 1 if found else 0


if __name__ == "__main__":
    sys.exit(main())
