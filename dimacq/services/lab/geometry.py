"""Geometry: digitized points, patches, reference nodes, registration, triax orientations and
lines of action, and a test setup built from them.

Every accepted point is committed to the database as soon as the digitizing session accepts it
(:meth:`GeometryService.journal_point`); registrations, orientations and lines of action are
stored when fitted. The database is the one copy of them: the digitizing session holds only the
points and patches of the open digitizer.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass
from typing import TYPE_CHECKING, Any, Literal

import numpy as np
from numpy.typing import NDArray
from sqlalchemy import select

from dimacq.errors import DeviceStateError, SetupError
from dimacq.model.setup import Excitation, KnownProperties, LoadCell, ResponseChannel, TestSetup
from dimacq.persistence import Database
from dimacq.persistence import models as m
from dimacq.services.lab.common import vec

if TYPE_CHECKING:
    from dimacq.drivers.digitizer import SerialDigitizer
    from dimacq.services.digitizing import DigitizedPoint, DigitizingSession
    from dimacq.services.lab.devices import DeviceService

__all__ = [
    "GeometryService",
    "LineOfAction",
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


# ---------------------------------------------------------------------------------- results
@dataclass(frozen=True)
class Shot:
    """One raw shot: its sequence number, triangulated tip (array coordinates) and verdict."""

    seq: int
    tip_array_m: list[float]
    speed_of_sound_m_s: float
    accepted: bool


@dataclass(frozen=True)
class Shots:
    """Raw shots and the median speed of sound measured on the calibration bar."""

    shots: list[Shot]
    speed_of_sound_m_s: float

    def to_json(self) -> dict[str, Any]:
        return asdict(self)


@dataclass(frozen=True)
class StoredPoint:
    """A digitized point as stored; ``position_m`` (GCS) once its patch is registered."""

    id: int
    label: str
    patch: int
    position_array_m: list[float]
    spread_m: list[float]
    n_shots: int
    n_used: int
    position_m: list[float] | None


@dataclass(frozen=True)
class Registration:
    """``x_G = matrix · x_A + offset_m`` of one patch, with the fit's quality (stored JSON)."""

    matrix: list[list[float]]
    offset_m: list[float]
    method: str
    scale: float
    labels: list[str]
    residual_norm_m: list[float]
    rms_m: float
    planarity: float

    @classmethod
    def from_json(cls, body: Mapping[str, Any]) -> Registration:
        return cls(**body)

    def apply(self, position_array_m: Sequence[float]) -> list[float]:
        a = np.asarray(self.matrix, float)
        return vec(a @ np.asarray(position_array_m, float) + np.asarray(self.offset_m, float))


@dataclass(frozen=True)
class PatchInfo:
    """An array position and its registration (None until registered)."""

    index: int
    name: str
    registration: Registration | None

    def to_json(self) -> dict[str, Any]:
        return asdict(self)


@dataclass(frozen=True)
class RegisteredPatch:
    index: int
    registration: Registration

    def to_json(self) -> dict[str, Any]:
        return asdict(self)


@dataclass(frozen=True)
class ReferenceNode:
    """A node with known GCS coordinates (metres)."""

    label: str
    position_m: list[float]


@dataclass(frozen=True)
class Orientation:
    """Orientation of the triax at ``node``: ``rotation`` has the sensor axes as columns (GCS);
    ``orthogonality`` and ``max_off_diagonal`` only from the affine fit."""

    node: int
    rotation: list[list[float]]
    origin_m: list[float]
    method: str
    rods: list[int]
    n_points: int
    residual_rms_m: float
    angle_std_deg: list[float]
    uncertainty_deg: float
    orthogonality: list[list[float]] | None = None
    max_off_diagonal: float | None = None

    @classmethod
    def from_json(cls, body: Mapping[str, Any]) -> Orientation:
        return cls(**body)

    def to_json(self) -> dict[str, Any]:
        out = asdict(self)
        for k in ("orthogonality", "max_off_diagonal"):
            if out[k] is None:
                del out[k]
        return out


