"""Mutation check of the drivers' protocol modules: does changing one constant fail a test?

For each target protocol module, each mutable item in turn is changed in a temporary copy of
the module's source, and that device's tests are run against the copy (a pytest plugin maps the
module's name to the copy; the working tree is not touched):

- every int constant assigned at module level or in a top-level class body (an endpoint, a
  request code, a port, an object index, an enum member): ``+1``, ``−1``, and its bytes swapped
  (for values above 0xFF, at the smallest width of 2, 4 or 8 bytes that holds it);
- every struct format string (``struct.Struct("<ii")``, ``">HBBII6H"``...) and numpy dtype
  string (``">u4"``, ``"<f4"``): byte order ``<`` ↔ ``>`` (``!`` → ``<``), and each
  signedness letter flipped in turn (``h``↔``H``, ``i``↔``I``, ``b``↔``B``, ``l``↔``L``,
  ``q``↔``Q``; dtype ``i``↔``u``).

A mutant is **killed** when its tests fail (``pytest -x``), **survived** when they pass (a
change that cannot differ, a byte order of one byte, is not made). By default the mutants run in
one process (``--in-process``): the heavy third-party imports (numpy, python-can, canopen) are
made once, and before each mutant every ``dimacq`` and test module is dropped from
``sys.modules`` so that the tests import the mutated copy afresh; ``--subprocess`` runs each in
a fresh interpreter instead (slower, the same verdicts). The results go to
``protocol_mutations_results.md`` beside this script (``--out`` / ``--results`` elsewhere) with
the command, date, commit and load.

Usage::

    python tests/scripts/protocol_mutations.py                 # every target
    python tests/scripts/protocol_mutations.py netft cia404    # those targets
    python tests/scripts/protocol_mutations.py --list          # the mutants, not run
"""

from __future__ import annotations

import argparse
import ast
import os
import re
import shlex
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
RESULTS = Path(__file__).with_name("protocol_mutations_results.md")
sys.path.insert(0, str(ROOT / "tests"))
from _results import Results  # noqa: E402

#: target name → (module, source file, test paths: fastest first, -x stops at the first failure)
TARGETS: dict[str, tuple[str, str, tuple[str, ...]]] = {
    "netft": (
        "dimacq.drivers.netft.protocol",
        "drivers/netft/protocol.py",
        (
            "tests/drivers/netft/test_netft_can_protocol.py",
            "tests/drivers/netft/test_netft_can_references.py",
            "tests/drivers/test_can_reference_exchanges.py",
            "tests/simulators/netft/test_netft_can_sim.py",
            # the RDT codec's exchanges (its timing tests are the alignment's, not the codec's)
            "tests/drivers/netft/test_netft_rdt.py::test_request_and_record_bytes",
            "tests/drivers/netft/test_netft_rdt.py::test_driver_on_the_loopback_simulator",
            "tests/drivers/netft/test_netft_rdt.py::test_calibration_read_from_the_device_over_tcp",
        ),
    ),
    "cia404": (
        "dimacq.drivers.cia404.protocol",
        "drivers/cia404/protocol.py",
        (
            "tests/drivers/cia404/test_cia404_protocol.py",
            "tests/drivers/test_can_reference_exchanges.py",
            "tests/simulators/cia404/test_cia404_node.py",
        ),
    ),
    "canopen": (
        "dimacq.drivers.canopen_loadcell.protocol",
        "drivers/canopen_loadcell/protocol.py",
        ("tests/simulators/canopen_loadcell/test_canopen_loadcell.py",),
    ),
    "mcc": (
        "dimacq.drivers.mcc.protocol",
        "drivers/mcc/protocol.py",
        (
            "tests/drivers/mcc/test_mcc_reference_exchanges.py",
            "tests/drivers/mcc/test_mcc_protocol.py",
            "tests/drivers/mcc/test_mcc_fpga.py",
            "tests/simulators/mcc/test_mcc_simulator.py",
        ),
    ),
    "loadcell": (
        "dimacq.drivers.loadcell.protocol",
        "drivers/loadcell/protocol.py",
        (
            "tests/drivers/loadcell/test_loadcell_protocol.py",
            "tests/drivers/loadcell/test_loadcell_driver.py",
        ),
    ),
    "daq": (
        "dimacq.drivers.daq.protocol",
        "drivers/daq/protocol.py",
        ("tests/drivers/daq/test_daq_driver.py", "tests/simulators/daq/test_daq_simulator.py"),
    ),
}

