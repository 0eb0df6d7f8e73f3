"""``dimacq demo`` with the wall and CPU time at each line it prints: what each stage costs.

    python tests/scripts/demo_stages.py [--results PATH] [DEMO ARGS ...]

Each line of the demo's output is stamped ``[wall s, CPU s]`` since start (CPU: this process's
user + sys, all its threads); the last line adds the CPU of its child processes (step 0, the
chain check, runs in one: :mod:`dimacq.cli.demo_steps`) as ``os.times`` reports it once they
ended. Differences between successive stamps are the stages' costs (the README's table in
"Time-lapse of the simulated lab"). Run it beside ``uptime``: on a loaded machine the wall time
grows, the CPU much less. The stamped lines go to ``demo_stages_results.md`` beside this script
(``--results PATH`` elsewhere, given before the demo's arguments) with the command, date, commit
and machine load.
"""

from __future__ import annotations

import builtins
import os
import sys
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from _results import Results


def main(argv: list[str]) -> int:
    path = None
    if argv[:1] == ["--results"] and len(argv) > 1:
        path, argv = Path(argv[1]), argv[2:]
    res = Results(__file__, "`dimacq demo`: wall and CPU time at each line", path)
    w0, c0 = time.perf_counter(), time.process_time()
    plain_print = builtins.print
    lines: list[str] = []

    def stamped(*args: Any, **kwargs: Any) -> None:
        if kwargs.get("file") in (None, sys.stdout):
            now = f"[{time.perf_counter() - w0:7.2f} s wall {time.process_time() - c0:7.2f} s CPU]"
            plain_print(now, *args, **kwargs)
            lines.append(" ".join([now, *map(str, args)]))
        else:
            plain_print(*args, **kwargs)

    builtins.print = stamped
    try:
        from dimacq.cli.main import main as dimacq_main

        rc = dimacq_main(["demo", *argv])
    finally:
        builtins.print = plain_print
    t = os.times()
    total = (
        f"total: {time.perf_counter() - w0:.2f} s wall; CPU {t.user + t.system:.2f} s "
        f"(user {t.user:.2f}, sys {t.system:.2f}), child processes {t.children_user + t.children_system:.2f} s"
    )
    print(total)
    res.note(f"demo exit status: {rc}")
    res.add("```\n" + "\n".join([*lines, total]) + "\n```")
    res.write()
    return rc


if __name__ == "__main__":  # the guard matters: step 0's process (spawn) imports this module
    sys.exit(main(sys.argv[1:]))
