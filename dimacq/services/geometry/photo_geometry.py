"""Geometry from photographs: fiducial tags detected by OpenCV, a bundle adjustment, and the
triaxes' and inputs' geometry as the digitizing chain records it.

Steps (:func:`geometry_from_photos`): read each photo of a folder (its EXIF focal length, or a
camera file), detect the tags of the family the tags file names
(``cv2.aruco.ArucoDetector``, corners refined to sub-pixel), name every photo that cannot help
and why (unreadable, blurred, no tags, tags of another family, one tag only, another image
size), chain first poses from the reference plates outwards (``cv2.solvePnP`` per tag and per
photo), then adjust everything together (:func:`dimacq.pipeline.photogrammetry.bundle.adjust`,
the intrinsics refined unless a camera file fixes them). Each triax and input becomes an
:class:`~dimacq.services.geometry.records.Orientation` or
:class:`~dimacq.services.geometry.records.LineOfAction` record with its standard
uncertainty (the adjustment's covariance ⊕ the tags' placement on their bodies), the records a
digitized setup is built from (:func:`dimacq.services.geometry.geometry_trust.geometry_uncertainty`).

A body whose tags are seen in fewer than :data:`MIN_VIEWS` photos is not fixed: the result
names it and how many more photos it needs.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from dimacq.errors import DataError, SetupError
from dimacq.io.tags_file import TagsFile
from dimacq.model.setup import TestSetup
from dimacq.pipeline.photogrammetry.bundle import BodyModel, BundleResult, Observation, adjust
from dimacq.pipeline.photogrammetry.camera import Intrinsics
from dimacq.services.geometry.photo_input import Photo, detect_tags, load_camera, read_photos
from dimacq.services.geometry.photo_poses import initial_poses, pose_from_points
from dimacq.services.geometry.photo_records import (
    PhotoGeometry,
    PhotoIssue,
    apply_to_setup,
    bundle_records,
)
from dimacq.services.geometry.records import LineOfAction, Orientation

__all__ = [
    "LIMIT_ANGLE_STD_DEG",
    "LIMIT_LOA_STD_DEG",
    "LIMIT_POSITION_STD_M",
    "MIN_VIEWS",
    "PHOTO_SUFFIXES",
    "PhotoGeometry",
    "PhotoIssue",
    "apply_to_setup",
    "detect_tags",
    "geometry_from_photos",
    "load_camera",
    "pose_from_points",
    "read_photos",
    "tied_only",
    "tied_views",
    "too_uncertain",
]

log = logging.getLogger(__name__)
FloatArray = NDArray[np.float64]

#: Photos a triax or input's tags must be seen in for its pose to count as fixed.
MIN_VIEWS = 3
PHOTO_SUFFIXES = (".jpg", ".jpeg", ".png", ".tif", ".tiff", ".bmp")
#: Tag views more oblique than this (angle between the tag's normal and the line of sight)
#: are left out of the adjustment.
MAX_INCIDENCE_DEG = 65.0
#: A triax whose stated 1σ exceeds these (per axis, per coordinate) is not fixed: the set is
#: refused and the triax named with the photos it still needs (``σ ∝ 1/√n``).
LIMIT_ANGLE_STD_DEG = 0.1
LIMIT_POSITION_STD_M = 2e-4
#: An input's line of action whose stated 1σ exceeds this angle is named (a warning).
LIMIT_LOA_STD_DEG = 0.2
#: A tag whose estimated placement is this many times the spread of a tag placed within its
#: stated 1σ is named as glued off its place (a warning) and its block's pose taken from its
#: other tags.
MISPLACED_Z = 4.5
#: A body whose corners' residuals are this many times the set's σ (its
#: ``residual_factor``) is named (its stated 1σ is scaled by the factor in any case).
DISAGREE_FACTOR = 2.0


# ------------------------------------------------------------------------------ the chain
def geometry_from_photos(
    photos_dir: str | Path,
    tags: TagsFile,
    *,
    setup: TestSetup | None = None,
    camera: tuple[Intrinsics, bool] | None = None,
    progress: Callable[[str], None] | None = None,
) -> PhotoGeometry:
    """Triax orientations and lines of action from the photos in ``photos_dir``.

    Parameters
    ----------
    photos_dir : path
        A folder of photos (JPEG, PNG, TIFF), one camera at one zoom.
    tags : TagsFile
    setup : TestSetup, optional
        The setup to put the geometry into (:func:`apply_to_setup`); its triax and input nodes
        without tags are named in ``unfixed``.
    camera : (Intrinsics, refine), optional
        A camera file's intrinsics (:func:`load_camera`); default: the photos' EXIF focal
        length, principal point at the image centre, no distortion, all refined.
    progress : callable (message), optional

    Raises
    ------
    DataError
        No usable photo, no focal length (EXIF-less photos and no camera file), or no reference
        plate seen: the message names the photos and the fix.
    """
    say = progress or (lambda _m: None)
    paths, photos, issues, models, known = _photos_of(Path(photos_dir), tags, say)
    intr, refine, source = _start_intrinsics(photos, camera, issues)
    views, unfixed = _views(models, photos, known, setup, issues)
    use_bodies = [
        bi
        for bi, b in enumerate(models)
        if views[bi] >= (1 if b.kind in ("reference", "scalebar") else MIN_VIEWS)
    ]
    sub_models = [models[bi] for bi in use_bodies]
    cams, poses = initial_poses(sub_models, photos, intr, say)
    if not any(sub_models[i].prior_position_m is not None for i in poses):
        raise DataError(
            "no reference plate is seen in any photo: the article's frame is not fixed; "
            "photograph the reference plates together with the triaxes and inputs"
        )
    obs, cam_idx, body_idx = _tied_observations(
        sub_models, photos, cams, poses, unfixed, issues, say
    )
    final_models = [sub_models[i] for i in body_idx]
    say(f"adjusting {len(cam_idx)} photos, {len(final_models)} bodies, {4 * len(obs)} corners")
    bundle = adjust(
        final_models,
        obs,
        intr,
        [cams[c][0] for c in cam_idx],
        [cams[c][1] for c in cam_idx],
        [poses[i][0] for i in body_idx],
        [poses[i][1] for i in body_idx],
        refine_intrinsics=refine,
        progress=lambda n, cost: say(f"adjustment: {n} evaluations, cost {cost:.4g}"),
        placement=(tags.placement_angle_deg, tags.placement_position_m),
        misplaced_z=MISPLACED_Z,
    )
    used = [photos[c].name for c in cam_idx]
    _bundle_issues(bundle, used, issues)
    depth = float(np.median(np.linalg.norm(bundle.camera_translations, axis=1)))
    scale_m = bundle.sigma_px * depth / bundle.intrinsics.fx
    orientations, loas = bundle_records(bundle, final_models, tags, scale_m)
    unfixed.extend(too_uncertain(bundle, orientations, loas, issues, tied_views(obs, final_models)))
    say(
        f"adjusted: σ {bundle.sigma_px:.3f} px, {len(orientations)} triaxes, {len(loas)} inputs, "
        f"{len(unfixed)} not fixed"
    )
    result = PhotoGeometry(
        orientations=orientations,
        lines_of_action=loas,
        bodies=list(bundle.bodies),
        bundle=bundle,
        photos=[p.name for p in paths],
        used=used,
        issues=issues,
        unfixed=unfixed,
        intrinsics_source=source,
        counts={"photos": len(paths), "used": len(used), "observations": len(obs)},
    )
    if setup is not None and not unfixed:
        result = replace(result, setup=apply_to_setup(setup, result))
    return result


def _photos_of(
    folder: Path, tags: TagsFile, say: Callable[[str], None]
) -> tuple[list[Path], list[Photo], list[PhotoIssue], list[BodyModel], set[int]]:
    """The photos of ``folder`` with their tags read (:func:`read_photos`), the issues met,
    the tags file's bodies and tag ids.

    Raises
    ------
    SetupError, DataError
        Not a folder, no photos, or none showing a tag of the tags file.
    """
    if not folder.is_dir():
        raise SetupError(f"photos folder {folder}: not a folder; give the folder of the photos")
    paths = sorted(p for p in folder.iterdir() if p.suffix.lower() in PHOTO_SUFFIXES)
    if not paths:
        raise DataError(
            f"photos folder {folder}: no photos ({', '.join(PHOTO_SUFFIXES)}); copy the photos there"
        )
    models = [_with_placement(b, tags) for b in tags.body_models()]
    known = {t.tag_id for b in models for t in b.tags}
    photos, issues = read_photos(paths, tags.family, known, say)
    if not photos:
        raise DataError(
            f"photos folder {folder}: none of {len(paths)} photos shows a tag of the tags file: "
            + "; ".join(str(i) for i in issues[:5])
        )
    return paths, photos, issues, models, known


def _with_placement(body: BodyModel, tags: TagsFile) -> BodyModel:
    """A reference body whose prior also carries its tags' placement on it: the tags the
    adjustment sees sit at the stated pose ⊕ their placement, ``σ² = σ_stated² + σ_place²/k``
    over its ``k`` tags (per coordinate, per axis)."""
    if body.prior_position_m is None:
        return body
    k = max(len(body.tags), 1)
    return replace(
        body,
        prior_position_std_m=float(
            np.hypot(body.prior_position_std_m, tags.placement_position_m / np.sqrt(k))
        ),
        prior_angle_std_deg=float(
            np.hypot(body.prior_angle_std_deg, tags.placement_angle_deg / np.sqrt(k))
        ),
    )


def _start_intrinsics(
    photos: list[Photo], camera: tuple[Intrinsics, bool] | None, issues: list[PhotoIssue]
) -> tuple[Intrinsics, bool, str]:
    """The intrinsics to start from, whether to refine them, and where they come from: the
    camera file, else the photos' EXIF focal length (median), the image centre, no distortion.

    Raises
    ------
    SetupError, DataError
        The camera file is for another image size; no camera file and no EXIF focal length.
    """
    w, h = photos[0].size
    if camera is not None:
        intr, refine = camera
        if (intr.width, intr.height) != (w, h):
            raise SetupError(
                f"camera file is for {intr.width}x{intr.height} px, the photos are {w}x{h} px; "
                "calibrate the camera at the photos' resolution"
            )
        return intr, refine, "camera file"
    focals = [p.focal_px for p in photos if p.focal_px]
    if not focals:
        raise DataError(
            f"{len(photos)} photos carry no EXIF focal length (e.g. {photos[0].name}): give "
            "--camera CAM.toml (fx, fy, cx, cy in pixels from a calibration) or use the "
            "camera's original files, whose EXIF states the focal length"
        )
    no_exif = [p.name for p in photos if not p.focal_px]
    if no_exif:
        issues.append(
            PhotoIssue(
                ", ".join(no_exif[:5]),
                "warn",
                f"{len(no_exif)} photos without EXIF focal length (the others' is used)",
                "keep the camera's original files",
            )
        )
    f = float(np.median(focals))
    intr = Intrinsics(fx=f, fy=f, cx=(w - 1) / 2, cy=(h - 1) / 2, width=w, height=h)
    return intr, True, "EXIF focal length, refined in the adjustment"


def _views(
    models: list[BodyModel],
    photos: list[Photo],
    known: set[int],
    setup: TestSetup | None,
    issues: list[PhotoIssue],
) -> tuple[dict[int, int], list[str]]:
    """Photos showing each body (by index), and what is not fixed: triaxes and inputs seen in
    fewer than :data:`MIN_VIEWS` photos (with how many more they need), the setup's triaxes and
    inputs without tags; a tag seen in one photo only is added to ``issues``."""
    views: dict[int, int] = {}
    for bi, b in enumerate(models):
        ids = {t.tag_id for t in b.tags}
        views[bi] = sum(1 for p in photos if ids & set(p.tags))
    unfixed = []
    for bi, b in enumerate(models):
        if b.kind in ("triax", "input") and views[bi] < MIN_VIEWS:
            id_list = sorted(t.tag_id for t in b.tags)
            need = MIN_VIEWS - views[bi]
            unfixed.append(
                f"{b.name}: its tags (ids {id_list[0]}–{id_list[-1]}) are seen in {views[bi]} photo(s); "
                f"take at least {need} more photo(s) showing them from other directions"
            )
    if setup is not None:
        have = {b.node for b in models if b.kind == "triax"}
        have_in = {b.node for b in models if b.kind == "input"}
        for n in sorted({ch.node for ch in setup.responses} - have):
            unfixed.append(f"triax {n}: no tags in the tags file; add its block to the tags file")
        for n in sorted({e.node for e in setup.excitations} - have_in):
            unfixed.append(f"input {n}: no tags in the tags file; add its jig to the tags file")
    for tid in sorted(known):
        n = sum(1 for p in photos if tid in p.tags)
        if n == 1:
            issues.append(
                PhotoIssue(
                    next(p.name for p in photos if tid in p.tags),
                    "warn",
                    f"tag {tid} is seen in this photo only",
                    "a tag seen once fixes nothing: show it in at least two more photos",
                )
            )
    return views, unfixed


def _tied_observations(
    sub_models: list[BodyModel],
    photos: list[Photo],
    cams: dict[int, tuple[FloatArray, FloatArray]],
    poses: dict[int, tuple[FloatArray, FloatArray]],
    unfixed: list[str],
    issues: list[PhotoIssue],
    say: Callable[[str], None],
) -> tuple[list[Observation], list[int], list[int]]:
    """The observations the adjustment uses (photos and bodies tied to the reference plates,
    tag views not too oblique), indexed by photo in the returned photo list; the photos
    (indices into ``photos``) and bodies (into ``sub_models``) they use. What is left out is
    added to ``unfixed`` (triaxes, inputs) or ``issues`` (photos)."""
    for i, b in enumerate(sub_models):
        if i not in poses and b.kind in ("triax", "input"):
            unfixed.append(
                f"{b.name}: its tags are never seen in a photo with tags already tied to the "
                "reference plates; take photos showing it with its neighbours"
            )
    for c, p in enumerate(photos):
        if c not in cams:
            issues.append(
                PhotoIssue(
                    p.name,
                    "skipped",
                    "its tags are not tied to the reference plates by any other photo",
                    "take photos bridging these tags and the rest",
                )
            )
    cam_idx = sorted(cams)
    body_idx = sorted(poses)
    final_models = [sub_models[i] for i in body_idx]
    remap = {c: k for k, c in enumerate(cam_idx)}
    mount = {t.tag_id for b in final_models for t in b.tags}
    obs = [
        Observation(remap[c], tid, corners)
        for c in cam_idx
        for tid, corners in photos[c].tags.items()
        if tid in mount
    ]
    obs, oblique = _drop_oblique(
        obs, final_models, [cams[c] for c in cam_idx], [poses[i] for i in body_idx]
    )
    if oblique:
        say(f"{oblique} tag views more oblique than {MAX_INCIDENCE_DEG:g} deg left out")
    obs = tied_only(obs, final_models)
    # photos and bodies left without a view are left out (nothing would fix them)
    seen_cams = sorted({o.photo for o in obs})
    tag_body = {t.tag_id: k for k, b in enumerate(final_models) for t in b.tags}
    seen_bodies = sorted({tag_body[o.tag_id] for o in obs})
    for k, b in enumerate(final_models):
        if k not in seen_bodies and b.kind in ("triax", "input"):
            unfixed.append(
                f"{b.name}: its tags are seen only edge-on (more than {MAX_INCIDENCE_DEG:g} deg "
                "from square on); take photos facing them"
            )
    cam_idx = [cam_idx[k] for k in seen_cams]
    cmap = {old: new_ for new_, old in enumerate(seen_cams)}
    body_idx = [body_idx[k] for k in seen_bodies]
    obs = [replace(o, photo=cmap[o.photo]) for o in obs]
    return obs, cam_idx, body_idx


def tied_only(obs: list[Observation], models: list[BodyModel]) -> list[Observation]:
    """``obs`` without the views of a body with no stated pose seen in one photo only (nothing
    but that photo fixes it) and of a photo showing one tag only (a small square alone leaves
    its tilt and its distance all but undetermined: the planar pose ambiguity); repeated until
    there is none."""
    body_of = {t.tag_id: k for k, b in enumerate(models) for t in b.tags}
    while True:
        photos_of: dict[int, set[int]] = {}
        tags_in: dict[int, int] = {}
        for o in obs:
            photos_of.setdefault(body_of[o.tag_id], set()).add(o.photo)
            tags_in[o.photo] = tags_in.get(o.photo, 0) + 1
        loose = {
            k for k, ph in photos_of.items() if len(ph) < 2 and models[k].prior_position_m is None
        }
        lone = {c for c, n in tags_in.items() if n < 2}
        if not loose and not lone:
            return obs
        obs = [o for o in obs if body_of[o.tag_id] not in loose and o.photo not in lone]


def _more_views(n: int, ratio: float) -> int:
    """Photos to add to ``n`` to bring a 1σ ``ratio`` times its limit under it,
    ``σ ∝ 1/√n``: ``⌈n (ratio² − 1)⌉``."""
    return max(1, int(np.ceil(n * (ratio**2 - 1.0))))


def too_uncertain(
    bundle: BundleResult,
    orientations: list[Orientation],
    loas: list[LineOfAction],
    issues: list[PhotoIssue],
    tied: dict[tuple[str, int | None], int] | None = None,
) -> list[str]:
    """The triaxes whose stated 1σ exceeds :data:`LIMIT_ANGLE_STD_DEG` or
    :data:`LIMIT_POSITION_STD_M`, each with the photos it still needs; inputs over
    :data:`LIMIT_LOA_STD_DEG` are added to ``issues``.

    Only a photo showing the block together with another tied body fixes it (a photo of the
    block alone leaves the camera's pose, and so the block's, free), so the count ``n`` is
    those photos (``tied``: body's kind and node → photos; default every photo of the block)
    and the advice asks for such photos: more close-ups from other sides for the angle, more
    views with the reference plates or tied neighbours for the position (its tie to the
    article's frame)."""
    seen = {(b.kind, b.node): b.n_photos for b in bundle.bodies}
    with_others = tied if tied is not None else seen
    out = []
    for o in orientations:
        angle = max(o.angle_std_deg or [0.0])
        pos = o.origin_std_m or 0.0
        ra, rp = angle / LIMIT_ANGLE_STD_DEG, pos / LIMIT_POSITION_STD_M
        if max(ra, rp) <= 1.0:
            continue
        n = max(with_others.get(("triax", o.node), 0), 1)
        fixes = []
        if ra > 1.0:
            fixes.append(
                f"take about {_more_views(n, ra)} more close-ups of its block from other sides, "
                "each showing a neighbouring tagged body too"
            )
        if rp > 1.0:
            fixes.append(
                f"take about {_more_views(n, rp)} more photos showing its block together with "
                "reference plates (or blocks already tied to them)"
            )
        out.append(
            f"triax {o.node}: stated 1σ {angle:.3f} deg, {1e3 * pos:.3f} mm from {n} photos "
            f"showing it with other tagged bodies (limits {LIMIT_ANGLE_STD_DEG:g} deg, "
            f"{1e3 * LIMIT_POSITION_STD_M:g} mm); " + "; ".join(fixes)
        )
    for a in loas:
        if (a.angle_std_deg or 0.0) > LIMIT_LOA_STD_DEG:
            n = max(with_others.get(("input", a.node), 0), 1)
            issues.append(
                PhotoIssue(
                    f"input {a.node}",
                    "warn",
                    f"line of action 1σ {a.angle_std_deg:.3f} deg from {n} photos "
                    f"(over {LIMIT_LOA_STD_DEG:g} deg)",
                    f"take about {_more_views(n, a.angle_std_deg / LIMIT_LOA_STD_DEG)} more "
                    "close-ups of its jig, each showing a neighbouring tagged body too",
                )
            )
    return out


def tied_views(
    obs: list[Observation], models: list[BodyModel]
) -> dict[tuple[str, int | None], int]:
    """Photos in which each body (kind, node) is seen together with another body's tags."""
    body_of = {t.tag_id: k for k, b in enumerate(models) for t in b.tags}
    per_photo: dict[int, set[int]] = {}
    for o in obs:
        per_photo.setdefault(o.photo, set()).add(body_of[o.tag_id])
    out: dict[tuple[str, int | None], int] = {}
    for bodies in per_photo.values():
        if len(bodies) > 1:
            for k in bodies:
                key = (models[k].kind, models[k].node)
                out[key] = out.get(key, 0) + 1
    return out


def _bundle_issues(bundle: BundleResult, used: list[str], issues: list[PhotoIssue]) -> None:
    """Add to ``issues`` the photos whose corner residual is over 4 × the set's and the tag
    views the adjustment left out as gross errors."""
    for k, r in enumerate(bundle.photo_rms_px):
        if np.isfinite(r) and r > 4 * max(bundle.sigma_px, 0.1):
            issues.append(
                PhotoIssue(
                    used[k],
                    "warn",
                    f"corner residual {r:.2f} px, {r / bundle.sigma_px:.1f} times the set's",
                    "motion blur or a tag misread: retake it",
                )
            )
    for k_photo, t, r in bundle.rejected:
        issues.append(
            PhotoIssue(
                used[k_photo],
                "warn",
                f"tag {t} left out as a gross error ({r:.1f} px)",
                "a tag partly hidden or misread: retake it",
            )
        )
    for b in bundle.bodies:
        if b.kind in ("triax", "input") and b.residual_factor > DISAGREE_FACTOR:
            issues.append(
                PhotoIssue(
                    b.name,
                    "warn",
                    f"its tags' corners disagree with the set's: residuals "
                    f"{b.residual_factor:.1f} times the set's σ over {b.n_photos} photos, so its "
                    "stated 1σ is scaled by as much",
                    "a tag partly hidden by a neighbouring body, bent or dirty: photograph it "
                    "from where nothing stands in front of its tags, or clear the view",
                )
            )
    for tp in bundle.placements:
        if tp.z > MISPLACED_Z:
            issues.append(
                PhotoIssue(
                    f"tag {tp.tag_id} on {tp.body}",
                    "warn",
                    f"sits {1e3 * float(np.linalg.norm(tp.shift_m)):.2f} mm and "
                    f"{float(np.degrees(np.linalg.norm(tp.angle_rad))):.3f}° off its stated place "
                    f"on the body ({tp.z:.1f} times its stated placement 1σ; {tp.n_views} views)"
                    + (
                        "; its block's pose is taken from its other tags"
                        if tp.freed
                        else "; its block has no other tag to take its pose from"
                    ),
                    "glue it square in its place (or state a larger placement 1σ in the tags "
                    "file) and photograph it again",
                )
            )


def _drop_oblique(
    obs: list[Observation],
    models: list[BodyModel],
    cams: list[tuple[FloatArray, FloatArray]],
    poses: list[tuple[FloatArray, FloatArray]],
) -> tuple[list[Observation], int]:
    """The observations whose tag faces the camera within :data:`MAX_INCIDENCE_DEG` at the
    first poses (a tag seen edge-on has its corners located far less well), each with its
    corner 1σ scaled by ``1/cos θ`` (its border is foreshortened by ``cos θ``)."""
    mount = {t.tag_id: (i, t) for i, b in enumerate(models) for t in b.tags}
    keep = []
    for o in obs:
        bi, t = mount[o.tag_id]
        rb, pb = poses[bi]
        rc, tc = cams[o.photo]
        centre = rc @ (rb @ t.offset_m + pb) + tc
        normal = rc @ rb @ t.rotation[:, 2]
        cos = -float(np.dot(normal, centre)) / float(np.linalg.norm(centre))
        if cos >= np.cos(np.radians(MAX_INCIDENCE_DEG)):
            keep.append(replace(o, sigma_scale=1.0 / cos))
    return keep, len(obs) - len(keep)