_STRUCT = re.compile(r"^[<>!=@]?(\d*[xcbB?hHiIlLqQnNefdsp])+$")
_DTYPE = re.compile(r"^[<>|=]?[iuf]\d$")
_SIGN = {
    "h": "H",
    "H": "h",
    "i": "I",
    "I": "i",
    "b": "B",
    "B": "b",
    "l": "L",
    "L": "l",
    "q": "Q",
    "Q": "q",
}


@dataclass(frozen=True)
class Mutant:
    """One change: ``line`` (1-based), the item's name, the source segment and its
    replacement at ``[start, end)`` of the source."""

    name: str
    line: int
    kind: str
    old: str
    new: str
    start: int
    end: int


def _offset(lines: list[str], line: int, col: int) -> int:
    return sum(len(x) for x in lines[: line - 1]) + len(
        lines[line - 1][:col].encode()[:col].decode(errors="ignore")
    )


def _int_mutants(value: int) -> list[tuple[str, int]]:
    out = [("+1", value + 1), ("-1", value - 1)]
    if value > 0xFF:
        width = next(w for w in (2, 4, 8) if value < 1 << (8 * w))
        swapped = int.from_bytes(value.to_bytes(width, "little"), "big")
        if swapped != value:
            out.append((f"byte swap ({width} B)", swapped))
    return out


def struct_size(fmt: str) -> int:
    import struct

    try:
        return struct.calcsize(fmt)
    except struct.error:
        return 0


def _fmt_mutants(fmt: str) -> list[tuple[str, str]]:
    out = []
    if _DTYPE.match(fmt):
        order, body = (fmt[0], fmt[1:]) if fmt[0] in "<>|=" else ("", fmt)
        if order in "<>":
            out.append(("byte order", {"<": ">", ">": "<"}[order] + body))
        if body[0] in "iu":
            out.append(("signedness", order + {"i": "u", "u": "i"}[body[0]] + body[1:]))
        return out
    order = fmt[0] if fmt[0] in "<>!=@" else ""
    body = fmt[len(order) :]
    one_byte = all(ch in "xcbB?s" or ch.isdigit() for ch in body)  # no multi-byte field
    if order in ("<", ">", "!") and not one_byte:  # one byte has no byte order: no mutant
        out.append(("byte order", {"<": ">", ">": "<", "!": "<"}[order] + body))
    for i, ch in enumerate(body):
        if ch in _SIGN:
            out.append(
                (
                    f"signedness {ch}->{_SIGN[ch]} at {i}",
                    order + body[:i] + _SIGN[ch] + body[i + 1 :],
                )
            )
    return out


_BITOPS = (ast.LShift, ast.RShift, ast.BitAnd, ast.BitOr, ast.BitXor)


def _float_mutants(value: float) -> list[tuple[str, str]]:
    return [("+0.1 %", repr(value * 1.001))] if value else [("+1e-3", "0.001")]


def _bytes_mutants(value: bytes) -> list[tuple[str, str]]:
    out = [("last byte +1", repr(value[:-1] + bytes([(value[-1] + 1) & 0xFF])))] if value else []
    if len(value) > 1:
        out.append(("one byte fewer", repr(value[:-1])))
    return out


def _hex_mutants(text: str) -> list[tuple[str, str]]:
    """A ``bytes.fromhex`` argument: its bytes reversed, its last byte +1."""
    data = bytes.fromhex(text)
    out = [("last byte +1", repr((data[:-1] + bytes([(data[-1] + 1) & 0xFF])).hex()))]
    if data[::-1] != data:
        out.append(("bytes reversed", repr(data[::-1].hex())))
    return out


def _field_swaps(fmt: str) -> list[tuple[str, str]]:
    """A struct layout with two adjacent fields of different codes swapped."""
    order = fmt[0] if fmt[0] in "<>!=@" else ""
    fields = re.findall(r"\d*[xcbB?hHiIlLqQnNefdsp]", fmt[len(order) :])
    out = []
    for k in range(len(fields) - 1):
        if fields[k] != fields[k + 1]:
            swapped = fields[:k] + [fields[k + 1], fields[k]] + fields[k + 2 :]
            out.append((f"fields {k},{k + 1} swapped", order + "".join(swapped)))
    return out


