"""Parts of ``dimacq demo`` (:mod:`dimacq.cli.commands.demo`): what its acquisitions ask for,
following an acquisition over HTTP, and step 0, the chain check on the weighed reference block,
run in a process of its own while the test's geometry is digitized.

Why a process: the demo's host work is Python under one GIL (the simulators' threads, the
drivers, the service, the HTTP client). Step 0 (its own service on the same data directory, its
own simulated lab: an acquisition and a solve) and steps 1–3 of the test (digitizing through the
HTTP API) need nothing of each other, so :class:`ChainCheck` starts step 0 in a child process
(``multiprocessing``, spawn); the test acquires once step 0 is done: one acquisition at a time,
as the time-lapse was chosen for, and not beside step 0's solve either (its modal fit, when the
automatic path runs it, takes both cores for seconds: at 18x on a loaded machine that starved
the test's acquisition into FIFO overflows). The child shares only the data
directory (SQLite in WAL mode takes writers of several processes; the test's service has made
the schema before the child starts) and sends back its lines, its result or its error, and what
:class:`~dimacq.backends.time_lapse.HostLag` saw, through a pipe.
"""

from __future__ import annotations

import argparse
import json
import logging
import multiprocessing
import secrets
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

from dimacq import errors
from dimacq.cli.progress import ProgressLine
from dimacq.errors import DataError, DeviceError, DimacqError, SetupError

if TYPE_CHECKING:
    from multiprocessing.connection import Connection

    from dimacq.backends.time_lapse import HostLag

__all__ = [
    "QUICK",
    "QUICK_CHAIN",
    "REFERENCE_SCENARIO",
    "ChainCheck",
    "acquire",
    "acquisition_plan",
    "chain_step",
    "check",
    "follow_acquisition",
]

#: What the demo's two acquisitions ask for unless ``--full`` (then the rig file's
#: ``[acquisition]``: 5 averages of 4096 samples per input for the calibration mass). The demo
#: must show the chain and the answer within its limits (0.5 % mass, 1 mm CG, 0.5 % principal
#: moments, verdict ok), not the most a lab would take. Records: 2048 samples at 2048 S/s are
#: 1 s, 1 Hz lines (80 in the scenario's 20–100 Hz band); the rig's exponential window
#: (τ = 0.25 s) has decayed to e⁻⁴ = 1.8 % by then, so a longer record adds lines, not
#: information. The test: 3 averages per input, the service's ``min_averages`` (a coherence and
#: a noise estimate per line). The chain check on the reference block: 2 (its factor's
#: uncertainty is the block's weighing and geometry, not the FRF noise: 1.00018…1.00020
#: ± 0.103 % with 5 averages of 4096 samples or 2 of 2048). Together about a third of the full
#: tests' simulated time; the README gives the runs.
QUICK: dict[str, int] = {"averages_per_input": 3, "record_samples": 2048}
QUICK_CHAIN: dict[str, int] = {"averages_per_input": 2, "min_averages": 2, "record_samples": 2048}


def acquisition_plan(args: argparse.Namespace, *, chain: bool = False) -> dict[str, int]:
    """The impact settings an acquisition asks for: :data:`QUICK` (the chain check
    :data:`QUICK_CHAIN`; ``--full``: none, the rig file's), overridden by ``--averages`` /
    ``--record-samples`` when given (``--averages`` also sets the fewest accepted averages
    when it is below them)."""
    plan = {} if args.full else dict(QUICK_CHAIN if chain else QUICK)
    if args.averages is not None:
        plan["averages_per_input"] = int(args.averages)
        if "min_averages" in plan:
            plan["min_averages"] = min(plan["min_averages"], int(args.averages))
    if args.record_samples is not None:
        plan["record_samples"] = int(args.record_samples)
    return plan


#: The lab's weighed reference block (config/reference-block/), cabled as the calibration mass.
REFERENCE_SCENARIO = "reference-block-bungee"


