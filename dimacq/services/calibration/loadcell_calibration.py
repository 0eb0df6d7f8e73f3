"""Bench calibration of a 6-DOF load cell: the static (dead-weight) session and its simulation.

:func:`run_static_calibration` drives one load cell amplifier (the :class:`~dimacq.devices.
loadcell.LoadCell` protocol: real over CAN, or the simulator over python-can ``virtual``) through
a :class:`~dimacq.pipeline.loadcell_calibration.LoadPlan`:

1. the plan is checked first (:func:`~dimacq.pipeline.loadcell_calibration.check_load_plan`):
   nobody lifts a weight for a plan that cannot determine the matrix;
2. the amplifier runs on its own clock at a low rate (``sample_rate_hz``; no DAQ is needed);
   every series is tared by its own zero readings;
3. for every load case the operator is asked (``operator(case, sample)``: a person through the
   progress prompt, or the virtual operator on the simulated bench), the reading is left to settle
   for ``settle_s`` (the hanger swing), then averaged over windows of ``average_s`` until a window
   no longer creeps (:func:`~dimacq.pipeline.loadcell_calibration.settled_mean`), at most
   ``max_wait_s``; only the current window is held in memory;
4. readings are zero-corrected per series (tare and linear zero drift) and the matrix and the
   certificate figures are computed (:func:`~dimacq.pipeline.loadcell_calibration.
   static_certificate`).

:func:`simulated_static_calibration` runs it on the simulated dead-weight bench
(:class:`~dimacq.simulators.loadcell.bench.DeadWeightBench`) behind the amplifier simulator.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import numpy as np
from numpy.typing import NDArray

from dimacq.devices.loadcell import LoadCell
from dimacq.errors import DataError, SetupError
from dimacq.pipeline.loadcell_calibration import (
    LoadCase,
    LoadPlan,
    StaticCertificate,
    check_load_plan,
    series_zero_corrected,
    settled_mean,
    static_certificate,
)

__all__ = [
    "StaticRun",
    "StaticSettings",
    "run_static_calibration",
    "simulated_static_calibration",
]

log = logging.getLogger(__name__)

FloatArray = NDArray[np.float64]

#: ``operator(case, sample)``: set up ``case`` (the prompt is ``case.prompt()``); ``sample`` is
#: the last sample read. Returns the sample at which the load was in place, or None when a
#: person confirms (then the amplifier's counter at that moment, GET_STATUS, is taken).
Operator = Callable[[LoadCase, int], int | None]
#: ``progress(done, total, message)``
ProgressFn = Callable[[int, int, str], None]


class BenchLoadCell(LoadCell, Protocol):
    """What a bench calibration needs of an amplifier beyond an acquisition's
    :class:`~dimacq.devices.loadcell.LoadCell`: its counter now (GET_STATUS), and storing and
    reading back a matrix (:class:`dimacq.drivers.loadcell.driver.LoadCellAmplifier`)."""

    def get_status(self) -> tuple[int, int, int]: ...

    def download_calibration(self, matrix: Any) -> None: ...

    def upload_calibration(self) -> NDArray[np.float64]: ...


@dataclass(frozen=True)
class StaticSettings:
    """Timing of a dead-weight calibration.

    Attributes
    ----------
    sample_rate_hz : int
        Amplifier rate on its internal clock, S/s.
    settle_s : float
        Wait after the operator has placed a load (the hanger swing dies down).
    average_s : float
        Length of one averaging window.
    max_wait_s : float
        Give up waiting for creep to stop after this long (the reading is flagged).
    creep_tolerance : float
        Drift allowed over a window, as a fraction of the reading's change from the zero.
    read_timeout_s : float
        Extra time allowed for samples to arrive beyond their duration.
    """

    sample_rate_hz: int = 20
    settle_s: float = 20.0
    average_s: float = 5.0
    max_wait_s: float = 120.0
    creep_tolerance: float = 2e-5
    read_timeout_s: float = 10.0

    def __post_init__(self) -> None:
        if self.sample_rate_hz < 1 or self.average_s * self.sample_rate_hz < 8:
            raise SetupError(
                f"sample_rate_hz {self.sample_rate_hz} × average_s {self.average_s}: give at "
                "least 8 samples per window"
            )
        if self.settle_s < 0 or self.max_wait_s < self.average_s:
            raise SetupError("settle_s ≥ 0 and max_wait_s ≥ average_s are required")


@dataclass(frozen=True, eq=False)
class StaticRun:
    """A dead-weight calibration: the raw settled readings and the certificate.

    Attributes
    ----------
    plan : LoadPlan
    readings : ndarray, shape (n_cases, 12)
        Settled means (gauge units: mV/V for bridges), before zero correction.
    times_s : ndarray, shape (n_cases,)
        Centre of each averaging window on the amplifier's clock.
    unsettled : ndarray of bool, shape (n_cases,)
    waited_s : ndarray, shape (n_cases,)
        From the load being in place to the end of its window.
    certificate : StaticCertificate
    """

    plan: LoadPlan
    readings: FloatArray
    times_s: FloatArray
    unsettled: NDArray[np.bool_]
    waited_s: FloatArray
    certificate: StaticCertificate

    @property
    def matrix(self) -> FloatArray:
        return self.certificate.fit.matrix


def run_static_calibration(
    loadcell: BenchLoadCell,
    plan: LoadPlan,
    operator: Operator,
    *,
    settings: StaticSettings | None = None,
    progress: ProgressFn | None = None,
) -> StaticRun:
    """Calibrate ``loadcell`` with dead weights (see the module docstring).

    Raises
    ------
    SetupError
        The plan does not determine the matrix (before any load is asked for).
    DataError
        Readings with lost frames that cannot be averaged.
    """
    st = settings or StaticSettings()
    check_load_plan(plan)
    fs = st.sample_rate_hz
    n_settle = round(st.settle_s * fs)
    n_avg = round(st.average_s * fs)
    n_max = round(st.max_wait_s * fs)
    timeout = st.average_s + st.read_timeout_s
    n_cases = len(plan.cases)
    readings = np.zeros((n_cases, 12))
    times = np.zeros(n_cases)
    waited = np.zeros(n_cases)
    unsettled = np.zeros(n_cases, dtype=bool)
    zero_of_series: dict[int, FloatArray] = {}
    loadcell.set_rate(fs)
    loadcell.start(external_clock=False)
    cursor = 0
    try:
        for i, case in enumerate(plan.cases):
            msg = case.prompt()
            if progress is not None:
                progress(i, n_cases, msg)
            log.info("load case %d/%d: %s", i + 1, n_cases, msg)
            at = operator(case, cursor)
            if at is None:  # a person confirmed: settling counts from the amplifier's "now"
                at = loadcell.get_status()[2]
            t0 = max(cursor, int(at))
            if t0 + n_settle > cursor:
                loadcell.read_until(t0 + n_settle, timeout_s=st.settle_s + timeout)
                cursor = t0 + n_settle
            zero = zero_of_series.get(case.series)
            while True:
                block = loadcell.read_until(cursor + n_avg, timeout_s=timeout)
                cursor += n_avg
                g = block.gauges_v
                if not block.valid.all():
                    continue  # frames lost: take the next window
                step = np.zeros(12) if zero is None else g.mean(axis=1) - zero
                sr = settled_mean(g, step, tolerance=st.creep_tolerance)
                if sr.settled or cursor - t0 >= n_max:
                    break
            readings[i] = sr.mean
            times[i] = (cursor - n_avg / 2) / fs
            waited[i] = (cursor - t0) / fs
            unsettled[i] = not sr.settled
            if case.phase == "zero" and zero is None:
                zero_of_series[case.series] = sr.mean
            if unsettled[i]:
                log.warning("load case %d still creeping after %.0f s", i + 1, waited[i])
        if progress is not None:
            progress(n_cases, n_cases, "all load cases read; fitting the matrix")
    finally:
        try:
            loadcell.stop()
        except Exception:  # keep the original error
            log.exception("stopping the load cell amplifier failed")
    corrected = series_zero_corrected(readings, times, plan)
    cert = static_certificate(corrected, plan, unsettled=unsettled)
    return StaticRun(plan, readings, times, unsettled, waited, cert)


# ---------------------------------------------------------------------------------------------
# The simulated dead-weight bench
# ---------------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class SimulatedStaticRun:
    """A static calibration on the simulated bench with the simulator's truth beside it.

    Attributes
    ----------
    run : StaticRun
    true_matrix : ndarray (6, 12)
        ``S⁺`` of the simulated cell.
    matrix_error_rel : float
        ``‖C − S⁺‖_F / ‖S⁺‖_F``.
    cell : StrainGaugeCell
        The simulated cell (same for the inertial calibration and the circular check).
    """

    run: StaticRun
    true_matrix: FloatArray
    matrix_error_rel: float
    cell: Any
    wall_s: float


def simulated_static_calibration(
    *,
    seed: int = 0,
    node: int = 501,
    minimal_plan: bool = False,
    settings: StaticSettings | None = None,
    time_scale: float = 200.0,
    progress: ProgressFn | None = None,
    cell: Any = None,
    backend: str = "simulated",
) -> SimulatedStaticRun:
    """Dead-weight calibration of the virtual lab's strain-gauge cell ``node`` (seed ``seed``):
    the bench behind the amplifier simulator of ``backend`` (an entry of
    ``BACKENDS["loadcell-bench"]``: the CAN FD or the CANopen one), the real driver, the
    virtual operator."""
    from dimacq.backends import lookup
    from dimacq.backends.base import DeviceContext

    open_dead_weight_bench = lookup("loadcell-bench", backend)  # the table reaches simulators
    from dimacq.pipeline.loadcell_calibration import standard_load_plan

    st = settings or StaticSettings()
    t_wall = time.monotonic()
    with DeviceContext(None) as ctx:  # type: ignore[arg-type]
        amp, operator, cell = open_dead_weight_bench(
            ctx,
            node=node,
            sample_rate_hz=st.sample_rate_hz,
            time_scale=time_scale,
            cell=cell,
            seed=seed,
        )
        plan = standard_load_plan(cell.rated_load, minimal=minimal_plan)
        run = run_static_calibration(amp, plan, operator, settings=st, progress=progress)
    S = np.asarray(cell.sensitivity_mvv, float)
    C_true = np.linalg.pinv(S)
    err = float(np.linalg.norm(run.matrix - C_true) / np.linalg.norm(C_true))
    if not np.isfinite(err):
        raise DataError("static calibration produced a non-finite matrix")
    return SimulatedStaticRun(run, C_true, err, cell, time.monotonic() - t_wall)


# ---------------------------------------------------------------------------------------------
# The configured rig: open the amplifier, calibrate, keep, download
# ---------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class DownloadCheck:
    """A matrix downloaded to the amplifier and read back.

    Attributes
    ----------
    verified : int
        Elements read back equal to the downloaded float32 values (72 when all agree).
    of : int
        Elements sent (72).
    max_abs_diff : float
        Largest difference from the float32 matrix sent.
    """

    verified: int
    of: int
    max_abs_diff: float

    @property
    def ok(self) -> bool:
        return self.verified == self.of


def download_and_verify(amplifier: BenchLoadCell, matrix: FloatArray) -> DownloadCheck:
    """Download ``matrix`` to the amplifier's memory (CRC checked by the amplifier), read it
    back (CRC checked by the driver) and count the elements that agree with what was sent.

    Raises
    ------
    DeviceError
        When an element read back differs (the amplifier kept something else).
    """
    from dimacq.errors import DeviceError

    C = np.asarray(matrix, dtype=float)
    amplifier.download_calibration(C)
    back = np.asarray(amplifier.upload_calibration(), dtype=float)
    sent = C.astype("<f4").astype(float)
    same = back == sent
    check = DownloadCheck(int(same.sum()), int(same.size), float(np.max(np.abs(back - sent))))
    if not check.ok:
        raise DeviceError(
            f"calibration read back from the amplifier differs in {check.of - check.verified} "
            f"of {check.of} elements (largest {check.max_abs_diff:.3g}); download again"
        )
    return check


@dataclass(frozen=True, eq=False)
class RigCalibration:
    """A static calibration of the configured rig's cell, kept and (on request) downloaded."""

    node: int
    serial_number: str
    run: StaticRun
    calibration: Any  # LoadCellCalibration
    installed: Any  # InstalledCalibration
    download: DownloadCheck | None

    def installed_document(self) -> dict[str, Any]:
        """The calibration document as installed (with its version)."""
        import dataclasses

        doc: dict[str, Any] = dataclasses.replace(
            self.calibration, version=self.installed.version
        ).to_json()
        return doc

    def to_json(self) -> dict[str, Any]:
        cert = self.run.certificate
        return {
            "method": "static",
            "load_cell_node": self.node,
            "serial_number": self.serial_number,
            "version": self.installed.version,
            "calibration_file": str(self.installed.current_path),
            "versioned_files": [str(self.installed.json_path), str(self.installed.xml_path)],
            "nonlinearity_pct_fs": cert.nonlinearity_pct_fs.tolist(),
            "hysteresis_pct_fs": cert.hysteresis_pct_fs.tolist(),
            "uncertainty_pct_fs": cert.uncertainty_pct_fs.tolist(),
            "crosstalk_pct_fs": cert.crosstalk_pct_fs.tolist(),
            "verdict": cert.verdict,
            "reasons": list(cert.reasons),
            "downloaded": self.download is not None,
            "download_verified": None if self.download is None else self.download.verified,
            "download_elements": None if self.download is None else self.download.of,
            "matrix": self.run.matrix.tolist(),
        }