def mutants(source: str) -> list[Mutant]:
    """Every mutant of ``source`` (see the module docstring).

    In the value of each module-level or top-level class-level assignment (named by its
    target): every int (``±1``, byte swap), float (``+0.1 %``), bytes constant (last byte
    ``+1``, one byte fewer), ``bytes.fromhex`` argument, tuple of names (first two swapped) and
    format string. Anywhere else (function bodies, dataclass defaults): every format string,
    every int written in hexadecimal and every int operand of a bit operation (``<< 2``,
    ``& 0x7F``: the protocol's numbers written inline). Nothing inside an f-string or a
    ``raise`` (messages) is mutated.
    """
    tree = ast.parse(source)
    lines = source.splitlines(keepends=True)
    starts = [0]
    for ln in lines:
        starts.append(starts[-1] + len(ln))
    parents = {c: n for n in ast.walk(tree) for c in ast.iter_child_nodes(n)}

    def pos(node: ast.AST) -> tuple[int, int]:
        a = starts[node.lineno - 1] + len(
            lines[node.lineno - 1].encode()[: node.col_offset].decode()
        )
        b = (
            starts[node.end_lineno - 1]
            + len(  # type: ignore[operator]
                lines[node.end_lineno - 1].encode()[: node.end_col_offset].decode()  # type: ignore[index]
            )
        )
        return a, b

    def in_message(node: ast.AST) -> bool:
        while node in parents:
            node = parents[node]
            if isinstance(node, (ast.JoinedStr, ast.Raise)):
                return True
        return False

    def enclosing(node: ast.AST) -> str:
        names = []
        while node in parents:
            node = parents[node]
            if isinstance(node, (ast.FunctionDef, ast.ClassDef)):
                names.append(node.name)
        return ".".join(reversed(names))

    out: list[Mutant] = []
    done: set[int] = set()

    def add(name: str, node: ast.AST, pairs: list[tuple[str, str]]) -> None:
        a, b = pos(node)
        if a in done:
            return
        done.add(a)
        for kind, new in pairs:
            out.append(Mutant(name, node.lineno, kind, source[a:b], new, a, b))

    def ints(value: int) -> list[tuple[str, str]]:
        return [(k, hex(v) if v >= 0 else str(v)) for k, v in _int_mutants(value)]

    def fmt_label(name: str, fmt: str, node: ast.AST) -> str:
        return f"{name} {fmt!r}" + (f" col {node.col_offset}" if "DTYPE" in name else "")

    def is_fmt(node: ast.AST) -> bool:
        if not (isinstance(node, ast.Constant) and isinstance(node.value, str)):
            return False
        fmt = node.value
        # with a byte order: a format, not a word ("lbf" is letters of codes too)
        return fmt[:1] in "<>!=@|" and bool(_STRUCT.match(fmt) or _DTYPE.match(fmt))

    def fmt_pairs(fmt: str) -> list[tuple[str, str]]:
        pairs = [(k, repr(v)) for k, v in _fmt_mutants(fmt)]
        if _STRUCT.match(fmt) and not _DTYPE.match(fmt):
            pairs += [(k, repr(v)) for k, v in _field_swaps(fmt)]
        return pairs

    bodies: list[tuple[str, list[ast.stmt]]] = [("", tree.body)]
    bodies += [(f"{n.name}.", n.body) for n in tree.body if isinstance(n, ast.ClassDef)]
    for prefix, body in bodies:
        for stmt in body:
            if isinstance(stmt, ast.Assign) and len(stmt.targets) == 1:
                target, value = stmt.targets[0], stmt.value
            elif isinstance(stmt, ast.AnnAssign) and stmt.value is not None and not prefix:
                # (a dataclass field's default: below, with the inline numbers)
                target, value = stmt.target, stmt.value
            else:
                continue
            if not isinstance(target, ast.Name):
                continue
            name = prefix + target.id
            for node in ast.walk(value):
                if not isinstance(node, ast.Constant) or in_message(node):
                    if (
                        isinstance(node, ast.Tuple)
                        and len(node.elts) > 1
                        and all(
                            isinstance(e, ast.Constant) and isinstance(e.value, str)
                            for e in node.elts
                        )
                        and node.elts[0].value != node.elts[1].value  # type: ignore[attr-defined]
                    ):
                        a, b = pos(node.elts[0])
                        c, d = pos(node.elts[1])
                        text = source[a:b], source[c:d]
                        seg = source[a:d]
                        out.append(
                            Mutant(
                                name,
                                node.lineno,
                                "first two swapped",
                                seg,
                                text[1] + source[b:c] + text[0],
                                a,
                                d,
                            )
                        )
                    continue
                v = node.value
                if isinstance(v, bool):
                    continue
                if isinstance(v, int):
                    add(name, node, ints(v))
                elif isinstance(v, float):
                    add(name, node, _float_mutants(v))
                elif isinstance(v, bytes):
                    add(name, node, _bytes_mutants(v))
                elif is_fmt(node):
                    add(fmt_label(name, v, node), node, fmt_pairs(v))
                elif (
                    isinstance(v, str)
                    and isinstance(parents.get(node), ast.Call)
                    and isinstance(parents[node].func, ast.Attribute)  # type: ignore[attr-defined]
                    and parents[node].func.attr == "fromhex"  # type: ignore[attr-defined]
                ):
                    add(name, node, _hex_mutants(v))
    # the numbers and formats written inline
    for node in ast.walk(tree):
        if not isinstance(node, ast.Constant) or in_message(node):
            continue
        v, where = node.value, enclosing(node)
        if is_fmt(node):
            call = parents.get(node)
            label = (
                f"{call.func.value.id}.{call.func.attr}({v!r})"  # type: ignore[attr-defined]
                if isinstance(call, ast.Call)
                and isinstance(call.func, ast.Attribute)
                and isinstance(call.func.value, ast.Name)
                and call.func.value.id == "struct"
                else f"{where or 'module'} {v!r}"
            )
            add(label, node, fmt_pairs(v))
        elif isinstance(v, int) and not isinstance(v, bool):
            a, b = pos(node)
            hexa = source[a:b].lower().startswith("0x")
            parent = parents.get(node)
            bitop = isinstance(parent, ast.BinOp) and isinstance(parent.op, _BITOPS)
            if hexa or bitop:
                add(f"{where or 'module'} {source[a:b]}", node, ints(v))
    out.sort(key=lambda m: m.start)
    return out