@dataclass(frozen=True)
class LineOfAction:
    """Line of action of the input at ``node``: unit ``direction`` through ``point_m`` (GCS)."""

    node: int
    direction: list[float]
    point_m: list[float]
    method: str
    perpendicular_rms_m: float
    angle_std_deg: float

    @classmethod
    def from_json(cls, body: Mapping[str, Any]) -> LineOfAction:
        return cls(**body)

    def to_json(self) -> dict[str, Any]:
        return asdict(self)


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
        from dimacq.services.digitizing import DigitizingSession, load_array_config

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

    def digitize(self, label: str, shots: int | None = None) -> DigitizedPoint:
        """Digitize one point of the current patch; it is committed before this returns."""
        with self.devices.lock:
            return self.devices.session().digitize(label, shots)

    def fire_shots(self, n: int) -> Shots:
        """Fire ``n`` raw shots and triangulate them (speed of sound, tip, accepted)."""
        from dimacq.pipeline.digitizing.triangulation import triangulate
        from dimacq.services.digitizing import records_to_arrays

        with self.devices.lock:
            sess = self.devices.session()
            driver = self.devices.digitizer()
            records = [driver.fire() for _ in range(n)]
        counts, bar, avg, status, seq = records_to_arrays(records)
        sol = triangulate(
            counts, bar, sess.geometry, averaging=avg, status=status, limits=sess.limits
        )
        shots = Shots(
            shots=[
                Shot(
                    seq=int(seq[i]),
                    tip_array_m=vec(sol.tip_m[i]),
                    speed_of_sound_m_s=float(sol.speed_m_s[i]),
                    accepted=bool(sol.accepted[i]),
                )
                for i in range(n)
            ],
            speed_of_sound_m_s=float(np.nanmedian(sol.speed_m_s)),
        )
        if np.isfinite(shots.speed_of_sound_m_s):
            self._speed_of_sound_m_s = shots.speed_of_sound_m_s
        return shots

    def measure_speed_of_sound(self, shots: int = 3) -> float:
        """Fire ``shots`` shots: the median speed of sound on the calibration bar, m/s."""
        return self.fire_shots(shots).speed_of_sound_m_s

    def last_speed_of_sound(self) -> float | None:
        """The speed of sound measured last (by any firing), m/s; None before the first."""
        return self._speed_of_sound_m_s

    def points(self) -> list[StoredPoint]:
        with self.db.session() as s:
            rows = list(s.scalars(select(m.DigitizedPointRow).order_by(m.DigitizedPointRow.id)))
            regs = self._registrations(s)
        out = []
        for r in rows:
            reg = regs.get(r.patch)
            out.append(
                StoredPoint(
                    id=r.id,
                    label=r.label,
                    patch=r.patch,
                    position_array_m=list(r.position_array_m),
                    spread_m=list(r.spread_m),
                    n_shots=r.n_shots,
                    n_used=r.n_used,
                    position_m=reg.apply(r.position_array_m) if reg else None,
                )
            )
        return out

    # ------------------------------------------------------------------ patches and registration
    def patches(self) -> list[PatchInfo]:
        with self.db.session() as s:
            return [
                PatchInfo(
                    p.index,
                    p.name,
                    None if not p.registration else Registration.from_json(p.registration),
                )
                for p in s.scalars(select(m.PatchRow).order_by(m.PatchRow.index))
            ]

    def new_patch(self, name: str | None = None) -> PatchInfo:
        """The array moved: later points belong to a new patch (register it again)."""
        with self.devices.lock:
            p = self.devices.session().new_patch(name)
        with self.db.session() as s:
            s.merge(m.PatchRow(index=p.index, name=p.name))
        return PatchInfo(p.index, p.name, None)

    def set_reference_nodes(self, nodes: Mapping[str, Sequence[float]]) -> list[ReferenceNode]:
        """Store reference nodes (label → three finite GCS coordinates in metres)."""
        with self.db.session() as s:
            for lab, pos in nodes.items():
                s.merge(m.ReferenceNode(label=lab, position_m=vec(pos)))
        return self.reference_nodes()

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
            return {(r.patch, r.label): list(r.position_array_m) for r in s.scalars(q)}

    @staticmethod
    def _registrations(s: Any) -> dict[int, Registration]:
        return {
            p.index: Registration.from_json(p.registration)
            for p in s.scalars(select(m.PatchRow))
            if p.registration
        }

    def register_patch(
        self,
        patch: int | None = None,
        method: Literal["rigid", "similarity", "affine"] = "rigid",
        labels: Sequence[str] | None = None,
    ) -> RegisteredPatch:
        """Register a patch (default: the last one) from the reference nodes it holds."""
        from dimacq.pipeline.digitizing.registration import register

        with self.db.session() as s:
            last = s.scalars(select(m.PatchRow.index).order_by(m.PatchRow.index.desc())).first()
            idx = int(last or 0) if patch is None else patch
            if s.get(m.PatchRow, idx) is None:
                raise SetupError(f"patch {idx} does not exist; list patches to find its index")
            refs = {r.label: r.position_m for r in s.scalars(select(m.ReferenceNode))}
        pts = {lab: p for (_, lab), p in self._latest_points(idx).items()}
        use = [lab for lab in (labels or sorted(refs)) if lab in refs and lab in pts]
        if len(use) < 3:
            raise SetupError(
                f"patch {idx}: {len(use)} reference node(s) digitized ({use}); digitize at least 4 "
                "reference nodes with known GCS coordinates in this patch (3 only for rigid frames)"
            )
        reg = register(
            np.array([pts[u] for u in use]), np.array([refs[u] for u in use]), method=method
        )
        result = Registration(
            matrix=np.asarray(reg.matrix).tolist(),
            offset_m=vec(reg.offset_m),
            method=reg.method,
            scale=float(reg.scale),
            labels=use,
            residual_norm_m=vec(reg.residual_norm_m),
            rms_m=float(reg.rms_m),
            planarity=float(reg.planarity),
        )
        with self.db.session() as s:
            row = s.get(m.PatchRow, idx)
            assert row is not None
            row.registration = asdict(result)
        return RegisteredPatch(idx, result)

    def global_points(self) -> dict[str, FloatArray]:
        """Label → GCS position (points of registered patches; the latest wins)."""
        with self.db.session() as s:
            regs = self._registrations(s)
        out: dict[str, FloatArray] = {}
        for (patch, label), pos in self._latest_points().items():
            reg = regs.get(patch)
            if reg:
                out[label] = np.asarray(reg.apply(pos))
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
        from dimacq.services.digitizing import load_jig

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
        result = Orientation(
            node=node,
            rotation=np.asarray(fit.rotation).tolist(),
            origin_m=vec(fit.origin_m),
            method=fit.method,
            rods=list(fit.rods),
            n_points=len(have),
            residual_rms_m=float(fit.residual_rms_m),
            angle_std_deg=vec(fit.angle_std_deg),
            uncertainty_deg=float(fit.uncertainty_deg),
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

        pts = self.global_points()
        missing = [lab for lab in [input_label, *labels] if lab not in pts]
        if missing:
            raise SetupError(
                f"input {node}: points {missing} are not digitized in a registered patch; "
                "digitize and register them first"
            )
        fn = line_of_action_svd if method == "svd" else line_of_action_thesis
        loa = fn(np.array([pts[lab] for lab in labels]), pts[input_label])
        result = LineOfAction(
            node=node,
            direction=vec(loa.direction),
            point_m=vec(pts[input_label]),
            method=loa.method,
            perpendicular_rms_m=float(loa.perpendicular_rms_m),
            angle_std_deg=float(loa.angle_std_deg),
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
        its line of action.
        """
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
                        position_m=_vec3(ori[n].origin_m),
                        direction_gcs=tuple(c[:, k] / np.linalg.norm(c[:, k])),
                    )
                )
        excitations = [
            Excitation(
                node=n,
                direction=1,
                position_m=_vec3(loas[n].point_m),
                direction_gcs=tuple(
                    np.asarray(loas[n].direction) / np.linalg.norm(loas[n].direction)
                ),
            )
            for n in ins
        ]
        try:
            return TestSetup(
                name=name,
                reference_point_m=tuple(reference_point_m),  # type: ignore[arg-type]
                length_unit=length_unit,
                responses=tuple(responses),
                excitations=tuple(excitations),
                load_cells=tuple(load_cells),
                known=known or KnownProperties(),
            )
        except ValueError as err:
            raise SetupError(f"setup from geometry: {err}") from err


def _vec3(v: Sequence[float]) -> tuple[float, float, float]:
    return (float(v[0]), float(v[1]), float(v[2]))