def certificate_json(cert: StaticCertificate) -> dict[str, Any]:
    """The certificate figures as stored in the calibration file."""
    return {
        "rated_load": cert.rated_load.tolist(),
        "nonlinearity_pct_fs": cert.nonlinearity_pct_fs.tolist(),
        "hysteresis_pct_fs": cert.hysteresis_pct_fs.tolist(),
        "uncertainty_pct_fs": cert.uncertainty_pct_fs.tolist(),
        "crosstalk_pct_fs": cert.crosstalk_pct_fs.tolist(),
        "matrix_std": cert.matrix_std.tolist(),
        "verdict": cert.verdict,
        "reasons": list(cert.reasons),
    }


def calibrate_rig_cell(
    settings: Any,
    operator: Operator,
    *,
    node: int | None = None,
    bench_file: str | None = None,
    download: bool = False,
    progress: ProgressFn | None = None,
) -> RigCalibration:
    """Static calibration of a load cell of the configured rig, for real.

    The rig file (``settings.rig_path``) names the cell's amplifier (CAN node id, channel) and
    its calibration file; the bench file (``bench_file`` or ``loadcell_bench.toml`` beside the
    rig file) gives the plan, the digitized hanger points and the timing. The amplifier is opened
    on ``loadcell_interface``/``loadcell_channel`` (a new cell needs no calibration file yet),
    the plan is run with ``operator`` prompting, and the result — unless its verdict is
    ``fail`` — becomes the next version of the cell's calibration file (JSON and XML kept,
    the current file replaced: the acquisition uses it from then on) and, with ``download``, is
    downloaded to the amplifier and read back.

    Raises
    ------
    SetupError
        No such load cell in the rig file, a bad bench file, a plan that cannot determine the
        matrix.
    DataError
        The calibration failed its checks (nothing installed; the readings are in the message's
        file).
    """
    import dataclasses

    from dimacq.backends import lookup
    from dimacq.backends.base import DeviceContext
    from dimacq.io.loadcell_bench import load_bench_file
    from dimacq.services.calibration.inertial_calibration import select_cell

    ctx = DeviceContext(settings)
    rig = ctx.rig_file
    entry = select_cell(rig, node)
    node = entry.node
    assert rig.path is not None
    bench = load_bench_file(bench_file or rig.path.parent / "loadcell_bench.toml")
    plan = bench.load_plan()
    check_load_plan(plan)
    t = bench.timing
    st = StaticSettings(
        sample_rate_hz=t.sample_rate_hz,
        settle_s=t.settle_s,
        average_s=t.average_s,
        max_wait_s=t.max_wait_s,
        creep_tolerance=t.creep_tolerance,
    )
    # the cell's amplifier through the loadcell backend table, as an acquisition opens it; on
    # the bench it needs no calibration file (a new cell)
    ctx.calibration_bench = node
    amp = lookup("loadcell", settings.loadcell)(ctx, entry)
    for need in ("get_status", "download_calibration", "upload_calibration"):
        if not callable(getattr(amp, need, None)):
            ctx.close()
            raise SetupError(
                f"loadcell = {settings.loadcell!r}: its amplifier has no {need}(); a dead-weight "
                "calibration needs an amplifier that reads its own clock and stores a matrix "
                "(the dimacq CAN FD amplifier)"
            )
    try:
        ident = amp.identify()
        run = run_static_calibration(amp, plan, operator, settings=st, progress=progress)
        res = install_static(
            settings,
            node,
            run,
            serial_number=str(ident.serial_number),
            bench_file=bench_file,
            rig=rig,
        )
        check = download_and_verify(amp, run.matrix) if download else None
    finally:
        ctx.close()
    return dataclasses.replace(res, download=check)