_PLUGIN = """
import importlib.abc, importlib.util, sys
_NAME, _PATH = {name!r}, {path!r}

class _Finder(importlib.abc.MetaPathFinder):
    def find_spec(self, fullname, path=None, target=None):
        if fullname == _NAME:
            return importlib.util.spec_from_file_location(fullname, _PATH)
        return None

sys.meta_path.insert(0, _Finder())
"""


def run_mutant(
    module: str, source: str, m: Mutant, tests: tuple[str, ...], workers: str, timeout_s: float
) -> tuple[str, float, str]:
    """``(verdict, seconds, first failing test)`` of one mutant."""
    text = source[: m.start] + m.new + source[m.end :]
    with tempfile.TemporaryDirectory(prefix="mutant-") as tmp:
        mod = Path(tmp) / "mutated_protocol.py"
        mod.write_text(text, encoding="utf-8")
        (Path(tmp) / "_mutant_plugin.py").write_text(_PLUGIN.format(name=module, path=str(mod)))
        env = dict(os.environ, PYTHONPATH=tmp + os.pathsep + os.environ.get("PYTHONPATH", ""))
        cmd = [
            sys.executable,
            "-m",
            "pytest",
            "-p",
            "_mutant_plugin",
            "-x",
            "-q",
            "-p",
            "no:cacheprovider",
            "-n",
            workers,
            "--no-header",
            "-rf",
            *tests,
        ]
        t0 = time.monotonic()
        try:
            r = subprocess.run(
                cmd, cwd=ROOT, env=env, capture_output=True, text=True, timeout=timeout_s
            )
        except subprocess.TimeoutExpired:
            return "killed (timeout)", time.monotonic() - t0, ""
        secs = time.monotonic() - t0
    failed = next(
        (ln.split(" ")[1] for ln in r.stdout.splitlines() if ln.startswith("FAILED ")), ""
    )
    if r.returncode == 0:
        return "survived", secs, ""
    if r.returncode == 1:
        return "killed", secs, failed
    return (
        f"killed (pytest exit {r.returncode})",
        secs,
        failed or r.stdout.strip().splitlines()[-1:][0] if r.stdout.strip() else "",
    )


class _Finder:
    """Maps one module name to a file (the mutated copy)."""

    def __init__(self, name: str, path: str) -> None:
        self.name, self.path = name, path

    def find_spec(self, fullname: str, path: object = None, target: object = None) -> object:
        import importlib.util

        if fullname == self.name:
            return importlib.util.spec_from_file_location(fullname, self.path)
        return None