def chain_step(
    data_dir: Path,
    token: str,
    args: argparse.Namespace,
    say: Callable[[str], None],
    imperfections: dict[str, Any] | None = None,
    lag: HostLag | None = None,
    runs: list[dict[str, Any]] | None = None,
    acquired: Callable[[], None] | None = None,
) -> dict[str, Any]:
    """Step 0: calibrate the measurement chain on the weighed reference block.

    As a lab does before a test: the reference block hangs on the bungee through the load cell
    with the same hammer and accelerometers; its drawing gives the geometry (setup file), its
    weighing certificate the mass. The service acquires it and solves with ``reference_mass``; the
    solution's ``chain_calibration`` (``γ`` and its uncertainty,
    :mod:`dimacq.pipeline.chain_calibration`) is applied to the test's solve (step 5) by id.
    Same data directory, so the test's service finds the stored solution.
    """
    import httpx

    from dimacq.api import create_app
    from dimacq.api.server import BackgroundServer
    from dimacq.config import default_config_file, load_settings, scenario_rig_file
    from dimacq.io.reference_mass import load_reference_mass
    from dimacq.simulators.lab.scenarios import build_scenario

    ref = load_reference_mass(default_config_file().parent / "reference-block" / "mass.toml")
    if ref.setup_file is None:
        raise SetupError("reference-block/mass.toml names no setup_file (the block's drawing)")
    block = build_scenario(REFERENCE_SCENARIO, args.seed)
    settings = load_settings(
        data_dir=data_dir,
        token=token,
        host="127.0.0.1",
        digitizer_url=f"simdigitizer://demo-{secrets.token_hex(4)}?seed={block.seed}",
        scenario=REFERENCE_SCENARIO,
        rig_file=scenario_rig_file(REFERENCE_SCENARIO),
        database_url="",
        simulation_imperfections=imperfections,
    )
    # a stand of its own: one service per stand on a database, and the test's service runs
    # beside this one (the reference block on its own bungee, same hammer and sensors)
    settings = settings.model_copy(update={"stand": f"{settings.stand_name[:90]}-chain"})
    with BackgroundServer(create_app(settings)) as srv:
        c = httpx.Client(
            base_url=srv.url, headers={"Authorization": f"Bearer {token}"}, timeout=120
        )
        try:
            say(
                f"[0/5] chain calibration: reference block {ref.serial_number} "
                f"({ref.mass_kg:g} ± {ref.u_kg:g} kg weighed) on the same hammer and sensors"
            )
            st = check(
                c.post(
                    "/api/setups/import",
                    params={"format": "toml", "name": "reference block (drawing)"},
                    content=ref.setup_file.read_bytes(),
                ),
                "reference block setup",
            )
            sid = int(st.get("setup_id", st.get("id")))
            frf_id = acquire(
                c,
                {"setup_id": sid, **acquisition_plan(args, chain=True), "seed": block.seed},
                "acquisition of the reference block (step 0; --no-chain-calibration skips it)",
                say,
                quiet=args.quiet,
                step="[0/5]",
                lag=lag,
                runs=runs,
            )
            if acquired is not None:  # its host lag and figures, as soon as they are known
                acquired()
            sol = check(
                c.post(
                    "/api/solutions",
                    json={
                        "frf_id": frf_id,
                        "reference_mass": {"mass_kg": ref.mass_kg, "u_kg": ref.u_kg},
                    },
                ),
                "reference block solve",
            )
        finally:
            c.close()
    cal = sol["result"].get("chain_calibration")
    if cal is None:
        reasons = "; ".join(
            r["message"] for r in sol["result"].get("verdict_reasons", []) if r["severity"] != "ok"
        )
        raise DataError(f"demo: the reference block gave no chain calibration: {reasons}")
    say(
        f"[0/5] chain factor {cal['factor']:.5f} ± {100 * cal['u_rel']:.3f} % "
        f"(block measures {cal['measured_mass_kg']:.4f} kg; solution {sol['id']})"
    )
    return {"solution_id": int(sol["id"]), **cal}


def check(r: Any, what: str) -> Any:
    if r.status_code >= 400:
        try:
            detail = r.json().get("detail")
        except ValueError:
            detail = r.text
        cls = DeviceError if r.status_code in (409, 503) else DataError
        raise cls(f"demo: {what} failed with HTTP {r.status_code}: {detail}")
    return r.json()


