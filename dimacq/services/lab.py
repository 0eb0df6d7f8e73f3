"""The lab service: devices, geometry, setups, FRFs, solutions and jobs behind one object.

:class:`Lab` is what the REST API (and anything else) drives. It opens the configured devices,
keeps every result in the database (:mod:`dimacq.persistence`) as soon as it exists, and runs
long work as background jobs (:mod:`dimacq.services.jobs`). The chain of a DIM test:

1. digitize points (:meth:`Lab.digitize`; each accepted point is committed at once), register each
   array position (patch) from reference nodes (:meth:`Lab.register_patch`);
2. orient each triaxial sensor from its digitized jig indentations (:meth:`Lab.fit_orientation`)
   and take each input's line of action (:meth:`Lab.fit_line_of_action`);
3. build the test setup from that geometry (:meth:`Lab.setup_from_geometry`) or import one;
4. acquire (:meth:`Lab.start_acquisition`, a job; every completed average is on disk and in the
   database before the next starts) → FRFs; or import FRFs (UFF);
5. select data and solve (:meth:`Lab.solve`).

No HTTP here; errors are :mod:`dimacq.errors` exceptions with messages naming the item and the fix.
Lookups of unknown ids return ``None`` (the API turns that into 404).
"""

from __future__ import annotations

import importlib
import io
import json
import logging
import tempfile
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray
from sqlalchemy import select

from dimacq.config import Settings
from dimacq.errors import (
    DataError,
    DeviceError,
    DeviceNotFoundError,
    DeviceStateError,
    DimacqError,
    SetupError,
)
from dimacq.model.frf import Channel, FrfData
from dimacq.model.setup import Excitation, LoadCell, ResponseChannel, TestSetup
from dimacq.persistence import ArrayStore, Database, open_database
from dimacq.persistence import models as m
from dimacq.services.jobs import FINAL_STATES, JobContext, JobManager

__all__ = ["DeviceInfo", "Lab", "frf_from_arrays", "frf_to_arrays"]

log = logging.getLogger(__name__)

FloatArray = NDArray[np.float64]


# ---------------------------------------------------------------------------------- FRF files
def frf_to_arrays(frf: FrfData) -> tuple[dict[str, NDArray[Any]], dict[str, Any]]:
    """FRF data as HDF5 datasets and attributes."""
    arrays: dict[str, NDArray[Any]] = {"frequencies_hz": frf.frequencies_hz, "H": frf.H}
    if frf.coherence is not None:
        arrays["coherence"] = frf.coherence
    attrs = {
        "outputs": [c.as_dict() for c in frf.outputs],
        "output_kinds": list(frf.output_kinds),
        "inputs": [c.as_dict() for c in frf.inputs],
        "meta": dict(frf.meta),
    }
    return arrays, attrs


def frf_from_arrays(arrays: Mapping[str, NDArray[Any]], attrs: Mapping[str, Any]) -> FrfData:
    """Inverse of :func:`frf_to_arrays`."""
    return FrfData(
        frequencies_hz=np.asarray(arrays["frequencies_hz"], dtype=float),
        H=np.asarray(arrays["H"], dtype=complex),
        outputs=tuple(Channel(int(c["node"]), int(c["direction"])) for c in attrs["outputs"]),
        output_kinds=tuple(attrs["output_kinds"]),
        inputs=tuple(Channel(int(c["node"]), int(c["direction"])) for c in attrs["inputs"]),
        coherence=None if "coherence" not in arrays else np.asarray(arrays["coherence"], float),
        meta={str(k): str(v) for k, v in dict(attrs.get("meta", {})).items()},
    )


# ---------------------------------------------------------------------------------- devices
@dataclass
class DeviceInfo:
    """State of one configured device."""

    name: str
    kind: Literal["digitizer", "daq", "loadcell"]
    address: str
    simulated: bool
    connected: bool = False
    identity: dict[str, Any] = field(default_factory=dict)
    error: str = ""

    def as_dict(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "kind": self.kind,
            "address": self.address,
            "simulated": self.simulated,
            "connected": self.connected,
            "identity": dict(self.identity),
            "error": self.error,
        }


def _vec(v: Sequence[float] | FloatArray) -> list[float]:
    return [float(x) for x in np.asarray(v, dtype=float).reshape(-1)]


