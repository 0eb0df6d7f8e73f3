"""Geometry: digitized points, patches, reference nodes, registration, triax orientations and
lines of action, and a test setup built from them.

Every accepted point is committed to the database as soon as the digitizing session accepts it
(:meth:`GeometryService.journal_point`); registrations, orientations and lines of action are
stored when fitted. The database is the one copy of them: the digitizing session holds only the
points and patches of the open digitizer.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import asdict
from typing import TYPE_CHECKING, Any, Literal

import numpy as np
from numpy.typing import NDArray
from sqlalchemy import delete, func, insert, select

from dimacq.errors import DataError, DeviceStateError, SetupError
from dimacq.model.setup import Excitation, KnownProperties, LoadCell, ResponseChannel, TestSetup
from dimacq.persistence import Database
from dimacq.persistence import models as m
from dimacq.services.geometry.records import (
    LineOfAction,
    NewTest,
    Orientation,
    PatchInfo,
    ReferenceNode,
    RegisteredPatch,
    Registration,
    Shot,
    Shots,
    StoredPoint,
)
from dimacq.services.lab.common import vec
from dimacq.services.lab.records import Page

if TYPE_CHECKING:
    from dimacq.drivers.digitizer import SerialDigitizer
    from dimacq.io.measured_points import MeasuredPoints
    from dimacq.services.geometry.digitizing import DigitizedPoint, DigitizingSession
    from dimacq.services.lab.devices import DeviceService

from dimacq.services.lab.geometry_helpers import (
    delete_all,
    distinct,
    finite_or_none,
    registrations_of,
    stored_point,
    vec3,
)

__all__ = [
    "GeometryService",
    "LineOfAction",
    "NewTest",
    "Orientation",
    "PatchInfo",
    "ReferenceNode",
    "RegisteredPatch",
    "Registration",
    "Shot",
    "Shots",
    "StoredPoint",
]

FloatArray = NDArray[np.float64]


# ---------------------------------------------------------------------------------- service
class GeometryService:
    """Digitizing, registration, orientation and lines of action over the open digitizer.

    Parameters
    ----------
    db : Database
    devices : DeviceService
        Holds the digitizer driver, its session and the lock that serialises their use.
    """

    def __init__(self, db: Database, devices: DeviceService) -> None:
        self.db = db
        self.devices = devices
        self._speed_of_sound_m_s: float | None = None  # the last finite one measured

    # ------------------------------------------------------------------ the session
    def open_session(self, driver: SerialDigitizer) -> DigitizingSession:
        """A digitizing session on a freshly opened digitizer, with the stored patches."""
        from dimacq.services.geometry.digitizer_config import load_array_config
        from dimacq.services.geometry.digitizing import DigitizingSession

        cfg = load_array_config()
        session = DigitizingSession(
            driver, cfg.geometry(), cfg.limits(), shots_per_point=5, journal=self.journal_point
        )
        with self.db.session() as s:
            patches = list(s.scalars(select(m.PatchRow).order_by(m.PatchRow.index)))
            if not patches:
                s.add(m.PatchRow(index=0, name="patch 0"))
        for p in patches[1:]:
            session.new_patch(p.name)
        return session

    def journal_point(self, point: DigitizedPoint) -> None:
        """Commit an accepted point (the session calls this before it returns the point)."""
        with self.db.session() as s:
            s.add(
                m.DigitizedPointRow(
                    label=point.label,
                    patch=int(point.patch),
                    position_array_m=vec(point.position_array_m),
                    spread_m=vec(point.spread_m),
                    n_shots=int(point.n_shots),
                    n_used=int(point.n_used),
                    seqs=[int(q) for q in point.seqs],
                )
            )

    # ------------------------------------------------------------------ digitizing
    def place_simulated_probe(self, tip_m: Sequence[float], axis: Sequence[float]) -> None:
        """Simulation only: put the simulator's probe tip at ``tip_m`` (array coordinates) with
        its axis along ``axis`` (any non-zero length; validated at the API edge)."""
        with self.devices.lock:
            driver = self.devices.digitizer()
            info = self.devices.require("digitizer")
            if not str(info.identity.get("model", "")).endswith("SIM"):
                raise DeviceStateError(
                    f"digitizer {info.identity.get('model', '?')} is a real array: the probe is placed "
                    "by hand, sim_probe is only for the simulator"
                )
            a = np.asarray(axis, dtype=float)
            a = a / float(np.linalg.norm(a))
            vals = ",".join(f"{v:.6f}" for v in (*np.asarray(tip_m, dtype=float), *a))
            driver.command(f"SIM:PROBE {vals}")

    def digitize(self, label: str, shots: int | None = None) -> dict[str, Any]:
        """Digitize one point of the current patch; it is committed before this returns. The
        point as measured (with its shot numbers ``seqs``) and as stored (``id``,
        ``created_at``, ``position_m`` once its patch is registered)."""
        with self.devices.lock:
            point = self.devices.session().digitize(label, shots)
            with self.db.session() as s:
                last = s.scalars(
                    select(m.DigitizedPointRow)
                    .where(m.DigitizedPointRow.label == label)
                    .order_by(m.DigitizedPointRow.id.desc())
                    .limit(1)
                ).first()
                # this point alone (not every stored point: a test digitizes hundreds)
                stored = None if last is None else stored_point(last, registrations_of(s))
        out = point.to_json()
        if stored is not None:
            out.update(asdict(stored))
        return out

    def fire_shots(self, n: int) -> Shots:
        """Fire ``n`` raw shots and triangulate them (speed of sound, tip, accepted)."""
        from dimacq.pipeline.digitizing.triangulation import triangulate
        from dimacq.services.geometry.digitizing import records_to_arrays

        with self.devices.lock:
            sess = self.devices.session()
            records = sess.fire(n)
        counts, bar, avg, status, seq = records_to_arrays(records)
        sol = triangulate(
            counts, bar, sess.geometry, averaging=avg, status=status, limits=sess.limits
        )
        shots = Shots(
            shots=[
                Shot(
                    seq=int(seq[i]),
                    tip_array_m=[finite_or_none(x) for x in vec(sol.tip_m[i])],
                    speed_of_sound_m_s=finite_or_none(sol.speed_m_s[i]),
                    accepted=bool(sol.accepted[i]),
                )
                for i in range(n)
            ],
            speed_of_sound_m_s=finite_or_none(
                np.nanmedian(sol.speed_m_s) if np.isfinite(sol.speed_m_s).any() else np.nan
            ),
        )
        if shots.speed_of_sound_m_s is not None:
            self._speed_of_sound_m_s = shots.speed_of_sound_m_s
        return shots

    def measure_speed_of_sound(self, shots: int = 3) -> float:
        """Fire ``shots`` shots: the median speed of sound on the calibration bar, m/s;
        DataError when no shot reached the bar."""
        got = self.fire_shots(shots).speed_of_sound_m_s
        if got is None:
            raise DataError(
                f"speed of sound: none of {shots} shots reached the calibration bar; check the "
                "bar's microphones and fire again"
            )
        return got

    def last_speed_of_sound(self) -> float | None:
        """The speed of sound measured last (by any firing), m/s; None before the first."""
        return self._speed_of_sound_m_s

    def points(self) -> list[StoredPoint]:
        with self.db.session() as s:
            rows = list(s.scalars(select(m.DigitizedPointRow).order_by(m.DigitizedPointRow.id)))
            regs = registrations_of(s)
        return [stored_point(r, regs) for r in rows]

    def points_page(self, limit: int | None, offset: int) -> Page[StoredPoint]:
        """One page of the points (id order), cut by the database, and their total count."""
        with self.db.session() as s:
            total = int(s.scalar(select(func.count()).select_from(m.DigitizedPointRow)) or 0)
            q = select(m.DigitizedPointRow).order_by(m.DigitizedPointRow.id).offset(offset)
            rows = list(s.scalars(q if limit is None else q.limit(limit)))
            regs = registrations_of(s)
        return Page([stored_point(r, regs) for r in rows], total)

    def delete_points(self, patch: int | None) -> int:
        """Delete every digitized point, or those of one patch (an import to do again); fits
        made from them are kept. Returns how many were deleted."""
        with self.db.session() as s:
            q = delete(m.DigitizedPointRow)
            if patch is not None:
                q = q.where(m.DigitizedPointRow.patch == patch)
            done = s.execute(q.execution_options(synchronize_session=False))
            return int(done.rowcount)  # type: ignore[attr-defined]

    def delete_point(self, point_id: int) -> bool | None:
        """Delete one digitized point (a mistaken one; fits made from it are kept). The label's
        earlier point, if any, is the latest again. None if there is no such point."""
        with self.db.session() as s:
            row = s.get(m.DigitizedPointRow, point_id)
            if row is None:
                return None
            s.delete(row)
            return True

    # ------------------------------------------------------------------ patches and registration
    def patches(self) -> list[PatchInfo]:
        with self.db.session() as s:
            return [
                PatchInfo(
                    p.index,
                    p.name,
                    None if not p.registration else Registration.from_json(p.registration),
                    p.test,
                )
                for p in s.scalars(select(m.PatchRow).order_by(m.PatchRow.index))
            ]

    def current_test(self) -> int:
        """The current digitizing test (the highest test number of the stored patches)."""
        with self.db.session() as s:
            t = s.scalars(select(m.PatchRow.test).order_by(m.PatchRow.test.desc())).first()
        return int(t or 0)

    def new_patch(self, name: str | None = None) -> PatchInfo:
        """The array moved: later points belong to a new patch (register it again)."""
        test = self.current_test()
        with self.devices.lock:
            p = self.devices.session().new_patch(name)
        with self.db.session() as s:
            s.merge(m.PatchRow(index=p.index, name=p.name, test=test))
        return PatchInfo(p.index, p.name, None, test)

    def import_points(self, points: MeasuredPoints, name: str | None = None) -> list[StoredPoint]:
        """Points measured by another instrument (:mod:`dimacq.io.measured_points`), in its own
        frame, as a new patch of the current test: registered, oriented and fitted into lines of
        action exactly as points the digitizer measured (one shot each; ``spread_m`` the file's
        sigma, else 0). The digitizer need not be connected."""
        name = name or f"imported {points.instrument or 'points'}"
        with self.devices.lock:
            live = self.devices.session_if_open()
            if live is not None:  # the session numbers its patches: it gets this one too
                index = live.new_patch(name).index
            else:
                with self.db.session() as s:
                    top = s.scalars(select(m.PatchRow.index).order_by(m.PatchRow.index.desc()))
                    index = int((top.first() or 0) + 1)
        test = self.current_test()
        with self.db.session() as s:
            s.merge(m.PatchRow(index=index, name=name, test=test))
            s.flush()
            new = [
                dict(label=p.label, patch=index, position_array_m=list(p.xyz_m), seqs=[],
                     spread_m=[p.sigma_m or 0.0] * 3, n_shots=1, n_used=1)
                for p in points.points
            ]  # fmt: skip
            s.execute(insert(m.DigitizedPointRow), new)  # one executemany, not a row at a time
        with self.db.session() as s:
            q = select(m.DigitizedPointRow).where(m.DigitizedPointRow.patch == index)
            rows = list(s.scalars(q.order_by(m.DigitizedPointRow.id)))
            regs = registrations_of(s)
        return [stored_point(r, regs) for r in rows]

    def import_photo_geometry(self, doc: Mapping[str, Any]) -> dict[str, Any]:
        """Store the orientations and lines of action of a photographed geometry (the JSON of
        :meth:`dimacq.services.geometry.photo_geometry.PhotoGeometry.to_json`) as the current test's
        records, replacing those of the same nodes. A result whose verdict is ``fail`` (a triax
        or input not fixed) is refused with its reasons."""
        if not isinstance(doc, Mapping) or doc.get("source") != "photographs":
            raise DataError(
                "photo geometry: not the JSON of dimacq geometry from-photos (source must be "
                "'photographs'); send GEOMETRY.json"
            )
        if doc.get("verdict") == "fail":
            raise DataError(
                "photo geometry: not every triax and input is fixed: "
                + "; ".join(str(u) for u in doc.get("unfixed", []))
            )
        try:
            ori = [Orientation.from_json(o) for o in doc.get("orientations", [])]
            loas = [LineOfAction.from_json(a) for a in doc.get("lines_of_action", [])]
        except TypeError as err:
            raise DataError(
                f"photo geometry: a record has wrong keys ({err}); send GEOMETRY.json"
            ) from err
        with self.db.session() as s:
            for o in ori:
                s.merge(m.OrientationRow(node=o.node, body=o.to_json()))
            for a in loas:
                s.merge(m.LineOfActionRow(node=a.node, body=a.to_json()))
        return {
            "orientations": len(ori),
            "lines_of_action": len(loas),
            "verdict": doc.get("verdict"),
        }

    def new_test(self, name: str | None = None) -> NewTest:
        """Start a new digitizing test: a fresh patch, no reference nodes, no orientations or
        lines of action. Earlier points and patches stay in the database (listed, never used
        for the new test's geometry); setups already built keep their geometry."""
        test = self.current_test() + 1
        with self.devices.lock:
            p = self.devices.session().new_patch(name or f"test {test} patch 0")
        with self.db.session() as s:
            s.merge(m.PatchRow(index=p.index, name=p.name, test=test))
            cleared = {
                "reference_nodes": delete_all(s, m.ReferenceNode),
                "orientations": delete_all(s, m.OrientationRow),
                "lines_of_action": delete_all(s, m.LineOfActionRow),
            }
        return NewTest(test, PatchInfo(p.index, p.name, None, test), cleared)

    def set_reference_nodes(self, nodes: Mapping[str, Sequence[float]]) -> list[ReferenceNode]:
        """Add or replace reference nodes (label → three finite GCS coordinates in metres)."""
        for lab, pos in nodes.items():
            if not lab or len(lab) > 200:
                raise SetupError("reference node label: give 1..200 characters")
            if len(pos) != 3 or not np.all(np.isfinite(pos)):
                raise SetupError(
                    f"reference node {lab!r}: give three finite GCS coordinates in metres"
                )
        with self.db.session() as s:
            for lab, pos in nodes.items():
                s.merge(m.ReferenceNode(label=lab, position_m=vec(pos)))
        return self.reference_nodes()

    def delete_reference_node(self, label: str) -> bool:
        """Remove a reference node (registrations already made are kept); False if unknown."""
        with self.db.session() as s:
            row = s.get(m.ReferenceNode, label)
            if row is None:
                return False
            s.delete(row)
        return True

    def reference_nodes(self) -> list[ReferenceNode]:
        with self.db.session() as s:
            return [
                ReferenceNode(r.label, list(r.position_m))
                for r in s.scalars(select(m.ReferenceNode).order_by(m.ReferenceNode.label))
            ]

    def _latest_points(self, patch: int | None = None) -> dict[tuple[int, str], list[float]]:
        with self.db.session() as s:
            q = select(m.DigitizedPointRow).order_by(m.DigitizedPointRow.id)
            if patch is not None:
                q = q.where(m.DigitizedPointRow.patch == patch)
            out: dict[tuple[int, str], list[float]] = {}
            for r in s.scalars(q):
                out.pop((r.patch, r.label), None)  # re-digitized: the latest, last in order
                out[(r.patch, r.label)] = list(r.position_array_m)
            return out

    def _registration_settings(self) -> tuple[float, float, float]:
        """(point accuracy, registration limit, prior σ of a node), m."""
        from dimacq.services.geometry.digitizer_config import load_array_config
        from dimacq.services.geometry.geometry_trust import registration_limit

        settings = self.devices.settings
        cfg = load_array_config()
        ref = settings.reference_node_accuracy_m
        limit = registration_limit(cfg, ref, settings.registration_limit_m)
        return cfg.accuracy.point_m, limit, float(np.hypot(cfg.accuracy.point_m, ref))

    def register_patch(
        self,
        patch: int | None = None,
        method: Literal["rigid", "similarity", "affine"] = "rigid",
        labels: Sequence[str] | None = None,
        limit_m: float | None = None,
    ) -> RegisteredPatch:
        """Register a patch (default: the last one) from the reference nodes it holds.

        A node residual above the limit (``limit_m``, default the ``registration_limit_m``
        setting) refuses it (DataError naming the worst node) and leaves the patch unregistered.
        A registration accepted against a limit raised above the array's is a ``warn``.
        """
        from dimacq.services.geometry.geometry_trust import judge_registration

        _point, default_limit, prior = self._registration_settings()
        limit = default_limit if limit_m is None else float(limit_m)
        test = self.current_test()
        with self.db.session() as s:
            last = s.scalars(select(m.PatchRow.index).order_by(m.PatchRow.index.desc())).first()
            idx = int(last or 0) if patch is None else patch
            prow = s.get(m.PatchRow, idx)
            if prow is None:
                raise SetupError(f"patch {idx} does not exist; list patches to find its index")
            if prow.test != test:
                raise SetupError(
                    f"patch {idx} belongs to test {prow.test}, not the current test {test}; "
                    "digitize the reference nodes again in a patch of this test"
                )
            refs = {r.label: r.position_m for r in s.scalars(select(m.ReferenceNode))}
        pts = {lab: p for (_, lab), p in self._latest_points(idx).items()}
        use = [lab for lab in (labels or sorted(refs)) if lab in refs and lab in pts]
        if len(use) < 3:
            raise SetupError(
                f"patch {idx}: {len(use)} reference node(s) digitized ({use}); digitize at least 4 "
                "reference nodes with known GCS coordinates in this patch (3 only for rigid frames)"
            )
        try:
            _reg, body = judge_registration(
                np.array([pts[u] for u in use]),
                np.array([refs[u] for u in use]),
                use,
                limit_m=limit,
                prior_sigma_m=prior,
                method=method,
            )
        except DataError:
            # the patch's points have changed since any earlier registration: unregister it
            with self.db.session() as s:
                row = s.get(m.PatchRow, idx)
                assert row is not None
                row.registration = None
            with self.devices.lock:
                sess = self.devices.session_if_open()
                if sess is not None and idx < len(sess.patches):
                    sess.patches[idx].registration = None
            raise
        if body["worst_residual_m"] > default_limit:
            body["verdict"] = "warn"
            body["reasons"].append(
                f"accepted against a raised limit {1e3 * limit:.2f} mm; the array's limit is "
                f"{1e3 * default_limit:.2f} mm (setups built on it state that limit, so a solve "
                "on them fails its registration check)"
            )
        result = Registration.from_json(body)
        with self.db.session() as s:
            row = s.get(m.PatchRow, idx)
            assert row is not None
            row.registration = result.to_json()
        return RegisteredPatch(idx, result)

    def global_points(self) -> dict[str, FloatArray]:
        """Label → GCS position (points of the current test's registered patches; the latest
        wins)."""
        return {k: v[0] for k, v in self._global_points_with_patch().items()}

    def _test_registrations(self) -> dict[int, Registration]:
        """Patch index → registration, the current test's registered patches only."""
        test = self.current_test()
        with self.db.session() as s:
            return {
                p.index: Registration.from_json(p.registration)
                for p in s.scalars(select(m.PatchRow).where(m.PatchRow.test == test))
                if p.registration
            }

    def _global_points_with_patch(self) -> dict[str, tuple[FloatArray, Registration]]:
        """Label → (GCS position, its patch's registration), current test only."""
        regs = self._test_registrations()
        out: dict[str, tuple[FloatArray, Registration]] = {}
        for (patch, label), pos in self._latest_points().items():
            reg = regs.get(patch)
            if reg:
                out.pop(label, None)
                out[label] = (np.asarray(reg.apply(pos)), reg)
        return out

    # ------------------------------------------------------------------ sensors and inputs
    def fit_orientation(
        self,
        node: int,
        prefix: str | None = None,
        method: Literal["rigid", "affine", "cross"] = "rigid",
    ) -> Orientation:
        """Orientation of the triax at ``node`` from jig points labelled ``<prefix><jig label>``."""
        from dimacq.pipeline.digitizing.orientation import fit_orientation
        from dimacq.services.geometry.digitizer_config import load_jig
        from dimacq.services.geometry.geometry_trust import orientation_uncertainty

        prefix = f"jig{node}/" if prefix is None else prefix
        jig = load_jig()
        with_patch = self._global_points_with_patch()
        pts = {k: v[0] for k, v in with_patch.items()}
        have = [i for i, lab in enumerate(jig.labels) if prefix + lab in pts]
        if len(have) < 4:
            raise SetupError(
                f"sensor {node}: {len(have)} jig points found with labels '{prefix}X1'..'{prefix}Z8' "
                "in registered patches; digitize the jig indentations (at least two rods) and register"
            )
        idx = np.array(have)
        xg = np.array([pts[prefix + jig.labels[i]] for i in have])
        fit = fit_orientation(jig.points_local_m[idx], xg, jig.rod[idx], method=method)
        point_m, _limit, _prior = self._registration_settings()
        unc = orientation_uncertainty(
            float(fit.uncertainty_deg),
            float(fit.residual_rms_m),
            len(have),
            fit.origin_m,
            distinct(with_patch[prefix + jig.labels[i]][1] for i in have),
            point_m,
        )
        result = Orientation(
            node=node,
            rotation=np.asarray(fit.rotation).tolist(),
            origin_m=vec(fit.origin_m),
            method=fit.method,
            rods=list(fit.rods),
            n_points=len(have),
            residual_rms_m=float(fit.residual_rms_m),
            angle_std_deg=vec(fit.angle_std_deg),
            uncertainty_deg=unc["uncertainty_deg"],
            jig_uncertainty_deg=unc["jig_uncertainty_deg"],
            registration_uncertainty_deg=unc["registration_uncertainty_deg"],
            origin_std_m=unc["origin_std_m"],
            orthogonality=None
            if fit.affine is None
            else np.asarray(fit.affine.orthogonality).tolist(),
            max_off_diagonal=None if fit.affine is None else float(fit.affine.max_off_diagonal),
        )
        with self.db.session() as s:
            s.merge(m.OrientationRow(node=node, body=result.to_json()))
        return result

    def orientations(self) -> list[Orientation]:
        with self.db.session() as s:
            return [
                Orientation.from_json(r.body)
                for r in s.scalars(select(m.OrientationRow).order_by(m.OrientationRow.node))
            ]

    def fit_line_of_action(
        self,
        node: int,
        input_label: str,
        labels: Sequence[str],
        method: Literal["svd", "eq13"] = "svd",
    ) -> LineOfAction:
        """Line of action of input ``node`` from digitized points along it (at least two) and
        the input point."""
        from dimacq.pipeline.digitizing.lines_of_action import (
            line_of_action_svd,
            line_of_action_thesis,
        )
        from dimacq.services.geometry.geometry_trust import line_of_action_uncertainty

        with_patch = self._global_points_with_patch()
        pts = {k: v[0] for k, v in with_patch.items()}
        missing = [lab for lab in [input_label, *labels] if lab not in pts]
        if missing:
            raise SetupError(
                f"input {node}: points {missing} are not digitized in a registered patch; "
                "digitize and register them first"
            )
        fn = line_of_action_svd if method == "svd" else line_of_action_thesis
        loa = fn(np.array([pts[lab] for lab in labels]), pts[input_label])
        point_m, _limit, _prior = self._registration_settings()
        unc = line_of_action_uncertainty(
            float(loa.angle_std_deg),
            pts[input_label],
            distinct(with_patch[lab][1] for lab in [input_label, *labels]),
            point_m,
        )
        result = LineOfAction(
            node=node,
            direction=vec(loa.direction),
            point_m=vec(pts[input_label]),
            method=loa.method,
            perpendicular_rms_m=float(loa.perpendicular_rms_m),
            angle_std_deg=unc["angle_std_deg"],
            fit_angle_std_deg=unc["fit_angle_std_deg"],
            registration_uncertainty_deg=unc["registration_uncertainty_deg"],
            point_std_m=unc["point_std_m"],
        )
        with self.db.session() as s:
            s.merge(m.LineOfActionRow(node=node, body=result.to_json()))
        return result

    def lines_of_action(self) -> list[LineOfAction]:
        with self.db.session() as s:
            return [
                LineOfAction.from_json(r.body)
                for r in s.scalars(select(m.LineOfActionRow).order_by(m.LineOfActionRow.node))
            ]

    # ------------------------------------------------------------------ the setup
    def setup_from_geometry(
        self,
        *,
        name: str = "",
        reference_point_m: Sequence[float] = (0.0, 0.0, 0.0),
        length_unit: Literal["m", "cm", "mm"] = "m",
        triaxes: Sequence[int] | None = None,
        inputs: Sequence[int] | None = None,
        load_cells: Sequence[LoadCell] = (),
        known: KnownProperties | None = None,
    ) -> TestSetup:
        """A test setup from the oriented triaxes and the lines of action (not stored).

        Each triax at node N gives channels N+X, N+Y, N+Z along the columns of its orientation
        matrix, at its jig origin; each input node gives one excitation at its input point along
        its line of action. The setup states the geometry's uncertainty
        (:func:`dimacq.services.geometry.geometry_trust.geometry_uncertainty`: the orientations', lines of
        action's and the current test's registrations' stated 1σ, and the array's registration
        limit).
        """
        from dimacq.services.geometry.geometry_trust import geometry_uncertainty

        ori = {o.node: o for o in self.orientations()}
        loas = {a.node: a for a in self.lines_of_action()}
        nodes = list(ori) if triaxes is None else list(triaxes)
        ins = list(loas) if inputs is None else list(inputs)
        missing = [n for n in nodes if n not in ori] + [n for n in ins if n not in loas]
        if missing:
            raise SetupError(
                f"nodes {missing} have no orientation / line of action yet; fit them first"
            )
        responses = []
        for n in nodes:
            c = np.asarray(ori[n].rotation, float)
            for k in range(3):
                responses.append(
                    ResponseChannel(
                        node=n,
                        direction=k + 1,
                        position_m=vec3(ori[n].origin_m),
                        direction_gcs=tuple(c[:, k] / np.linalg.norm(c[:, k])),
                    )
                )
        excitations = [
            Excitation(
                node=n,
                direction=1,
                position_m=vec3(loas[n].point_m),
                direction_gcs=tuple(
                    np.asarray(loas[n].direction) / np.linalg.norm(loas[n].direction)
                ),
            )
            for n in ins
        ]
        point_m, limit, _prior = self._registration_settings()
        geo_unc = geometry_uncertainty(
            [ori[n].to_json() for n in nodes],
            [loas[n].to_json() for n in ins],
            [r.to_json() for r in self._test_registrations().values()],
            point_accuracy_m=point_m,
            # the array's limit, not a limit raised for one registration
            registration_limit_m=limit,
        )
        try:
            return TestSetup(
                name=name,
                reference_point_m=tuple(reference_point_m),  # type: ignore[arg-type]
                length_unit=length_unit,
                responses=tuple(responses),
                excitations=tuple(excitations),
                load_cells=tuple(load_cells),
                known=known or KnownProperties(),
                geometry_uncertainty=geo_unc,
            )
        except ValueError as err:
            raise SetupError(f"setup from geometry: {err}") from err