def _purge() -> None:
    """Drop every dimacq and test module (the tests import them again, the mutant among them)."""
    tests = str(ROOT / "tests")
    for name in list(sys.modules):
        mod = sys.modules[name]
        f = getattr(mod, "__file__", None) or ""
        if name == "dimacq" or name.startswith("dimacq.") or f.startswith(tests):
            del sys.modules[name]


def run_in_process(
    module: str, source: str, m: Mutant, tests: tuple[str, ...]
) -> tuple[str, float, str]:
    """``(verdict, seconds, first failing test)`` of one mutant, in this process."""
    import contextlib
    import io

    import pytest

    text = source[: m.start] + m.new + source[m.end :]
    with tempfile.TemporaryDirectory(prefix="mutant-") as tmp:
        mod = Path(tmp) / "mutated_protocol.py"
        mod.write_text(text, encoding="utf-8")
        finder = _Finder(module, str(mod))
        _purge()
        sys.meta_path.insert(0, finder)  # type: ignore[arg-type]
        out = io.StringIO()
        t0 = time.monotonic()
        rc: int | pytest.ExitCode = 0
        try:
            # one path at a time, in order: most mutants fail the first (the reference
            # exchanges) and the others are not even collected
            for path in tests:
                with contextlib.redirect_stdout(out):
                    rc = pytest.main(
                        [
                            "-x",
                            "-q",
                            "-p",
                            "no:cacheprovider",
                            "-n",
                            "0",
                            "--no-header",
                            "-rf",
                            path,
                        ]
                    )
                _purge()
                if rc != 0:
                    break
        finally:
            sys.meta_path.remove(finder)  # type: ignore[arg-type]
            _purge()
        secs = time.monotonic() - t0
    lines = out.getvalue().splitlines()
    failed = next((ln.split(" ")[1] for ln in lines if ln.startswith("FAILED ")), "")
    if rc == 0:
        return "survived", secs, ""
    if rc == 1:
        return "killed", secs, failed
    return f"killed (pytest exit {int(rc)})", secs, failed or (lines[-1] if lines else "")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("targets", nargs="*", help=f"of {sorted(TARGETS)} (default: all)")
    ap.add_argument("--list", action="store_true", help="list the mutants, run nothing")
    ap.add_argument("-n", "--workers", default="0", help="pytest-xdist workers per run (0 or 2)")
    ap.add_argument("--timeout", type=float, default=600.0, help="per mutant, s")
    ap.add_argument(
        "--out", "--results", type=Path, default=RESULTS, help="the results file (markdown)"
    )
    ap.add_argument(
        "--subprocess", action="store_true", help="each mutant in a fresh interpreter (slower)"
    )
    ap.add_argument(
        "--from-log",
        type=Path,
        action="append",
        default=[],
        help="write the results from the printed log(s) of runs stopped before their end (the "
        "source unchanged since): the mutants not reached are listed as not run",
    )
    ap.add_argument(
        "--mutants",
        default="",
        help="run only these mutants (1-based numbers of --list, comma-separated: a re-run of "
        "survivors after a test was added; merge with --from-log)",
    )
    ap.add_argument(
        "--reuse-log",
        type=Path,
        action="append",
        default=[],
        help="a log of an earlier run (another numbering): a mutant it shows killed, named by the "
        "same item and mutation (one of its kind in the module), is not run again; its line is "
        "printed with '(earlier run)'",
    )
    args = ap.parse_args(argv)
    res = Results(__file__, "Protocol mutations: results", args.out)
    if argv is not None:
        res.command = " ".join(["python", res.shown, *map(shlex.quote, argv)])
    earlier: dict[tuple[str, str], str] = {}
    old_pat = re.compile(r"^\[(\w+) \d+/\d+\] (.*?): (killed(?: \([^)]*\))?) \([\d.]+ s\) ?(.*)$")
    for log in args.reuse_log:
        for ln in log.read_text(encoding="utf-8").splitlines():
            got = old_pat.match(ln)
            if got and "earlier run" not in ln:
                earlier[(got[1], got[2])] = got[4]
    picked = {int(x) for x in args.mutants.split(",") if x.strip()}
    names = args.targets or list(TARGETS)
    unknown = [n for n in names if n not in TARGETS]
    if unknown:
        ap.error(f"unknown targets {unknown}; give any of {sorted(TARGETS)}")
    sections = []
    total_survived = 0
    logged: dict[str, dict[int, tuple[str, float, str]]] = {}
    pat = re.compile(
        r"^\[(\w+) (\d+)/(\d+)\] .*?: (killed(?: \([^)]*\))?|survived) \(([\d.]+) s\) ?(.*)$"
    )
    for log in args.from_log:
        for ln in log.read_text(encoding="utf-8").splitlines():
            got = pat.match(ln)
            if got:
                logged.setdefault(got[1], {})[int(got[2]) - 1] = (got[4], float(got[5]), got[6])
    for name in names:
        module, rel, tests = TARGETS[name]
        path = ROOT / rel
        if not path.exists():
            sections.append(f"## {module}\n\n{rel} not in this tree: not run.\n")
            continue
        source = path.read_text(encoding="utf-8")
        ms = mutants(source)
        present = tuple(t for t in tests if (ROOT / t.split("::")[0]).exists())
        rows = []
        if args.from_log:
            done = logged.get(name, {})
            for i, m in enumerate(ms):
                verdict, _secs, failed = done.get(i, ("not run", 0.0, ""))
                total_survived += verdict == "survived"
                rows.append(
                    f"| {m.line} | `{m.name}` | {m.kind} | `{m.old}` → `{m.new}` | {verdict} | "
                    f"{failed.replace('|', '/')} |"
                )
            killed = sum("killed" in r for r in rows)
            survived = sum("| survived |" in r for r in rows)
            sections.append(
                f"## {module}\n\nTests: {', '.join(f'`{t}`' for t in present)}\n\n"
                f"{killed} killed, {survived} survived, {len(rows) - killed - survived} not run "
                f"of {len(rows)} mutants.\n\n"
                "| line | item | mutation | change | verdict | first failing test |\n"
                "|---|---|---|---|---|---|\n" + "\n".join(rows) + "\n"
            )
            continue
        if not args.list:  # the unmutated copy must pass, or the verdicts mean nothing
            control = Mutant("(none)", 1, "control", "", "", 0, 0)
            verdict, secs, failed = (
                run_mutant(module, source, control, present, args.workers, args.timeout)
                if args.subprocess
                else run_in_process(module, source, control, present)
            )
            print(f"[{name}] control (no change): {verdict} ({secs:.1f} s) {failed}", flush=True)
            if verdict != "survived":
                print(f"{name}: the tests fail without a mutation ({failed}); fix them first")
                return 2
        for i, m in enumerate(ms):
            if args.list:
                print(f"{name} {i + 1:3d} {m.line:4d} {m.name:40s} {m.kind:24s} {m.old} -> {m.new}")
                continue
            if picked and i + 1 not in picked:
                continue
            key = (name, f"{m.name} {m.kind}")
            if key in earlier and sum(f"{x.name} {x.kind}" == key[1] for x in ms) == 1:
                print(
                    f"[{name} {i + 1}/{len(ms)}] {m.name} {m.kind}: killed (earlier run) (0.0 s) "
                    f"{earlier[key]}",
                    flush=True,
                )
                continue
            verdict, secs, failed = (
                run_mutant(module, source, m, present, args.workers, args.timeout)
                if args.subprocess
                else run_in_process(module, source, m, present)
            )
            total_survived += verdict == "survived"
            print(
                f"[{name} {i + 1}/{len(ms)}] {m.name} {m.kind}: {verdict} ({secs:.1f} s) {failed}",
                flush=True,
            )
            rows.append(
                f"| {m.line} | `{m.name}` | {m.kind} | `{m.old}` → `{m.new}` | {verdict} | "
                f"{failed.replace('|', '/')} |"
            )
        if args.list:
            continue
        killed = sum("killed" in r for r in rows)
        sections.append(
            f"## {module}\n\nTests: {', '.join(f'`{t}`' for t in present)}\n\n"
            f"{killed} of {len(rows)} mutants killed, {len(rows) - killed} survived.\n\n"
            "| line | item | mutation | change | verdict | first failing test |\n"
            "|---|---|---|---|---|---|\n" + "\n".join(rows) + "\n"
        )
    if args.list:
        return 0
    res.note(
        f"targets run: {', '.join(names)}; modules not run are listed with their test paths "
        "in the script's TARGETS"
    )
    res.add("\n".join(sections))
    res.write()
    return 1 if total_survived else 0


if __name__ == "__main__":
    sys.exit(main())