def acquire(
    c: Any,
    body: dict[str, Any],
    what: str,
    say: Callable[[str], None],
    *,
    quiet: bool = False,
    step: str = "[4/5]",
    lag: HostLag | None = None,
    runs: list[dict[str, Any]] | None = None,
) -> int:
    """``POST /api/acquisitions`` with ``body``, followed to its end: its FRF set's id.

    An acquisition that ends incomplete (inputs left below ``min_averages``: on a host that fell
    behind the time-lapse, strikes lost in DAQ FIFO overflows) has those inputs struck once more
    and appended into its FRF set (``inputs`` + ``merge_frf_id``), as its message tells a user
    to; the host lag is reported either way (:class:`~dimacq.backends.time_lapse.HostLag`).
    """
    acq = check(c.post("/api/acquisitions", json=body), what)
    a = follow_acquisition(c, acq, say, quiet=quiet, step=step, lag=lag, runs=runs)
    missing = list(a["incomplete_inputs"]) if a["state"] == "incomplete" else []
    if missing:
        say(f"{step} striking {len(missing)} incomplete input(s) again into FRF set {a['frf_id']}")
        again = {**body, "inputs": missing, "merge_frf_id": a["frf_id"]}
        acq = check(c.post("/api/acquisitions", json=again), f"{what}, incomplete inputs again")
        a = follow_acquisition(c, acq, say, quiet=quiet, step=step, lag=lag, runs=runs)
    return int(a["frf_id"])


def follow_acquisition(
    c: Any,
    acq: dict[str, Any],
    say: Callable[[str], None],
    quiet: bool = False,
    step: str = "[4/5]",
    lag: HostLag | None = None,
    runs: list[dict[str, Any]] | None = None,
) -> dict[str, Any]:
    """Follow acquisition ``acq`` (the POST's answer) over server-sent events to its end: its
    state (``GET /api/acquisitions/{id}``); none of its FRFs stored raises :class:`DataError`."""
    t0 = time.perf_counter()
    job_id = acq["job_id"]
    progress = ProgressLine(f"{step} acquisition", quiet=quiet)
    try:
        with c.stream("GET", f"/api/jobs/{job_id}/events", params={"poll_s": 0.2}) as r:
            for line in r.iter_lines():
                if not line.startswith("data:"):
                    continue
                snap = json.loads(line[5:])
                progress.update(snap["progress"], snap["message"])
                if snap["state"] in ("succeeded", "failed", "cancelled", "interrupted"):
                    break
    finally:
        progress.close()
    a = check(c.get(f"/api/acquisitions/{acq['id']}"), "acquisition status")
    wall = time.perf_counter() - t0
    say(
        f"{step} averages accepted {a['averages_accepted']}, rejected {a['averages_rejected']} "
        f"({wall:.1f} s)"
    )
    if runs is not None:  # what it took: the summary's simulated seconds (wall × time-lapse)
        cfg = a.get("config") or {}
        runs.append(
            {
                "step": step,
                "wall_s": wall,
                "averages_accepted": a["averages_accepted"],
                "averages_rejected": a["averages_rejected"],
                **{k: cfg.get(k) for k in ("averages_per_input", "record_samples")},
            }
        )
    if lag is not None:  # did the host keep up? the rejections' and lost strikes' reasons say
        lag.observe_reasons(av["reason"] for av in a["averages"] if not av["accepted"])
        lag.observe_reasons(r for st in a["input_states"] for r in st.get("lost_reasons", []))
    if a["frf_id"] is None:
        raise DataError(f"demo: acquisition {acq['id']} ended {a['state']}: {a['message']}")
    if a["state"] != "succeeded":  # "incomplete": FRFs of some inputs only, the rest named
        say(f"{step} acquisition {acq['id']} ended {a['state']}: {a['message']}")
    return dict(a)