class Lab:
    """The lab: configuration, database, array files, devices and jobs.

    Parameters
    ----------
    settings : Settings
    open_devices : bool
        Open the configured devices now (:meth:`connect_all`); failures are recorded in the
        device list, not raised, so the service starts without hardware.
    rig_factory : callable (settings, setup, config) -> Rig, optional
        Builds the acquisition rig (:class:`dimacq.services.lab_rig.Rig`); default
        :func:`dimacq.services.lab_rig.build_rig` on the configured devices.
    """

    def __init__(
        self,
        settings: Settings,
        *,
        open_devices: bool = True,
        rig_factory: Callable[[Settings, TestSetup, Mapping[str, Any]], Any] | None = None,
    ) -> None:
        self.settings = settings
        self._rig_factory = rig_factory
        settings.data_dir.mkdir(parents=True, exist_ok=True)
        self.db: Database = open_database(settings.db_url)
        self.arrays = ArrayStore(settings.data_dir / "arrays")
        self.jobs = JobManager(persist=self._persist_job)
        self.started_monotonic = time.monotonic()
        self.version = _version()
        self._device_lock = threading.RLock()
        self._digitizer: Any = None
        self._dig_session: Any = None
        self._sim_names: list[str] = []
        self.devices: dict[str, DeviceInfo] = {
            "digitizer": DeviceInfo(
                "digitizer",
                "digitizer",
                settings.digitizer_url,
                settings.digitizer_url.startswith("simdigitizer://"),
            ),
            "daq": DeviceInfo("daq", "daq", f"usb:{settings.daq_backend}", settings.simulated),
            "loadcell": DeviceInfo(
                "loadcell",
                "loadcell",
                f"can:{settings.loadcell_interface}:{settings.loadcell_channel}",
                # With the simulated lab the cells are the lab's own; otherwise "virtual" is
                # just another python-can interface with whatever listens on it.
                settings.simulated,
            ),
        }
        self._recover()
        if open_devices:
            self.connect_all()

    # ------------------------------------------------------------------ lifetime
    def _recover(self) -> None:
        """After a restart: jobs that were running are interrupted; orphan average files
        (written but not yet committed when the service died) are registered."""
        with self.db.session() as s:
            for row in s.scalars(select(m.JobRow)):
                if row.state not in FINAL_STATES:
                    row.state = "interrupted"
                    row.message = "the service stopped while this job ran; completed work is kept"
                    row.finished_at = m.utcnow()
                self.jobs.adopt(
                    {
                        "id": row.id,
                        "kind": row.kind,
                        "state": row.state,
                        "progress": row.progress,
                        "message": row.message,
                        "result": row.result,
                        "error": row.error,
                        "created_at": row.created_at,
                        "finished_at": row.finished_at,
                    }
                )
            for acq in s.scalars(select(m.Acquisition)):
                if acq.state in ("running", "configured-running"):
                    acq.state = "interrupted"
                    acq.message = (
                        "the service stopped during the acquisition; completed averages are kept"
                    )
            known = set(s.scalars(select(m.Average.path)))
            for rel in self.arrays.orphans("acquisitions", known):
                try:
                    _, attrs = self.arrays.read(rel)
                    s.add(
                        m.Average(
                            acquisition_id=int(attrs["acquisition_id"]),
                            input_index=int(attrs["input_index"]),
                            number=int(attrs["number"]),
                            accepted=bool(attrs["accepted"]),
                            reason=str(attrs.get("reason", "")),
                            path=rel,
                        )
                    )
                    log.info("recovered average file %s", rel)
                except (OSError, KeyError, DataError) as err:
                    log.warning("average file %s is unreadable (%s); left in place", rel, err)

    def close(self) -> None:
        """Cancel jobs, close devices and the database."""
        self.jobs.shutdown()
        self.disconnect_all()
        self.db.close()

    def status(self) -> dict[str, Any]:
        """Cheap in-memory status (no I/O): devices, running jobs, uptime."""
        running = self.jobs.running()
        return {
            "service": "dimacq",
            "version": self.version,
            "schema_version": self.db.schema_version,
            "uptime_s": time.monotonic() - self.started_monotonic,
            "devices": {
                k: {"connected": d.connected, "error": d.error} for k, d in self.devices.items()
            },
            "jobs_running": [
                {"id": j.id, "kind": j.kind, "progress": j.progress, "message": j.message}
                for j in running
            ],
        }

    # ------------------------------------------------------------------ jobs persistence
    def _persist_job(self, snap: dict[str, Any]) -> None:
        with self.db.session() as s:
            row = s.get(m.JobRow, snap["id"])
            if row is None:
                row = m.JobRow(id=snap["id"], kind=snap["kind"], state=snap["state"])
                s.add(row)
            row.state = snap["state"]
            row.progress = float(snap["progress"])
            row.message = snap["message"]
            row.result = snap["result"]
            row.error = snap["error"]
            if snap["finished_at"]:
                row.finished_at = m.utcnow()

    # ------------------------------------------------------------------ devices
    def connect_all(self) -> None:
        for name in self.devices:
            try:
                self.connect(name)
            except DimacqError as err:
                log.warning("device %s not connected: %s", name, err)

    def disconnect_all(self) -> None:
        with self._device_lock:
            if self._digitizer is not None:
                try:
                    self._digitizer.close()
                except Exception:  # closing a vanished port must not stop the shutdown
                    log.exception("closing the digitizer failed")
                self._digitizer = None
                self._dig_session = None
            if self._sim_names:
                from dimacq.simulators.digitizer import unregister_device

                for n in self._sim_names:
                    unregister_device(n)
                self._sim_names = []
            for d in self.devices.values():
                d.connected = False

    def device(self, name: str) -> DeviceInfo | None:
        return self.devices.get(name)

    def connect(self, name: str) -> DeviceInfo:
        """(Re)open one device; the device list records the outcome."""
        info = self.devices.get(name)
        if info is None:
            raise SetupError(f"device {name!r} is unknown; use one of {sorted(self.devices)}")
        with self._device_lock:
            try:
                if info.kind == "digitizer":
                    self._connect_digitizer(info)
                else:
                    self._connect_acquisition_device(info)
            except DimacqError as err:
                info.connected = False
                info.error = str(err)
                raise
            info.error = ""
            return info

    def identify(self, name: str) -> dict[str, Any]:
        info = self.devices.get(name)
        if info is None:
            raise SetupError(f"device {name!r} is unknown; use one of {sorted(self.devices)}")
        if not info.connected:
            raise DeviceStateError(
                f"device {name} is not connected ({info.error or 'closed'}); connect it first"
            )
        if info.kind == "digitizer":
            with self._device_lock:
                ident = self._digitizer.identify()
            info.identity = _identity_dict(ident)
        return dict(info.identity)

    def _connect_digitizer(self, info: DeviceInfo) -> None:
        from dimacq.drivers.digitizer import SerialDigitizer
        from dimacq.services.digitizing import DigitizingSession, load_array_config

        url = self.settings.digitizer_url
        if self._digitizer is not None:
            try:
                self._digitizer.close()
            except Exception:
                log.exception("closing the digitizer failed")
            self._digitizer = None
        if url.startswith("simdigitizer://"):
            import dimacq.simulators.digitizer as simdig

            name = url.split("://", 1)[1].split("?", 1)[0]
            simdig.get_device(url)  # create it from the query on first use
            if name not in self._sim_names:
                self._sim_names.append(name)
        cfg = load_array_config()
        driver = SerialDigitizer.from_url(url, timeout_s=2.0)
        ident = driver.identify()
        driver.configure(
            emitters=2, microphones=len(cfg.array.microphones_m), averaging=1, bar_repeats=4
        )
        self._digitizer = driver
        session = DigitizingSession(
            driver, cfg.geometry(), cfg.limits(), shots_per_point=5, journal=self._journal_point
        )
        with self.db.session() as s:
            patches = list(s.scalars(select(m.PatchRow).order_by(m.PatchRow.index)))
            if not patches:
                s.add(m.PatchRow(index=0, name="patch 0"))
        for p in patches[1:]:
            session.new_patch(p.name)
        self._dig_session = session
        info.connected = True
        info.identity = _identity_dict(ident)

    def _connect_acquisition_device(self, info: DeviceInfo) -> None:
        if info.simulated:
            scenarios = _virtual_lab_module()
            if scenarios is None:
                raise DeviceNotFoundError(
                    f"{info.name}: the simulated {info.kind} needs the virtual lab scenarios "
                    "(dimacq.simulators.lab.scenarios), which are not installed in this build"
                )
            spec = scenarios.load_scenario(self.settings.scenario)  # SetupError if unknown
            info.connected = True
            info.identity = {
                "model": "simulated USB DAQ (pyusb backend)"
                if info.kind == "daq"
                else "simulated CAN FD load cell amplifier (python-can virtual)",
                "scenario": spec.name,
                "description": spec.description,
            }
            return
        self._probe_real_device(info)

    def _probe_real_device(self, info: DeviceInfo) -> None:
        """Open the real DAQ or every load cell amplifier of the rig file, identify, close
        (:func:`dimacq.services.lab_rig.build_rig` opens them again for each acquisition)."""
        from dimacq.io.rig_file import load_rig_file
        from dimacq.services import lab_rig

        rig_file = load_rig_file(self.settings.rig_path)
        if info.kind == "daq":
            daq = lab_rig.open_daq(self.settings, rig_file)
            try:
                ident = daq.identify()
            finally:
                daq.close()
            info.identity = {"model": "dimacq USB DAQ", **_identity_dict(ident)}
        else:
            cells = {}
            for entry in rig_file.load_cells:
                amp, close = lab_rig.open_loadcell(self.settings, rig_file, entry)
                try:
                    cells[str(entry.node)] = {
                        "node_id": entry.node_id,
                        **_identity_dict(amp.identify()),
                    }
                finally:
                    close()
            info.identity = {"model": "CAN FD load cell amplifier", "load_cells": cells}
        info.connected = True

    # ------------------------------------------------------------------ digitizer
    def _session(self) -> Any:
        info = self.devices["digitizer"]
        if self._dig_session is None or not info.connected:
            raise DeviceStateError(
                f"digitizer is not connected ({info.error or 'closed'}); POST "
                "/api/devices/digitizer/connect first"
            )
        return self._dig_session

    def _journal_point(self, point: Any) -> None:
        with self.db.session() as s:
            s.add(
                m.DigitizedPointRow(
                    label=point.label,
                    patch=int(point.patch),
                    position_array_m=_vec(point.position_array_m),
                    spread_m=_vec(point.spread_m),
                    n_shots=int(point.n_shots),
                    n_used=int(point.n_used),
                    seqs=[int(q) for q in point.seqs],
                )
            )

    def place_simulated_probe(self, tip_m: Sequence[float], axis: Sequence[float]) -> None:
        """Simulation only: put the simulator's probe tip at ``tip_m`` (array coordinates)."""
        with self._device_lock:
            self._session()
            info = self.devices["digitizer"]
            if not str(info.identity.get("model", "")).endswith("SIM"):
                raise DeviceStateError(
                    f"digitizer {info.identity.get('model', '?')} is a real array: the probe is placed "
                    "by hand, sim_probe is only for the simulator"
                )
            a = np.asarray(axis, dtype=float)
            n = float(np.linalg.norm(a))
            if not np.isfinite(n) or n == 0:
                raise SetupError("sim_probe.axis: give a non-zero direction of the probe")
            a = a / n
            t = np.asarray(tip_m, dtype=float)
            if not np.all(np.isfinite(t)):
                raise SetupError("sim_probe.tip_m: give three finite numbers (metres)")
            vals = ",".join(f"{v:.6f}" for v in (*t, *a))
            self._digitizer.command(f"SIM:PROBE {vals}")

    def digitize(self, label: str, shots: int | None = None) -> dict[str, Any]:
        """Digitize one point of the current patch; it is committed before this returns."""
        if not label or len(label) > 200:
            raise SetupError("label: give a non-empty point label of at most 200 characters")
        if shots is not None and not 1 <= shots <= 100:
            raise SetupError(f"shots {shots}: give 1..100 accepted shots per point")
        with self._device_lock:
            point = self._session().digitize(label, shots)
        return point.to_json()

    def fire_shots(self, n: int) -> dict[str, Any]:
        """Fire ``n`` raw shots and triangulate them (speed of sound, tip, accepted)."""
        from dimacq.pipeline.digitizing.triangulation import triangulate
        from dimacq.services.digitizing import records_to_arrays

        if not 1 <= n <= 100:
            raise SetupError(f"n {n}: give 1..100 shots")
        with self._device_lock:
            sess = self._session()
            records = [self._digitizer.fire() for _ in range(n)]
        counts, bar, avg, status, seq = records_to_arrays(records)
        sol = triangulate(
            counts, bar, sess.geometry, averaging=avg, status=status, limits=sess.limits
        )
        return {
            "shots": [
                {
                    "seq": int(seq[i]),
                    "tip_array_m": _vec(sol.tip_m[i]),
                    "speed_of_sound_m_s": float(sol.speed_m_s[i]),
                    "accepted": bool(sol.accepted[i]),
                }
                for i in range(n)
            ],
            "speed_of_sound_m_s": float(np.nanmedian(sol.speed_m_s)),
        }

    def points(self) -> list[dict[str, Any]]:
        with self.db.session() as s:
            rows = list(s.scalars(select(m.DigitizedPointRow).order_by(m.DigitizedPointRow.id)))
            regs = {p.index: p.registration for p in s.scalars(select(m.PatchRow))}
        out = []
        for r in rows:
            d = _point_dict(r)
            reg = regs.get(r.patch)
            d["position_m"] = _apply_reg(reg, r.position_array_m) if reg else None
            out.append(d)
        return out

    def patches(self) -> list[dict[str, Any]]:
        with self.db.session() as s:
            return [
                {"index": p.index, "name": p.name, "registration": p.registration}
                for p in s.scalars(select(m.PatchRow).order_by(m.PatchRow.index))
            ]

    def new_patch(self, name: str | None = None) -> dict[str, Any]:
        """The array moved: later points belong to a new patch (register it again)."""
        with self._device_lock:
            sess = self._session()
            p = sess.new_patch(name)
        with self.db.session() as s:
            s.merge(m.PatchRow(index=p.index, name=p.name))
        return {"index": p.index, "name": p.name, "registration": None}

    def set_reference_nodes(self, nodes: Mapping[str, Sequence[float]]) -> list[dict[str, Any]]:
        for lab, pos in nodes.items():
            if len(pos) != 3 or not np.all(np.isfinite(pos)):
                raise SetupError(
                    f"reference node {lab!r}: give three finite GCS coordinates in metres"
                )
        with self.db.session() as s:
            for lab, pos in nodes.items():
                s.merge(m.ReferenceNode(label=lab, position_m=_vec(pos)))
        return self.reference_nodes()

    def reference_nodes(self) -> list[dict[str, Any]]:
        with self.db.session() as s:
            return [
                {"label": r.label, "position_m": list(r.position_m)}
                for r in s.scalars(select(m.ReferenceNode).order_by(m.ReferenceNode.label))
            ]

    def _latest_points(self, patch: int | None = None) -> dict[tuple[int, str], list[float]]:
        with self.db.session() as s:
            q = select(m.DigitizedPointRow).order_by(m.DigitizedPointRow.id)
            if patch is not None:
                q = q.where(m.DigitizedPointRow.patch == patch)
            return {(r.patch, r.label): list(r.position_array_m) for r in s.scalars(q)}

    def register_patch(
        self, patch: int | None = None, method: str = "rigid", labels: Sequence[str] | None = None
    ) -> dict[str, Any]:
        """Register a patch (default: the current one) from the reference nodes it holds."""
        from dimacq.pipeline.digitizing.registration import register

        if method not in ("rigid", "similarity", "affine"):
            raise SetupError(f"method {method!r}: use rigid, similarity or affine")
        with self.db.session() as s:
            last = s.scalars(select(m.PatchRow.index).order_by(m.PatchRow.index.desc())).first()
            idx = int(last or 0) if patch is None else patch
            if s.get(m.PatchRow, idx) is None:
                raise SetupError(f"patch {idx} does not exist; list patches to find its index")
            refs = {r.label: r.position_m for r in s.scalars(select(m.ReferenceNode))}
        pts = {lab: p for (pi, lab), p in self._latest_points(idx).items()}
        use = [lab for lab in (labels or sorted(refs)) if lab in refs and lab in pts]
        if len(use) < 3:
            raise SetupError(
                f"patch {idx}: {len(use)} reference node(s) digitized ({use}); digitize at least 4 "
                "reference nodes with known GCS coordinates in this patch (3 only for rigid frames)"
            )
        reg = register(
            np.array([pts[u] for u in use]), np.array([refs[u] for u in use]), method=method
        )
        body = {
            "matrix": np.asarray(reg.matrix).tolist(),
            "offset_m": _vec(reg.offset_m),
            "method": reg.method,
            "scale": float(reg.scale),
            "labels": use,
            "residual_norm_m": _vec(reg.residual_norm_m),
            "rms_m": float(reg.rms_m),
            "planarity": float(reg.planarity),
        }
        with self.db.session() as s:
            row = s.get(m.PatchRow, idx)
            assert row is not None
            row.registration = body
        with self._device_lock:
            if self._dig_session is not None and idx < len(self._dig_session.patches):
                self._dig_session.patches[idx].registration = reg
        return {"index": idx, "registration": body}

    def global_points(self) -> dict[str, FloatArray]:
        """Label → GCS position (points of registered patches; the latest wins)."""
        with self.db.session() as s:
            regs = {p.index: p.registration for p in s.scalars(select(m.PatchRow))}
        out: dict[str, FloatArray] = {}
        for (patch, label), pos in self._latest_points().items():
            reg = regs.get(patch)
            if reg:
                out[label] = np.asarray(_apply_reg(reg, pos))
        return out

    def fit_orientation(
        self, node: int, prefix: str | None = None, method: str = "rigid"
    ) -> dict[str, Any]:
        """Orientation of the triax at ``node`` from jig points labelled ``<prefix><jig label>``."""
        from dimacq.pipeline.digitizing.orientation import fit_orientation
        from dimacq.services.digitizing import load_jig

        if method not in ("rigid", "affine", "cross"):
            raise SetupError(f"method {method!r}: use rigid, affine or cross")
        prefix = f"jig{node}/" if prefix is None else prefix
        jig = load_jig()
        pts = self.global_points()
        have = [i for i, lab in enumerate(jig.labels) if prefix + lab in pts]
        if len(have) < 4:
            raise SetupError(
                f"sensor {node}: {len(have)} jig points found with labels '{prefix}X1'..'{prefix}Z8' "
                "in registered patches; digitize the jig indentations (at least two rods) and register"
            )
        idx = np.array(have)
        xg = np.array([pts[prefix + jig.labels[i]] for i in have])
        fit = fit_orientation(jig.points_local_m[idx], xg, jig.rod[idx], method=method)
        body: dict[str, Any] = {
            "node": node,
            "rotation": np.asarray(fit.rotation).tolist(),
            "origin_m": _vec(fit.origin_m),
            "method": fit.method,
            "rods": list(fit.rods),
            "n_points": len(have),
            "residual_rms_m": float(fit.residual_rms_m),
            "angle_std_deg": _vec(fit.angle_std_deg),
            "uncertainty_deg": float(fit.uncertainty_deg),
        }
        if fit.affine is not None:
            body["orthogonality"] = np.asarray(fit.affine.orthogonality).tolist()
            body["max_off_diagonal"] = float(fit.affine.max_off_diagonal)
        with self.db.session() as s:
            s.merge(m.OrientationRow(node=node, body=body))
        return body

    def orientations(self) -> list[dict[str, Any]]:
        with self.db.session() as s:
            return [
                r.body for r in s.scalars(select(m.OrientationRow).order_by(m.OrientationRow.node))
            ]

    def fit_line_of_action(
        self, node: int, input_label: str, labels: Sequence[str], method: str = "svd"
    ) -> dict[str, Any]:
        """Line of action of input ``node``: points along it and the input point, all digitized."""
        from dimacq.pipeline.digitizing.lines_of_action import (
            line_of_action_svd,
            line_of_action_thesis,
        )

        if method not in ("svd", "eq13"):
            raise SetupError(f"method {method!r}: use svd or eq13")
        pts = self.global_points()
        missing = [lab for lab in [input_label, *labels] if lab not in pts]
        if missing:
            raise SetupError(
                f"input {node}: points {missing} are not digitized in a registered patch; "
                "digitize and register them first"
            )
        if len(labels) < 2:
            raise SetupError(
                f"input {node}: labels: give at least 2 points along the line of action"
            )
        fn = line_of_action_svd if method == "svd" else line_of_action_thesis
        loa = fn(np.array([pts[lab] for lab in labels]), pts[input_label])
        body = {
            "node": node,
            "direction": _vec(loa.direction),
            "point_m": _vec(pts[input_label]),
            "method": loa.method,
            "perpendicular_rms_m": float(loa.perpendicular_rms_m),
            "angle_std_deg": float(loa.angle_std_deg),
        }
        with self.db.session() as s:
            s.merge(m.LineOfActionRow(node=node, body=body))
        return body

    def lines_of_action(self) -> list[dict[str, Any]]:
        with self.db.session() as s:
            return [
                r.body
                for r in s.scalars(select(m.LineOfActionRow).order_by(m.LineOfActionRow.node))
            ]

    # ------------------------------------------------------------------ setups
    def save_setup(self, setup: TestSetup) -> int:
        from dimacq.io.setup_file import dump_setup_dict

        with self.db.session() as s:
            row = m.SetupRow(name=setup.name, body=dump_setup_dict(setup))
            s.add(row)
            s.flush()
            return int(row.id)

    def setup(self, setup_id: int) -> TestSetup | None:
        from dimacq.io.setup_file import parse_setup

        with self.db.session() as s:
            row = s.get(m.SetupRow, setup_id)
            return None if row is None else parse_setup(row.body, f"setup {setup_id}")

    def setups(self) -> list[dict[str, Any]]:
        with self.db.session() as s:
            return [
                _setup_summary(r) for r in s.scalars(select(m.SetupRow).order_by(m.SetupRow.id))
            ]

    def setup_summary(self, setup_id: int) -> dict[str, Any] | None:
        with self.db.session() as s:
            row = s.get(m.SetupRow, setup_id)
            return None if row is None else _setup_summary(row)

    def import_setup(self, data: bytes, fmt: str, name: str | None = None) -> dict[str, Any]:
        """Import a setup file (``json``/``toml``) or a whole-test UFF (``uff``: setup + FRFs)."""
        from dimacq.io.setup_file import parse_setup
        from dimacq.io.uff import read_uff_test

        if fmt == "json":
            try:
                doc = json.loads(data.decode("utf-8"))
            except (UnicodeDecodeError, json.JSONDecodeError) as err:
                raise DataError(
                    f"setup JSON is not valid JSON ({err}); send a JSON object"
                ) from err
            if not isinstance(doc, dict):
                raise DataError("setup JSON must be an object with responses and excitations")
            setup = parse_setup(doc, "uploaded setup")
        elif fmt == "toml":
            import tomllib

            try:
                doc = tomllib.loads(data.decode("utf-8"))
            except (UnicodeDecodeError, tomllib.TOMLDecodeError) as err:
                raise DataError(f"setup TOML is not valid TOML ({err})") from err
            setup = parse_setup(doc, "uploaded setup")
        elif fmt == "uff":
            with tempfile.TemporaryDirectory() as tmp:
                path = Path(tmp) / "upload.uff"
                path.write_bytes(data)
                try:
                    setup, frf = read_uff_test(path, name=name)
                except DimacqError:
                    raise
                except Exception as err:  # pyuff raises bare exceptions on malformed files
                    raise DataError(
                        f"UFF upload could not be read ({type(err).__name__}: {err})"
                    ) from err
            sid = self.save_setup(setup)
            fid = self.save_frf(frf, sid, name=name or setup.name)
            return {"setup_id": sid, "frf_id": fid}
        else:
            raise SetupError(f"format {fmt!r}: use json, toml or uff")
        if name:
            setup = setup.model_copy(update={"name": name})
        return {"setup_id": self.save_setup(setup), "frf_id": None}

    def export_setup(self, setup_id: int, fmt: str) -> tuple[bytes, str] | None:
        """Setup as ``json`` or ``toml`` text; None if it does not exist."""
        from dimacq.io.setup_file import dump_setup_dict

        setup = self.setup(setup_id)
        if setup is None:
            return None
        if fmt == "json":
            return json.dumps(dump_setup_dict(setup), indent=2).encode(), "application/json"
        if fmt == "toml":
            import tomli_w

            return tomli_w.dumps(dump_setup_dict(setup, toml=True)).encode(), "application/toml"
        raise SetupError(f"format {fmt!r}: use json or toml (UFF: export an FRF set)")

    def setup_from_geometry(
        self,
        *,
        name: str = "",
        reference_point_m: Sequence[float] = (0.0, 0.0, 0.0),
        length_unit: str = "m",
        triaxes: Sequence[int] | None = None,
        inputs: Sequence[int] | None = None,
        load_cells: Sequence[LoadCell] = (),
        known: Mapping[str, Any] | None = None,
    ) -> int:
        """A test setup from the oriented triaxes and the lines of action; returns its id.

        Each triax at node N gives channels N+X, N+Y, N+Z along the columns of its orientation
        matrix, at its jig origin; each input node gives one excitation at its input point along
        its line of action.
        """
        ori = {o["node"]: o for o in self.orientations()}
        loas = {a["node"]: a for a in self.lines_of_action()}
        nodes = list(ori) if triaxes is None else list(triaxes)
        ins = list(loas) if inputs is None else list(inputs)
        missing = [n for n in nodes if n not in ori] + [n for n in ins if n not in loas]
        if missing:
            raise SetupError(
                f"nodes {missing} have no orientation / line of action yet; fit them first"
            )
        responses = []
        for n in nodes:
            c = np.asarray(ori[n]["rotation"], float)
            for k in range(3):
                responses.append(
                    ResponseChannel(
                        node=n,
                        direction=k + 1,
                        position_m=tuple(ori[n]["origin_m"]),
                        direction_gcs=tuple(c[:, k] / np.linalg.norm(c[:, k])),
                    )
                )
        excitations = [
            Excitation(
                node=n,
                direction=1,
                position_m=tuple(loas[n]["point_m"]),
                direction_gcs=tuple(
                    np.asarray(loas[n]["direction"]) / np.linalg.norm(loas[n]["direction"])
                ),
            )
            for n in ins
        ]
        try:
            setup = TestSetup(
                name=name,
                reference_point_m=tuple(reference_point_m),  # type: ignore[arg-type]
                length_unit=length_unit,  # type: ignore[arg-type]
                responses=tuple(responses),
                excitations=tuple(excitations),
                load_cells=tuple(load_cells),
                known=known or {},  # type: ignore[arg-type]
            )
        except ValueError as err:
            raise SetupError(f"setup from geometry: {err}") from err
        return self.save_setup(setup)

    # ------------------------------------------------------------------ FRFs
    def save_frf(
        self, frf: FrfData, setup_id: int, *, name: str = "", acquisition_id: int | None = None
    ) -> int:
        """Store FRFs (HDF5 file, then the row referencing it)."""
        arrays, attrs = frf_to_arrays(frf)
        with self.db.session() as s:
            if s.get(m.SetupRow, setup_id) is None:
                raise SetupError(
                    f"setup_id {setup_id} does not exist; create or import the setup first"
                )
        rel = f"frfs/frf-{time.time_ns()}.h5"
        self.arrays.write(rel, arrays, attrs)
        with self.db.session() as s:
            row = m.FrfSet(
                setup_id=setup_id,
                acquisition_id=acquisition_id,
                name=name,
                path=rel,
                n_lines=frf.n_lines,
                n_outputs=int(frf.H.shape[1]),
                n_inputs=int(frf.H.shape[2]),
                f_min_hz=float(frf.frequencies_hz[0]),
                f_max_hz=float(frf.frequencies_hz[-1]),
            )
            s.add(row)
            s.flush()
            return int(row.id)

    def frf_summary(self, frf_id: int) -> dict[str, Any] | None:
        with self.db.session() as s:
            row = s.get(m.FrfSet, frf_id)
            return None if row is None else _frf_summary(row)

    def frfs(self) -> list[dict[str, Any]]:
        with self.db.session() as s:
            return [_frf_summary(r) for r in s.scalars(select(m.FrfSet).order_by(m.FrfSet.id))]

    def frf(self, frf_id: int) -> tuple[FrfData, TestSetup] | None:
        with self.db.session() as s:
            row = s.get(m.FrfSet, frf_id)
            if row is None:
                return None
            rel, setup_id = row.path, row.setup_id
        arrays, attrs = self.arrays.read(rel)
        setup = self.setup(setup_id)
        if setup is None:
            raise DataError(f"FRF set {frf_id}: its setup {setup_id} is missing from the database")
        return frf_from_arrays(arrays, attrs), setup

    def import_frf(self, data: bytes, setup_id: int, name: str = "") -> int:
        """FRFs from a UFF file (58 records) matched to an existing setup."""
        from dimacq.io.uff import read_frf_uff

        setup = self.setup(setup_id)
        if setup is None:
            raise SetupError(
                f"setup_id {setup_id} does not exist; create or import the setup first"
            )
        with tempfile.TemporaryDirectory() as tmp:
            path = Path(tmp) / "upload.uff"
            path.write_bytes(data)
            try:
                frf = read_frf_uff(path, setup)
            except DimacqError:
                raise
            except Exception as err:  # pyuff raises bare exceptions on malformed files
                raise DataError(
                    f"UFF upload could not be read ({type(err).__name__}: {err})"
                ) from err
        return self.save_frf(frf, setup_id, name=name)

    def export_frf_uff(self, frf_id: int, whole_test: bool = True) -> bytes | None:
        from dimacq.io.uff import write_frf_uff, write_uff_test

        got = self.frf(frf_id)
        if got is None:
            return None
        frf, setup = got
        with tempfile.TemporaryDirectory() as tmp:
            path = Path(tmp) / "out.uff"
            if whole_test:
                write_uff_test(path, setup, frf)
            else:
                write_frf_uff(path, frf)
            return path.read_bytes()

    def frf_data(
        self, frf_id: int, output: int | None = None, input_: int | None = None
    ) -> dict[str, Any] | None:
        """FRF values (real/imag) of one output/input pair or all of them."""
        got = self.frf(frf_id)
        if got is None:
            return None
        frf, _ = got
        n_out, n_in = frf.H.shape[1:]
        oi = list(range(n_out)) if output is None else [output]
        ii = list(range(n_in)) if input_ is None else [input_]
        for k, n, what in ((output, n_out, "output"), (input_, n_in, "input")):
            if k is not None and not 0 <= k < n:
                raise SetupError(f"{what} index {k} is outside 0..{n - 1}")
        h = frf.H[:, oi][:, :, ii]
        return {
            "frequencies_hz": _vec(frf.frequencies_hz),
            "outputs": [frf.outputs[i].as_dict() for i in oi],
            "inputs": [frf.inputs[j].as_dict() for j in ii],
            "real": h.real.tolist(),
            "imag": h.imag.tolist(),
            "coherence": None if frf.coherence is None else frf.coherence[:, oi][:, :, ii].tolist(),
        }

    # ------------------------------------------------------------------ solutions
    def solve(self, frf_id: int, options: Mapping[str, Any]) -> dict[str, Any] | None:
        """DIM solution of an FRF set; stored and returned with its id.

        ``options``: ``band_hz`` [lo, hi] (overrides the automatic band), ``known`` (parameter →
        value), ``length_unit``, ``method`` (joint/mean), and the analysis service's switches
        (``select_responses``, ``select_inputs``, ``auto_band``, ``geometry_uncertainty``: default
        on; ``repair_orientation``). The result carries ``verdict`` (ok/warn/fail) and
        ``verdict_reasons``; a ``fail`` is stored and returned like any other (HTTP 201), its
        reasons say why it must not be used.
        """

        got = self.frf(frf_id)
        if got is None:
            return None
        frf, setup = got
        band = tuple(options["band_hz"]) if options.get("band_hz") else None
        if band is not None and not (band[0] < band[1]):
            raise SetupError(f"band_hz {list(band)}: give [low, high] with low < high, in Hz")
        known = setup.known.as_dict()
        known.update({k: float(v) for k, v in (options.get("known") or {}).items()})
        from dimacq.services.analysis import AnalysisOptions, analyse

        opts = AnalysisOptions(
            select_responses=bool(options.get("select_responses", True)),
            select_inputs=bool(options.get("select_inputs", True)),
            repair_orientation=bool(options.get("repair_orientation")),
            auto_band=bool(options.get("auto_band", True)),
            band_hz=band,
            known=known,
            length_unit=options.get("length_unit"),
            method=options.get("method") or "joint",
            geometry_samples=400 if options.get("geometry_uncertainty", True) else 0,
        )
        result = analyse(frf, setup, opts).to_json()
        result = _json_safe(result)
        with self.db.session() as s:
            row = m.Solution(frf_id=frf_id, options=_json_safe(dict(options)), result=result)
            s.add(row)
            s.flush()
            sid = int(row.id)
        return {"id": sid, "frf_id": frf_id, "options": dict(options), "result": result}

    def solution(self, solution_id: int) -> dict[str, Any] | None:
        with self.db.session() as s:
            row = s.get(m.Solution, solution_id)
            if row is None:
                return None
            return {
                "id": row.id,
                "frf_id": row.frf_id,
                "options": row.options,
                "result": row.result,
            }

    def solutions(self) -> list[dict[str, Any]]:
        with self.db.session() as s:
            return [
                {"id": r.id, "frf_id": r.frf_id, "options": r.options, "result": r.result}
                for r in s.scalars(select(m.Solution).order_by(m.Solution.id))
            ]

    def solution_figure(self, solution_id: int, fmt: str = "png") -> bytes | None:
        """Parameters against frequency with the band (thesis Fig. 25) as PNG or SVG."""
        if fmt not in ("png", "svg"):
            raise SetupError(f"format {fmt!r}: use png or svg")
        sol = self.solution(solution_id)
        if sol is None:
            return None
        from dimacq.pipeline import dim

        got = self.frf(sol["frf_id"])
        if got is None:
            raise DataError(f"solution {solution_id}: its FRF set {sol['frf_id']} is missing")
        frf, setup = got
        opts = sol["options"]
        full = dim.solve(
            frf, setup, known=sol["result"].get("known"), length_unit=opts.get("length_unit")
        )
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        names = ("m", "cx", "cy", "cz", "Ixx", "Iyy", "Izz")
        cols = (0, 1, 2, 3, 4, 7, 9)
        fig, axes = plt.subplots(len(names), 1, figsize=(7, 12), sharex=True)
        lo, hi = sol["result"]["band_hz"]
        for ax, nm, c in zip(axes, names, cols, strict=True):
            ax.plot(full.frequencies_hz, full.per_line[:, c], lw=0.8)
            ax.axvspan(lo, hi, alpha=0.15)
            ax.set_ylabel(nm)
        axes[-1].set_xlabel("frequency, Hz")
        buf = io.BytesIO()
        fig.savefig(buf, format=fmt)
        plt.close(fig)
        return buf.getvalue()

    # ------------------------------------------------------------------ acquisitions
    def start_acquisition(self, config: Mapping[str, Any]) -> dict[str, Any]:
        """Configure and start an impact acquisition as a job; returns the acquisition.

        Every completed average (accepted or rejected) is written to its own HDF5 file and
        committed to the database before the next strike, so a crash loses none of them. When all
        inputs have their averages the FRFs are estimated and stored as an FRF set.
        """
        cfg = dict(config)
        setup_id = int(cfg["setup_id"])
        setup = self.setup(setup_id)
        if setup is None:
            raise SetupError(
                f"setup_id {setup_id} does not exist; create or import the setup first"
            )
        if self.jobs.running("acquisition"):
            raise DeviceStateError("an acquisition is already running; stop it or wait for it")
        rig = self._build_rig(setup, cfg)  # raises DeviceError if the devices are not there
        with self.db.session() as s:
            row = m.Acquisition(setup_id=setup_id, config=_json_safe(cfg), state="running")
            s.add(row)
            s.flush()
            acq_id = int(row.id)
        try:
            job = self.jobs.submit(
                "acquisition", lambda ctx: self._run_acquisition(ctx, acq_id, setup, cfg, rig)
            )
        except DimacqError:
            rig.close()
            with self.db.session() as s:
                r = s.get(m.Acquisition, acq_id)
                assert r is not None
                r.state = "failed"
            raise
        with self.db.session() as s:
            r = s.get(m.Acquisition, acq_id)
            assert r is not None
            r.job_id = job.id
        out = self.acquisition(acq_id)
        assert out is not None
        return out

    def _build_rig(self, setup: TestSetup, cfg: Mapping[str, Any]) -> Any:
        from dimacq.services import lab_rig

        if self._rig_factory is not None:
            return self._rig_factory(self.settings, setup, cfg)
        for name in ("daq", "loadcell"):
            info = self.devices[name]
            if not info.connected:
                raise DeviceNotFoundError(
                    f"{name} is not connected ({info.error or 'closed'}); connect it first"
                )
        return lab_rig.build_rig(self.settings, setup, cfg)

    def _run_acquisition(
        self, ctx: JobContext, acq_id: int, setup: TestSetup, cfg: Mapping[str, Any], rig: Any
    ) -> dict[str, Any]:
        from dimacq.services import lab_rig

        counter = {"n": 0}

        def on_average(
            input_index: int,
            accepted: bool,
            reasons: Sequence[str],
            record: Mapping[str, NDArray[Any]],
        ) -> None:
            counter["n"] += 1
            rel = f"acquisitions/{acq_id:06d}/avg-{counter['n']:05d}.h5"
            attrs = {
                "acquisition_id": acq_id,
                "input_index": input_index,
                "number": counter["n"],
                "accepted": accepted,
                "reason": "; ".join(reasons),
            }
            self.arrays.write(rel, record, attrs)
            with self.db.session() as s:
                s.add(
                    m.Average(
                        acquisition_id=acq_id,
                        input_index=input_index,
                        number=counter["n"],
                        accepted=accepted,
                        reason="; ".join(reasons),
                        path=rel,
                    )
                )

        def on_progress(fraction: float, message: str) -> None:
            ctx.progress(fraction, message)
            ctx.check_cancelled()  # raising here stops the session; its finally stops the devices

        state, message = "failed", ""
        try:
            frf = lab_rig.run_impact_test(
                rig, setup, cfg, on_average=on_average, on_progress=on_progress
            )
            fid = self.save_frf(
                frf, self._setup_id_of(acq_id), name=f"acquisition {acq_id}", acquisition_id=acq_id
            )
            state, message = "finished", f"FRFs stored as FRF set {fid}"
            with self.db.session() as s:
                r = s.get(m.Acquisition, acq_id)
                assert r is not None
                r.frf_id = fid
            return {"acquisition_id": acq_id, "frf_id": fid}
        except DimacqError as err:
            state = "cancelled" if ctx.cancelled else "failed"
            message = str(err)
            raise
        finally:
            rig.close()
            with self.db.session() as s:
                r = s.get(m.Acquisition, acq_id)
                assert r is not None
                r.state, r.message = state, message

    def _setup_id_of(self, acq_id: int) -> int:
        with self.db.session() as s:
            r = s.get(m.Acquisition, acq_id)
            assert r is not None and r.setup_id is not None
            return int(r.setup_id)

    def acquisitions(self) -> list[dict[str, Any]]:
        with self.db.session() as s:
            ids = list(s.scalars(select(m.Acquisition.id).order_by(m.Acquisition.id)))
        return [a for a in (self.acquisition(i) for i in ids) if a is not None]

    def acquisition(self, acq_id: int) -> dict[str, Any] | None:
        """State, progress and every completed average of an acquisition."""
        with self.db.session() as s:
            r = s.get(m.Acquisition, acq_id)
            if r is None:
                return None
            avgs = list(
                s.scalars(
                    select(m.Average)
                    .where(m.Average.acquisition_id == acq_id)
                    .order_by(m.Average.number)
                )
            )
            out: dict[str, Any] = {
                "id": r.id,
                "setup_id": r.setup_id,
                "config": r.config,
                "state": r.state,
                "message": r.message,
                "job_id": r.job_id,
                "frf_id": r.frf_id,
                "averages_accepted": sum(1 for a in avgs if a.accepted),
                "averages_rejected": sum(1 for a in avgs if not a.accepted),
                "averages": [
                    {
                        "number": a.number,
                        "input_index": a.input_index,
                        "accepted": a.accepted,
                        "reason": a.reason,
                        "path": a.path,
                    }
                    for a in avgs
                ],
            }
        snap = self.jobs.snapshot(out["job_id"]) if out["job_id"] else None
        out["progress"] = snap["progress"] if snap else (1.0 if out["state"] == "finished" else 0.0)
        return out

    def stop_acquisition(self, acq_id: int) -> dict[str, Any] | None:
        """Cancel a running acquisition (completed averages are kept)."""
        cur = self.acquisition(acq_id)
        if cur is None:
            return None
        if cur["job_id"] and cur["state"] == "running":
            self.jobs.cancel(cur["job_id"])
        return self.acquisition(acq_id)

    # ------------------------------------------------------------------ calibrations
    def save_calibration(self, body: Mapping[str, Any]) -> dict[str, Any]:
        from dimacq.io.loadcell_calibration import read_calibration_json, write_calibration_json

        with tempfile.TemporaryDirectory() as tmp:
            p = Path(tmp) / "cal.json"
            p.write_text(json.dumps(dict(body)))
            cal = read_calibration_json(p)  # validates
            write_calibration_json(cal, p)
            doc = json.loads(p.read_text())
        with self.db.session() as s:
            row = m.Calibration(serial=cal.serial_number, body=doc)
            s.add(row)
            s.flush()
            return {"id": int(row.id), "serial_number": cal.serial_number, "calibration": doc}

    def calibrations(self) -> list[dict[str, Any]]:
        with self.db.session() as s:
            return [
                {"id": r.id, "serial_number": r.serial, "calibration": r.body}
                for r in s.scalars(select(m.Calibration).order_by(m.Calibration.id))
            ]

    def calibration(self, cal_id: int) -> dict[str, Any] | None:
        with self.db.session() as s:
            r = s.get(m.Calibration, cal_id)
            return (
                None
                if r is None
                else {"id": r.id, "serial_number": r.serial, "calibration": r.body}
            )

    # ------------------------------------------------------------------ sensitivity
    def start_sensitivity(self, params: Mapping[str, Any]) -> dict[str, Any]:
        """A sensitivity study (thesis cube model) as a job; returns the study and job ids."""
        mod = _optional_module("dimacq.pipeline.sensitivity")
        if mod is None or not hasattr(mod, "cube_study"):
            raise DeviceStateError(
                "the sensitivity study (dimacq.pipeline.sensitivity.cube_study) is not installed in "
                "this build"
            )
        with self.db.session() as s:
            row = m.SensitivityStudy(params=dict(params))
            s.add(row)
            s.flush()
            sid = int(row.id)

        def work(ctx: JobContext) -> dict[str, Any]:
            ctx.progress(0.0, "running Monte Carlo trials")
            res = mod.cube_study(
                float(params["half_size_m"]),
                n_sensors=int(params.get("sensors", 1)),
                max_angle_deg=float(params["max_angle_deg"]),
                n_trials=int(params.get("trials", 500)),
                seed=params.get("seed"),
            )
            out = _json_safe(res.to_json() if hasattr(res, "to_json") else dict(res))
            with self.db.session() as s2:
                r = s2.get(m.SensitivityStudy, sid)
                assert r is not None
                r.result = out
            return {"study_id": sid}

        job = self.jobs.submit("sensitivity", work)
        return {"id": sid, "job_id": job.id}

    def sensitivity(self, study_id: int) -> dict[str, Any] | None:
        with self.db.session() as s:
            r = s.get(m.SensitivityStudy, study_id)
            return None if r is None else {"id": r.id, "params": r.params, "result": r.result}


