"""Load cell calibration runs as jobs (the API): progress, and the operator's prompts answered
by a confirm call (:class:`CalibrationRuns`, composed by the calibrations service)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from dimacq.backends import BACKENDS
from dimacq.errors import SetupError
from dimacq.pipeline.loadcell_calibration import LoadCase
from dimacq.services.loadcell_calibration import (
    calibrate_rig_cell,
    certificate_json,
    simulated_static_calibration,
)

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

    ``start`` submits a ``loadcell-calibration`` job (method static): on the simulated lab the
    virtual dead-weight bench and operator (:func:`simulated_static_calibration`), on the real
    rig :func:`calibrate_rig_cell` with a person answering the
    prompts: the job's progress message is the prompt, :meth:`prompt` gives it with its case
    number, :meth:`confirm` tells the job the load is in place. The result is recorded through
    ``record`` (a calibration document → its record).
    """

    def __init__(
        self, jobs: Any, settings: Any, record: Callable[[dict[str, Any]], dict[str, Any]]
    ) -> None:
        import threading

        self.jobs = jobs
        self.settings = settings
        self.record = record
        self._lock = threading.Lock()
        self._prompts: dict[str, _Prompt] = {}

    def start(self, request: dict[str, Any]) -> dict[str, Any]:
        """Submit a run. ``request``: ``method`` (static | inertial), ``node`` (real rig),
        ``download`` (bool, real rig), ``plan`` (standard | minimal, simulated)."""
        from dimacq.errors import DeviceStateError

        extra = sorted(set(request) - {"method", "node", "download", "plan"})
        if extra:
            raise SetupError(
                f"{extra}: not calibration run items; give method, node, download, plan"
            )
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
        if method != "static":
            raise SetupError(
                "method inertial runs from the command line (dimacq loadcell calibrate "
                "--simulated --method inertial); through the API use method static"
            )
        if self.jobs.running("loadcell-calibration"):
            raise DeviceStateError("a load cell calibration is already running; wait or cancel it")

        def work(ctx: Any) -> dict[str, Any]:
            if simulated:
                return self._simulated(ctx, method, plan == "minimal")
            return self._real(ctx, node, download)

        job = self.jobs.submit("loadcell-calibration", work)
        return {"job_id": job.id, "method": method, "simulated": simulated}

    def _simulated(self, ctx: Any, method: str, minimal: bool) -> dict[str, Any]:
        import datetime as _dt

        from dimacq.io.loadcell_calibration import LoadCellCalibration

        def prog(done: int, total: int, message: str) -> None:
            ctx.check_cancelled()
            ctx.progress(done / max(total, 1), message)

        sim = simulated_static_calibration(
            minimal_plan=minimal, progress=prog, backend=self.settings.loadcell
        )
        cert = sim.run.certificate
        cal = LoadCellCalibration(
            serial_number="501",
            date=_dt.date.today().isoformat(),
            matrix=sim.run.matrix,
            method="static",
            gauge_unit="mV/V",
            certificate=certificate_json(cert),
            notes="virtual dead-weight bench (API)",
        )
        rec = self.record(cal.to_json())
        return {
            "method": "static",
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
        """The load case the job waits for (``waiting`` false when it waits for none)."""
        with self._lock:
            p = self._prompts.get(job_id)
        if p is None:
            return {"job_id": job_id, "waiting": False}
        return {
            "job_id": job_id,
            "waiting": True,
            "case": p.case,
            "of": p.of,
            "message": p.message,
        }

    def confirm(self, job_id: str, case: int) -> dict[str, Any]:
        """The operator has put load case ``case`` in place."""
        from dimacq.errors import DeviceStateError

        with self._lock:
            p = self._prompts.get(job_id)
            if p is None:
                raise DeviceStateError(f"job {job_id} is not waiting for a load case")
            if p.case != case:
                raise SetupError(
                    f"case {case}: job {job_id} waits for load case {p.case} ({p.message})"
                )
            del self._prompts[job_id]  # answered: no longer offered to prompt()
            p.confirmed.set()
        return {"job_id": job_id, "confirmed": case}
