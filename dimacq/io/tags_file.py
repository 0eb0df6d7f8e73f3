"""Tags files: which fiducial tag sits where, for geometry from photographs.

A tags file (TOML, ``schema_version = 1``) states the tag family, how well a tag is placed on
its body, named tag layouts (a triax block's, an impact jig's) and the bodies::

    schema_version = 1
    family = "DICT_APRILTAG_36h11"   # cv2.aruco predefined dictionary
    placement_position_m = 5e-5      # 1σ of a tag's placement on its body, per coordinate
    placement_angle_deg = 0.05       # 1σ of its rotation on the body, per axis

    [layouts.triax-block]            # tag index → side and pose in the body frame
    tags = [{index = 0, side_m = 0.024, offset_m = [0, 0, 0.016], rotation_deg = [0, 0, 0]}, ...]

    [[bodies]]
    kind = "triax"                   # triax | input | reference | scalebar
    node = 1                         # triax and input: the setup's node
    layout = "triax-block"           # or inline: tags = [...]
    first_id = 0                     # tag id = first_id + index

    [[bodies]]
    kind = "reference"               # a plate whose pose in the article's frame is stated
    name = "REF0"
    layout = "plate"
    first_id = 400
    position_m = [0.2, 0.15, 0.05]
    rotation_deg = [0, 0, 45]        # rotation vector, degrees (body → article frame)
    position_std_m = 5e-5
    angle_std_deg = 0.05

A triax's body frame is the sensor's (origin at its measuring point, axes its X, Y, Z); an
input's has its origin at the impact point and the line of action along ``−z``; a scale bar is a
body whose tags are a certified distance apart (the layout states it). ``rotation_deg`` is a
rotation vector in degrees (``scipy.spatial.transform.Rotation.from_rotvec``).
"""

from __future__ import annotations

import tomllib
from pathlib import Path
from typing import Any, Literal

import numpy as np
import tomli_w
from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator
from scipy.spatial.transform import Rotation

from dimacq.errors import SetupError
from dimacq.io.validation import refuse
from dimacq.pipeline.photogrammetry.bundle import BodyModel, TagMount

__all__ = ["BodySpec", "TagSpec", "TagsFile", "dump_tags", "load_tags"]


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class TagSpec(_Model):
    """One tag of a layout: index (id = body's ``first_id`` + index), side, pose on the body."""

    index: int = Field(ge=0)
    side_m: float = Field(gt=0, le=2.0)
    offset_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    rotation_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)


class LayoutSpec(_Model):
    tags: list[TagSpec] = Field(min_length=1)


class BodySpec(_Model):
    """One body carrying tags (see the module)."""

    kind: Literal["triax", "input", "reference", "scalebar"]
    node: int | None = None
    name: str = ""
    layout: str | None = None
    tags: list[TagSpec] | None = None
    first_id: int = Field(default=0, ge=0)
    position_m: tuple[float, float, float] | None = None
    rotation_deg: tuple[float, float, float] | None = None
    position_std_m: float = Field(default=5e-5, gt=0, le=0.1)
    angle_std_deg: float = Field(default=0.05, gt=0, le=45)

    @model_validator(mode="after")
    def _check(self) -> BodySpec:
        if (self.layout is None) == (self.tags is None):
            raise ValueError("give either layout (a name of [layouts]) or tags, not both/neither")
        if self.kind in ("triax", "input") and self.node is None:
            raise ValueError(f"a {self.kind} body needs its node (the setup's node number)")
        if self.kind == "reference" and (self.position_m is None or self.rotation_deg is None):
            raise ValueError(
                "a reference body needs its stated position_m and rotation_deg in the article's "
                "frame"
            )
        return self

    def label(self) -> str:
        if self.name:
            return self.name
        return f"{self.kind} {self.node}" if self.node is not None else self.kind