# ---------------------------------------------------------------------------------- helpers
def _version() -> str:
    try:
        from importlib.metadata import version

        return version("dimacq")
    except Exception:
        return "unknown"


def _optional_module(name: str) -> Any:
    try:
        return importlib.import_module(name)
    except ImportError:
        return None


def _virtual_lab_module() -> Any:
    return _optional_module("dimacq.simulators.lab.scenarios")


def _identity_dict(ident: Any) -> dict[str, Any]:
    if hasattr(ident, "__dataclass_fields__"):
        from dataclasses import asdict

        return {k: v for k, v in asdict(ident).items()}
    return {"identity": str(ident)}


def _point_dict(r: m.DigitizedPointRow) -> dict[str, Any]:
    return {
        "id": r.id,
        "label": r.label,
        "patch": r.patch,
        "position_array_m": list(r.position_array_m),
        "spread_m": list(r.spread_m),
        "n_shots": r.n_shots,
        "n_used": r.n_used,
    }


def _apply_reg(reg: Mapping[str, Any], pos: Sequence[float]) -> list[float]:
    a = np.asarray(reg["matrix"], float)
    return _vec(a @ np.asarray(pos, float) + np.asarray(reg["offset_m"], float))


def _setup_summary(r: m.SetupRow) -> dict[str, Any]:
    return {
        "id": r.id,
        "name": r.name,
        "n_responses": len(r.body.get("responses", [])),
        "n_excitations": len(r.body.get("excitations", [])),
        "n_load_cells": len(r.body.get("load_cells", [])),
        "setup": r.body,
    }


def _frf_summary(r: m.FrfSet) -> dict[str, Any]:
    return {
        "id": r.id,
        "setup_id": r.setup_id,
        "acquisition_id": r.acquisition_id,
        "name": r.name,
        "n_lines": r.n_lines,
        "n_outputs": r.n_outputs,
        "n_inputs": r.n_inputs,
        "f_min_hz": r.f_min_hz,
        "f_max_hz": r.f_max_hz,
    }


def _json_safe(obj: Any) -> Any:
    """NaN/inf → None and numpy → Python, so the JSON is strict."""
    if isinstance(obj, dict):
        return {str(k): _json_safe(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_json_safe(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return _json_safe(obj.tolist())
    if isinstance(obj, np.generic):
        return _json_safe(obj.item())
    if isinstance(obj, float) and not np.isfinite(obj):
        return None
    if isinstance(obj, Path):
        return str(obj)
    return obj


# DeviceError is re-exported for the API's error mapping documentation.
_ = DeviceError