def install_static(
    settings: Any,
    node: int,
    run: StaticRun,
    *,
    serial_number: str,
    bench_file: str | None = None,
    rig: Any = None,
) -> RigCalibration:
    """Make a static run the next version of load cell ``node``'s calibration file of the rig
    file (JSON and XML kept, the current file replaced), unless its verdict is ``fail``.

    Raises
    ------
    DataError
        The certificate's verdict is ``fail``: nothing installed; the readings are kept in
        ``data_dir/calibrations/failed-*.json`` (named in the message).
    """
    import datetime as _dt
    import json

    from dimacq.io.loadcell_calibration import LoadCellCalibration, install_calibration
    from dimacq.io.rig_file import load_rig_file
    from dimacq.services.calibration.inertial_calibration import select_cell

    rig = rig if rig is not None else load_rig_file(settings.rig_path)
    entry = select_cell(rig, node)
    cert = run.certificate
    plan = run.plan
    cal = LoadCellCalibration(
        serial_number=serial_number,
        date=_dt.date.today().isoformat(),
        matrix=run.matrix,
        method="static",
        gauge_unit="mV/V",
        diagnostics={
            "residual_rel": cert.fit.residual_rel,
            "condition": cert.fit.condition,
            "load_cases": len(plan.cases),
            "unsettled_readings": int(run.unsettled.sum()),
        },
        certificate=certificate_json(cert),
        notes=f"dead-weight calibration, bench file {bench_file or 'loadcell_bench.toml'}",
    )
    if cert.verdict == "fail":
        keep = Path(settings.data_dir) / "calibrations"
        keep.mkdir(parents=True, exist_ok=True)
        raw = keep / f"failed-{serial_number}-{int(time.time())}.json"
        raw.write_text(
            json.dumps(
                {
                    "readings": run.readings.tolist(),
                    "times_s": run.times_s.tolist(),
                    **certificate_json(cert),
                }
            )
            + "\n",
            encoding="utf-8",
        )
        raise DataError(
            f"load cell {node}: calibration failed ({'; '.join(cert.reasons)}); nothing "
            f"installed, the readings are in {raw}"
        )
    installed = install_calibration(cal, rig.calibration_path(entry))
    log.info(
        "load cell %d (serial %s): calibration version %d installed at %s",
        node,
        serial_number,
        installed.version,
        installed.current_path,
    )
    return RigCalibration(node, serial_number, run, cal, installed, None)


def record_calibration(db: Any, document: dict[str, Any]) -> int:
    """Store a calibration document (``LoadCellCalibration.to_json()``) as a database record;
    returns its id."""
    from dimacq.persistence import models as m

    with db.session() as s:
        row = m.Calibration(serial=str(document["serial_number"]), body=document)
        s.add(row)
        s.flush()
        return int(row.id)