class TagsFile(_Model):
    """A tags file (see the module)."""

    schema_version: Literal[1] = 1
    family: str = "DICT_APRILTAG_36h11"
    placement_position_m: float = Field(default=5e-5, ge=0, le=0.01)
    placement_angle_deg: float = Field(default=0.05, ge=0, le=10)
    layouts: dict[str, LayoutSpec] = Field(default_factory=dict)
    bodies: list[BodySpec] = Field(min_length=1)

    @model_validator(mode="after")
    def _ids(self) -> TagsFile:
        seen: dict[int, str] = {}
        for b in self.bodies:
            if b.layout is not None and b.layout not in self.layouts:
                raise ValueError(
                    f"body {b.label()!r}: layout {b.layout!r} is not in [layouts] "
                    f"({sorted(self.layouts)}); define it or fix the name"
                )
            for t in self.tags_of(b):
                tid = b.first_id + t.index
                if tid in seen:
                    raise ValueError(
                        f"tag id {tid} is on both {seen[tid]!r} and {b.label()!r}; give each "
                        "body its own first_id"
                    )
                seen[tid] = b.label()
        labels = [b.label() for b in self.bodies]
        dup = sorted({x for x in labels if labels.count(x) > 1})
        if dup:
            raise ValueError(f"bodies {dup} are given twice; one entry per node or name")
        return self

    def tags_of(self, body: BodySpec) -> list[TagSpec]:
        return (
            list(body.tags) if body.tags is not None else list(self.layouts[body.layout or ""].tags)
        )

    def body_models(self) -> list[BodyModel]:
        """The bodies as the bundle adjustment takes them (tags mounted at their stated
        poses; reference bodies with their stated pose as prior)."""
        out = []
        for b in self.bodies:
            mounts = tuple(
                TagMount(
                    b.first_id + t.index,
                    t.side_m,
                    Rotation.from_rotvec(np.radians(t.rotation_deg)).as_matrix(),
                    np.asarray(t.offset_m, float),
                )
                for t in self.tags_of(b)
            )
            ref = b.kind == "reference"
            out.append(
                BodyModel(
                    b.label(),
                    b.kind,
                    mounts,
                    node=b.node,
                    prior_rotation=Rotation.from_rotvec(np.radians(b.rotation_deg)).as_matrix()
                    if ref and b.rotation_deg is not None
                    else None,
                    prior_position_m=np.asarray(b.position_m, float)
                    if ref and b.position_m is not None
                    else None,
                    prior_position_std_m=b.position_std_m,
                    prior_angle_std_deg=b.angle_std_deg,
                )
            )
        return out


def load_tags(path: str | Path) -> TagsFile:
    """Read and check a tags file; a bad one is refused with the item and the fix named."""
    p = Path(path)
    try:
        data: Any = tomllib.loads(p.read_text(encoding="utf-8"))
    except FileNotFoundError as err:
        raise SetupError(f"tags file {p}: not found; give the path of the tags file") from err
    except tomllib.TOMLDecodeError as err:
        raise SetupError(f"tags file {p}: not valid TOML ({err}); fix the syntax") from err
    try:
        return TagsFile.model_validate(data)
    except ValidationError as err:
        raise refuse(
            "tags file", str(p), err, TagsFile, "see dimacq/manual/photo-geometry.md"
        ) from err


def dump_tags(tags: TagsFile, path: str | Path) -> None:
    """Write a tags file (TOML)."""
    Path(path).write_text(tomli_w.dumps(tags.model_dump(exclude_none=True)), encoding="utf-8")


def _face_rotations() -> list[Rotation]:
    """Rotations taking a tag's +z to each face normal of a cube: +z, +x, −x, +y, −y, −z."""
    return [
        Rotation.identity(),
        Rotation.from_euler("y", 90, degrees=True),
        Rotation.from_euler("y", -90, degrees=True),
        Rotation.from_euler("x", -90, degrees=True),
        Rotation.from_euler("x", 90, degrees=True),
        Rotation.from_euler("x", 180, degrees=True),
    ]


def _tag(index: int, side: float, rot: Rotation, offset: Any) -> TagSpec:
    return TagSpec(
        index=index,
        side_m=float(side),
        offset_m=tuple(float(v) for v in offset),  # type: ignore[arg-type]
        rotation_deg=tuple(float(v) for v in np.degrees(rot.as_rotvec())),  # type: ignore[arg-type]
    )