def _child(
    conn: Connection,
    data_dir: Path,
    token: str,
    args: argparse.Namespace,
    imperfections: dict[str, Any] | None,
) -> None:
    """The child process of :class:`ChainCheck`: step 0, its lines sent as they come (its log
    at the parent's ``-v`` level, on the same stderr: a spawned child starts unconfigured)."""
    from dimacq.backends.time_lapse import HostLag

    level = logging.WARNING - 10 * min(int(getattr(args, "verbose", 0) or 0), 2)
    logging.basicConfig(level=level, format="%(levelname)s %(name)s: %(message)s")

    lag = HostLag()
    runs: list[dict[str, Any]] = []
    try:
        with lag.recording():
            chain = chain_step(
                data_dir,
                token,
                args,
                lambda m: conn.send(("say", m)),
                imperfections,
                lag,
                runs,
                acquired=lambda: conn.send(("acquired", lag, runs)),
            )
        end: tuple[Any, ...] = ("ok", chain)
    except DimacqError as err:
        end = ("error", type(err).__name__, str(err))
    except BaseException as err:  # a bug: named, with its type, not hidden
        end = ("error", "DimacqError", f"demo: step 0 failed: {type(err).__name__}: {err}")
    try:
        conn.send(end)
    except OSError:  # the demo is gone (interrupted): nobody to tell
        pass
    finally:
        conn.close()


class ChainCheck:
    """Step 0 running in a child process (see the module doc): :meth:`result` waits for it."""

    def __init__(
        self,
        data_dir: Path,
        token: str,
        args: argparse.Namespace,
        imperfections: dict[str, Any] | None,
        say: Callable[[str], None],
    ) -> None:
        ctx = multiprocessing.get_context("spawn")
        recv, send = ctx.Pipe(duplex=False)
        child_args = argparse.Namespace(**{**vars(args), "quiet": True, "func": None})
        self._proc = ctx.Process(
            target=_child,
            args=(send, data_dir, token, child_args, imperfections),
            name="dimacq-demo-chain-check",
            daemon=True,
        )
        self._proc.start()
        send.close()  # the child holds the sending end: EOF here when it ends
        self._say = say
        self._end: tuple[Any, ...] | None = None
        self._acquired: tuple[HostLag, list[dict[str, Any]]] | None = None
        self._acquired_event = threading.Event()
        self._reader = threading.Thread(
            target=self._read, args=(recv,), name="dimacq-demo-chain-lines", daemon=True
        )
        self._reader.start()

    def _read(self, recv: Connection) -> None:
        try:
            while True:
                msg = recv.recv()
                if msg[0] == "say":
                    self._say(msg[1])
                elif msg[0] == "acquired":
                    self._acquired = (msg[1], msg[2])
                    self._acquired_event.set()
                else:
                    self._end = msg
                    return
        except EOFError:  # the child died without a word
            self._end = ("error", "DimacqError", "demo: step 0's process ended without a result")
        finally:
            recv.close()
            self._acquired_event.set()  # nothing more comes: whoever waits, wait no longer

    def acquired(
        self, lag: HostLag | None = None, runs: list[dict[str, Any]] | None = None
    ) -> None:
        """Wait until step 0 has acquired (the DAQ is free; its solve may still run): its host
        lag and acquisition added to ``lag`` and ``runs``. Its error, if it ended before, is
        raised here (:meth:`result`)."""
        self._acquired_event.wait()
        if self._acquired is None:
            self.result()  # it ended without acquiring: raises its error
            return
        child_lag, child_runs = self._acquired
        if lag is not None:
            lag.merge(child_lag)
        if runs is not None:
            runs.extend(child_runs)

    def result(self) -> Any:
        """Wait for step 0: its chain calibration (``solution_id``, factor, ...). Its error is
        raised here, as the same :mod:`dimacq.errors` class."""
        self._reader.join()
        self._proc.join()
        end = self._end or ("error", "DimacqError", "demo: step 0 gave no result")
        if end[0] != "ok":
            cls = getattr(errors, end[1], DimacqError)
            if not (isinstance(cls, type) and issubclass(cls, DimacqError)):
                cls = DimacqError
            raise cls(end[2])
        return end[1]

    def close(self) -> None:
        """Stop the child if it still runs (the demo failed before it waited for it)."""
        if self._proc.is_alive():
            self._proc.terminate()
        self._proc.join(timeout=10)
        self._reader.join(timeout=10)
