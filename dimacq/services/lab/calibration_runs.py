"""Load cell calibration runs as jobs (the API): progress, and the operator's prompts answered
by a confirm call (:class:`CalibrationRuns`, composed by the calibrations service)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from dimacq.backends import BACKENDS
from dimacq.errors import SetupError
from dimacq.pipeline.loadcell_calibration import LoadCase
from dimacq.services.calibration.loadcell_calibration import (
    calibrate_rig_cell,
    simulated_static_calibration,
)
from dimacq.services.lab.ownership import DeviceOwners

#: The most averages per input a calibration run asks (an impact test's limit).
MAX_AVERAGES = 100

__all__ = ["CalibrationRuns"]


# ---------------------------------------------------------------------------------------------
# Calibration runs as jobs (the API): progress and operator prompts answered by a confirm call
# ---------------------------------------------------------------------------------------------
@dataclass
class _Prompt:
    case: int
    of: int
    message: str
    confirmed: Any  # threading.Event


class CalibrationRuns:
    """Load cell calibrations run as background jobs.

    ``start`` submits a ``loadcell-calibration`` job. Static: on the simulated lab the
    virtual dead-weight bench and operator (:func:`simulated_static_calibration`), on the real
    rig :func:`calibrate_rig_cell` with a person answering the prompts: the job's progress
    message is the prompt, :meth:`prompt` gives it with its case number, :meth:`confirm` tells
    the job the load is in place. Inertial: the calibration mass on the cell through the rig
    builder (:func:`~dimacq.services.calibration.inertial_calibration.run_inertial_calibration`); a person
    strikes when asked: :meth:`prompt` gives the strike request (``kind`` ``strike``: the input's
    node, direction and line of action, the average, as the acquisition's "strike point 101
    along −X"; the trigger sees the hit, nothing to confirm). Then, on request, the circular
    check (its strikes asked the same way). The result is
    installed as the cell's next calibration version (the simulated lab: in a scratch copy of
    the rig under ``data_dir/calibration-runs/<job>``, the shipped files stay as they are) and
    recorded through ``record`` (a calibration document → its record).
    """

    def __init__(
        self,
        jobs: Any,
        settings: Any,
        record: Callable[[dict[str, Any]], dict[str, Any]],
        owners: DeviceOwners | None = None,
    ) -> None:
        import threading

        #: the stand's device owners: a run holds the load cell (and, inertial, the DAQ)
        self.owners = owners if owners is not None else DeviceOwners()
        self.jobs = jobs
        self.settings = settings
        self.record = record
        self._lock = threading.Lock()
        self._prompts: dict[str, _Prompt] = {}
        self._strikes: dict[str, tuple[str, Any]] = {}  # job → (stage, StrikeRequest)

    def start(self, request: dict[str, Any]) -> dict[str, Any]:
        """Submit a run. ``request``: ``method`` (static | inertial), ``node`` (real rig),
        ``download`` (bool, real rig), ``plan`` (standard | minimal, simulated),
        ``circular_check`` (bool: the circular check after the calibration; default true on the
        simulated lab, false on a real rig, where it needs a person to strike again)."""
        from dimacq.errors import DeviceStateError

        items = {"method", "node", "download", "plan", "circular_check", "averages_per_input"}
        extra = sorted(set(request) - items)
        if extra:
            raise SetupError(f"{extra}: not calibration run items; give {', '.join(sorted(items))}")
        method = request.get("method", "static")
        if method not in ("static", "inertial"):
            raise SetupError(f"method {method!r}: use static or inertial")
        node = request.get("node")
        if node is not None and (not isinstance(node, int) or isinstance(node, bool)):
            raise SetupError(f"node {node!r}: give the load cell's node number (an integer)")
        download = request.get("download", False)
        if not isinstance(download, bool):
            raise SetupError(f"download {download!r}: give true or false")
        plan = request.get("plan", "standard")
        if plan not in ("standard", "minimal"):
            raise SetupError(f"plan {plan!r}: use standard or minimal")
        # a backend with a simulated dead-weight bench (BACKENDS["loadcell-bench"]) runs there
        simulated = self.settings.loadcell in BACKENDS["loadcell-bench"]
        check = request.get("circular_check", simulated)
        if not isinstance(check, bool):
            raise SetupError(f"circular_check {check!r}: give true or false")
        averages = request.get("averages_per_input")
        if averages is not None and (
            not isinstance(averages, int)
            or isinstance(averages, bool)
            or not 1 <= averages <= MAX_AVERAGES
        ):
            raise SetupError(
                f"averages_per_input {averages!r}: give an integer 1–{MAX_AVERAGES} (what an "
                "impact test takes per input; default: the bench file's)"
            )
        cfg = {} if averages is None else {"averages_per_input": averages}
        devices = ("loadcell", "daq") if method == "inertial" else ("loadcell",)
        claim = self.owners.claim(devices, f"a load cell calibration run ({method})")
        if self.jobs.running("loadcell-calibration"):  # another process of this stand's service
            self.owners.release(claim)
            raise DeviceStateError("a load cell calibration is already running; wait or cancel it")

        def work(ctx: Any) -> dict[str, Any]:
            try:
                return run(ctx)
            finally:
                self.owners.release(claim)

        def run(ctx: Any) -> dict[str, Any]:
            settings = self.settings
            if simulated:  # the simulated lab's files stay as shipped: a scratch copy per job
                from pathlib import Path

                from dimacq.services.calibration.inertial_calibration import scratch_rig

                where = Path(settings.data_dir) / "calibration-runs" / ctx.job_id
                settings = scratch_rig(settings, where)
            if method == "inertial":
                result = self._inertial(ctx, settings, node, download, simulated, cfg)
            elif simulated:
                result = self._simulated(ctx, settings, plan == "minimal")
            else:
                result = self._real(ctx, node, download)
            if check and result.get("verdict") != "fail":
                result.update(self._check(ctx, settings, result["load_cell_node"], cfg))
            return result

        try:
            job = self.jobs.submit("loadcell-calibration", work)
        except BaseException:
            self.owners.release(claim)
            raise
        self.owners.rename(claim, f"load cell calibration run {job.id} ({method})")
        return {"job_id": job.id, "method": method, "simulated": simulated}

    def _strike_prompt(self, ctx: Any, stage: str) -> Callable[[Any], None]:
        """Keep the latest strike request of job ``ctx`` for :meth:`prompt`."""

        def asked(req: Any) -> None:
            with self._lock:
                self._strikes[ctx.job_id] = (stage, req)

        return asked

    def _strikes_done(self, job_id: str) -> None:
        with self._lock:
            self._strikes.pop(job_id, None)

    def _job_progress(self, ctx: Any, stage: str) -> Callable[[float, str], None]:
        def show(fraction: float, message: str) -> None:
            ctx.check_cancelled()
            ctx.progress(fraction, f"{stage}: {message}")

        return show

    def _inertial(
        self,
        ctx: Any,
        settings: Any,
        node: int | None,
        download: bool,
        simulated: bool,
        cfg: dict[str, Any],
    ) -> dict[str, Any]:
        """The inertial bench through the rig builder; on a real rig the job's progress asks
        the person for every strike (as an acquisition does)."""
        from dimacq.io.rig_file import load_rig_file
        from dimacq.services.calibration.inertial_calibration import (
            install_inertial,
            installed_document,
            run_inertial_calibration,
            select_cell,
        )
        from dimacq.services.calibration.loadcell_calibration import download_and_verify

        try:
            run, verified = run_inertial_calibration(
                settings,
                node=node,
                cfg=cfg,
                on_progress=self._job_progress(ctx, "inertial bench"),
                download=download_and_verify if download else None,
                on_strike=self._strike_prompt(ctx, "inertial bench"),
            )
        finally:
            self._strikes_done(ctx.job_id)
        rig = load_rig_file(settings.rig_path)
        installed = install_inertial(rig, select_cell(rig, run.node), run)
        rec = self.record(installed_document(run.calibration(), installed.version))
        return {
            "method": "inertial",
            "load_cell_node": run.node,
            "serial_number": run.serial_number,
            "version": installed.version,
            "calibration_file": None if simulated else str(installed.current_path),
            "nonlinearity_pct_fs": None,
            "hysteresis_pct_fs": None,
            "uncertainty_pct_fs": run.uncertainty_pct_fs(),
            "matrix_uncertainty_rel": run.matrix_uncertainty_rel(),
            "verdict": run.verdict,
            "reasons": list(run.reasons),
            "band_hz": list(run.band_hz),
            "fit": run.fit_json(),
            "downloaded": verified is not None,
            "download_verified": None if verified is None else verified.verified,
            "matrix": run.matrix.tolist(),
            "record_id": rec["id"],
        }

    def _check(self, ctx: Any, settings: Any, node: int, cfg: dict[str, Any]) -> dict[str, Any]:
        from dimacq.services.calibration.circular_check import circular_check

        try:
            chk = circular_check(
                settings,
                node=node,
                cfg=cfg,
                on_progress=self._job_progress(ctx, "circular check"),
                on_strike=self._strike_prompt(ctx, "circular check"),
            )
        finally:
            self._strikes_done(ctx.job_id)
        return chk.to_json()

    def _simulated(self, ctx: Any, settings: Any, minimal: bool) -> dict[str, Any]:
        """The simulated dead-weight bench; installed in the job's scratch rig (so that the
        circular check reads it) and recorded."""
        from dimacq.services.calibration.inertial_calibration import select_cell
        from dimacq.services.calibration.loadcell_calibration import install_static

        def prog(done: int, total: int, message: str) -> None:
            ctx.check_cancelled()
            ctx.progress(done / max(total, 1), message)

        from dimacq.io.rig_file import load_rig_file

        node = select_cell(load_rig_file(settings.rig_path), None).node
        sim = simulated_static_calibration(
            node=node, minimal_plan=minimal, progress=prog, backend=self.settings.loadcell
        )
        cert = sim.run.certificate
        res = install_static(settings, node, sim.run, serial_number=str(node))
        rec = self.record(res.installed_document())
        return {
            "method": "static",
            "load_cell_node": node,
            "version": res.installed.version,
            "matrix_error_rel": sim.matrix_error_rel,
            "nonlinearity_pct_fs": cert.nonlinearity_pct_fs.tolist(),
            "hysteresis_pct_fs": cert.hysteresis_pct_fs.tolist(),
            "uncertainty_pct_fs": cert.uncertainty_pct_fs.tolist(),
            "crosstalk_pct_fs": cert.crosstalk_pct_fs.tolist(),
            "verdict": cert.verdict,
            "reasons": list(cert.reasons),
            "matrix": sim.run.matrix.tolist(),
            "record_id": rec["id"],
        }

    def _real(self, ctx: Any, node: int | None, download: bool) -> dict[str, Any]:
        import threading

        def operator(case: LoadCase, _sample: int) -> None:
            total = len(plan_cases) if plan_cases else 0
            idx = case_index["i"]
            ev = threading.Event()
            with self._lock:
                self._prompts[ctx.job_id] = _Prompt(idx, total, case.prompt(), ev)
            ctx.progress(
                idx / max(total, 1),
                f"load case {idx + 1}/{total}: {case.prompt()} — confirm when in place",
            )
            try:
                while not ev.wait(0.1):
                    ctx.check_cancelled()
            finally:
                with self._lock:
                    if self._prompts.get(ctx.job_id) is not None and not ev.is_set():
                        self._prompts.pop(ctx.job_id, None)

        plan_cases: list[int] = []
        case_index = {"i": 0}

        def progress(done: int, total: int, message: str) -> None:
            ctx.check_cancelled()
            plan_cases[:] = list(range(total))
            case_index["i"] = done
            ctx.progress(done / max(total, 1), message)

        res = calibrate_rig_cell(
            self.settings, operator, node=node, download=download, progress=progress
        )
        rec = self.record(res.installed_document())
        return {**res.to_json(), "record_id": rec["id"]}

    def prompt(self, job_id: str) -> dict[str, Any]:
        """What the job waits for from the operator: ``kind`` ``load_case`` (``case``, ``of``,
        ``message``: confirm when in place) or ``strike`` (``stage``, ``input_index``,
        ``n_inputs``, ``node``, ``direction``, ``direction_gcs``, ``average``, ``averages``,
        ``request``, ``message``: the latest request, until the stage's strikes are done);
        ``waiting`` false when it waits for none."""
        with self._lock:
            p = self._prompts.get(job_id)
            strike = self._strikes.get(job_id)
        if p is not None:
            return {
                "job_id": job_id,
                "waiting": True,
                "kind": "load_case",
                "case": p.case,
                "of": p.of,
                "message": p.message,
            }
        if strike is not None:
            stage, req = strike
            return {
                "job_id": job_id,
                "waiting": True,
                "kind": "strike",
                "stage": stage,
                **req.to_json(),
            }
        return {"job_id": job_id, "waiting": False}

    def confirm(self, job_id: str, case: int) -> dict[str, Any]:
        """The operator has put load case ``case`` in place."""
        from dimacq.errors import DeviceStateError

        with self._lock:
            p = self._prompts.get(job_id)
            if p is None and job_id in self._strikes:
                raise DeviceStateError(
                    f"job {job_id} waits for a strike, not a load case: strike as its prompt "
                    "says (the trigger sees the hit)"
                )
            if p is None:
                raise DeviceStateError(f"job {job_id} is not waiting for a load case")
            if p.case != case:
                raise SetupError(
                    f"case {case}: job {job_id} waits for load case {p.case} ({p.message})"
                )
            del self._prompts[job_id]  # answered: no longer offered to prompt()
            p.confirmed.set()
        return {"job_id": job_id, "confirmed": case}