def standard_tags(
    triax_nodes: list[int],
    input_nodes: list[int],
    points_m: Any,
    *,
    tag_side_m: float | None = None,
    reference_std_m: float = 5e-5,
    reference_angle_deg: float = 0.05,
) -> TagsFile:
    """The lab's standard tag plan for an article whose measured points are ``points_m``
    (shape (n, 3), article frame).

    Each triax carries a cube cap of edge ``1.25 s`` with a tag of side ``s`` on every face
    (its frame is the sensor's); each input an impact jig, a cube of edge ``1.25 s`` standing on
    the impact point along the line of action, with tags on its top and four sides; reference
    plates (tags of side ``1.6 s``) stand at the corners of the points' box grown by ``3 s`` and,
    on a long article, every ~1.5 m along its edges, facing out of the box; a scale bar with two
    such tags ``0.6 ×`` the box's shortest extent apart. ``s`` defaults to 5 % of the box
    diagonal within 20–60 mm.
    """
    pts = np.asarray(points_m, float).reshape(-1, 3)
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    s = float(tag_side_m or np.clip(0.05 * np.linalg.norm(hi - lo), 0.02, 0.06))
    h = 0.625 * s
    faces = _face_rotations()
    block = LayoutSpec(tags=[_tag(k, s, f, f.apply([0.0, 0.0, h])) for k, f in enumerate(faces)])
    jig = LayoutSpec(
        tags=[
            _tag(k, s, f, f.apply([0.0, 0.0, h]) + np.array([0.0, 0.0, h]))
            for k, f in enumerate(faces[:5])
        ]
    )
    plate = LayoutSpec(tags=[_tag(0, 1.6 * s, Rotation.identity(), (0.0, 0.0, 0.0))])
    lo_r, hi_r = lo - 3 * s, hi + 3 * s
    centre = 0.5 * (lo_r + hi_r)
    stations = [
        np.linspace(lo_r[k], hi_r[k], max(2, int(np.ceil((hi_r[k] - lo_r[k]) / 1.5)) + 1))
        for k in range(3)
    ]
    refs = []
    for x in stations[0]:
        for y in stations[1]:
            for z in stations[2]:
                p = np.array([x, y, z])
                extreme = np.isclose(p, lo_r) | np.isclose(p, hi_r)
                if extreme.sum() >= 2:
                    refs.append(p)
    bodies: list[BodySpec] = []
    nid = 0
    for n in triax_nodes:
        bodies.append(BodySpec(kind="triax", node=n, layout="triax-block", first_id=nid))
        nid += 6
    for n in input_nodes:
        bodies.append(BodySpec(kind="input", node=n, layout="impact-jig", first_id=nid))
        nid += 5
    for k, p in enumerate(refs):
        out = (p - centre) / np.maximum(hi_r - lo_r, 1e-9)
        normal = out / np.linalg.norm(out)
        rot, _ = Rotation.align_vectors([normal], [[0.0, 0.0, 1.0]])
        bodies.append(
            BodySpec(
                kind="reference",
                name=f"REF{k}",
                layout="plate",
                first_id=nid,
                position_m=tuple(float(v) for v in p),  # type: ignore[arg-type]
                rotation_deg=tuple(float(v) for v in np.degrees(rot.as_rotvec())),  # type: ignore[arg-type]
                position_std_m=reference_std_m,
                angle_std_deg=reference_angle_deg,
            )
        )
        nid += 1
    bar_len = 0.6 * float(np.min(hi - lo)) if np.min(hi - lo) > 0 else 0.3
    bar = [
        _tag(k, 1.6 * s, Rotation.identity(), (sign * bar_len / 2, 0.0, 0.0))
        for k, sign in enumerate((-1.0, 1.0))
    ]
    bodies.append(BodySpec(kind="scalebar", name="scale bar", tags=bar, first_id=nid))
    return TagsFile(
        layouts={"triax-block": block, "impact-jig": jig, "plate": plate}, bodies=bodies
    )
