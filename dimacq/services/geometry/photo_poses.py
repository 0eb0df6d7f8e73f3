"""First poses for the photo adjustment, chained from the reference plates.

A photo's pose (world → camera) comes from the placed tags it shows, a body's (body → world)
from the photos already placed that show it; each from the candidate most other views agree
with (:data:`INIT_AGREE`), so that a single tag's mirrored pose or one wrongly placed body does
not carry on through the chain. The bundle adjustment
(:func:`dimacq.pipeline.photogrammetry.bundle.adjust`) starts from them.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray

from dimacq.errors import DataError
from dimacq.pipeline.photogrammetry.bundle import BodyModel, TagMount
from dimacq.pipeline.photogrammetry.camera import Intrinsics, tag_corners, undistort_normalised
from dimacq.services.geometry.photo_input import Photo, load_cv2

__all__ = ["INIT_AGREE", "initial_poses", "pose_from_points"]

FloatArray = NDArray[np.float64]


def pose_from_points(
    obj: FloatArray, xy: FloatArray, planar_square: bool
) -> tuple[FloatArray, FloatArray, float]:
    """(R, t, rms) of object points seen at normalised image points (camera matrix I)."""
    cv2 = load_cv2()
    k = np.eye(3)
    if planar_square:
        _n, rs, ts, errs = cv2.solvePnPGeneric(
            obj.astype(np.float64), xy.astype(np.float64), k, None, flags=cv2.SOLVEPNP_IPPE_SQUARE
        )
        best = int(np.argmin(np.asarray(errs).ravel()))
        r, t, e = rs[best], ts[best], float(np.asarray(errs).ravel()[best])
    else:
        ok, r, t = cv2.solvePnP(
            obj.astype(np.float64), xy.astype(np.float64), k, None, flags=cv2.SOLVEPNP_SQPNP
        )
        if not ok:
            raise DataError("pose: solvePnP failed")
        ok, r, t = cv2.solvePnP(obj, xy, k, None, r, t, True, cv2.SOLVEPNP_ITERATIVE)
        proj, _ = cv2.projectPoints(obj, r, t, k, None)
        e = float(np.sqrt(np.mean((proj.reshape(-1, 2) - xy) ** 2)))
    return cv2.Rodrigues(r)[0], np.asarray(t, float).ravel(), e


#: First poses: a tag view whose corners lie farther than this (RMS, normalised image units:
#: 45 px at a focal length of 1500 px) from where a candidate pose puts them disagrees with
#: it. The first poses ignore the lens distortion (up to some 30 px at a photo's corners).
INIT_AGREE = 0.03


def initial_poses(
    models: list[BodyModel],
    photos: list[Photo],
    intr: Intrinsics,
    say: Callable[[str], None],
) -> tuple[dict[int, tuple[FloatArray, FloatArray]], dict[int, tuple[FloatArray, FloatArray]]]:
    """First poses, chained from the reference plates: photos (world → camera) and bodies
    (body → world) that can be reached; the rest stay out.

    Each pose is the candidate most of the views agree with (:func:`_photo_pose`,
    :func:`_body_pose`), so one body placed wrongly, or a tag's mirrored planar pose, does not
    carry on through the chain. A photo showing one placed tag only waits until no photo with
    more can be placed. Once the chain ends every photo and every body without a stated pose is
    placed again from all the others (twice)."""
    mount = {t.tag_id: (i, t) for i, b in enumerate(models) for t in b.tags}
    norm = [
        {tid: undistort_normalised(c, intr) for tid, c in p.tags.items() if tid in mount}
        for p in photos
    ]
    bodies: dict[int, tuple[FloatArray, FloatArray]] = {
        i: (np.asarray(b.prior_rotation), np.asarray(b.prior_position_m))
        for i, b in enumerate(models)
        if b.prior_position_m is not None
    }
    cams: dict[int, tuple[FloatArray, FloatArray]] = {}
    while True:
        progress = False
        for min_tags in (2, 1):
            for c, obs in enumerate(norm):
                if c in cams:
                    continue
                pose = _photo_pose(obs, mount, bodies, min_tags)
                if pose is not None:
                    cams[c] = pose
                    progress = True
            if progress:
                break
        for bi, b in enumerate(models):
            if bi in bodies:
                continue
            pose = _body_pose(b, cams, norm, photos)
            if pose is not None:
                bodies[bi] = pose
                progress = True
        if not progress:
            break
    for _sweep in range(2):
        for c in list(cams):
            cams[c] = _photo_pose(norm[c], mount, bodies, 1) or cams[c]
        for bi, b in enumerate(models):
            if b.prior_position_m is None and bi in bodies:
                bodies[bi] = _body_pose(b, cams, norm, photos) or bodies[bi]
    say(f"first poses: {len(cams)} of {len(photos)} photos, {len(bodies)} of {len(models)} bodies")
    return cams, bodies


def _tag_rms(r_c: FloatArray, t_c: FloatArray, corners_w: FloatArray, xy: FloatArray) -> float:
    """RMS distance (normalised units) of a tag's corners ``corners_w`` (world) seen through
    the camera ``X_c = r_c X + t_c`` from where they are seen, ``xy``; ``inf`` behind it."""
    xc = corners_w @ r_c.T + t_c
    if np.any(xc[:, 2] <= 1e-6):
        return float("inf")
    return float(np.sqrt(np.mean(np.sum((xc[:, :2] / xc[:, 2:3] - xy) ** 2, axis=1))))


def _view_poses(
    mounts: list[TagMount], xy: dict[int, FloatArray]
) -> list[tuple[FloatArray, FloatArray]]:
    """Candidate poses (body → camera) of a body from one photo's view of its tags
    ``mounts``: one from their corners together (``SOLVEPNP_SQPNP``) when two or more, the
    planar square's two solutions (``SOLVEPNP_IPPE_SQUARE``) when one."""
    cv2 = load_cv2()
    if len(mounts) > 1:
        obj = np.concatenate([t.corners_body() for t in mounts])
        pts = np.concatenate([xy[t.tag_id] for t in mounts])
        try:
            r, t_, _ = pose_from_points(obj, pts, False)
        except DataError:
            return []
        return [(r, t_)]
    t = mounts[0]
    _n, rs, ts, _e = cv2.solvePnPGeneric(
        tag_corners(t.side_m).astype(np.float64),
        xy[t.tag_id].astype(np.float64),
        np.eye(3),
        None,
        flags=cv2.SOLVEPNP_IPPE_SQUARE,
    )
    out = []
    for rv, tv in zip(rs, ts, strict=True):
        r_ct = cv2.Rodrigues(rv)[0]
        r_cb = r_ct @ t.rotation.T
        out.append((r_cb, np.asarray(tv, float).ravel() - r_cb @ t.offset_m))
    return out


def _photo_pose(
    obs: dict[int, FloatArray],
    mount: dict[int, tuple[int, TagMount]],
    bodies: dict[int, tuple[FloatArray, FloatArray]],
    min_tags: int,
) -> tuple[FloatArray, FloatArray] | None:
    """A photo's first pose (world → camera) from the placed tags it shows (at least
    ``min_tags``; ``None`` with fewer): candidates from each placed body's tags in it
    (:func:`_view_poses`), the one the most placed tags agree with (:data:`INIT_AGREE`; then
    the smallest error), refined on the tags that agree (``cv2.solvePnP``)."""
    seen: dict[int, list[TagMount]] = {}
    for tid in obs:
        bi, t = mount[tid]
        if bi in bodies:
            seen.setdefault(bi, []).append(t)
    world = {
        t.tag_id: t.corners_body() @ bodies[bi][0].T + bodies[bi][1]
        for bi, ts in seen.items()
        for t in ts
    }
    if len(world) < min_tags:
        return None
    best: tuple[int, float, FloatArray, FloatArray] | None = None
    for bi, ts in seen.items():
        rb, pb = bodies[bi]
        for r_cb, t_cb in _view_poses(ts, obs):
            rc = r_cb @ rb.T  # world → camera
            tc = t_cb - rc @ pb
            errs = [_tag_rms(rc, tc, w, obs[tid]) for tid, w in world.items()]
            agree = sum(e < INIT_AGREE for e in errs)
            score = float(np.sum(np.minimum(errs, INIT_AGREE)))
            if best is None or (agree, -score) > (best[0], -best[1]):
                best = (agree, score, rc, tc)
    if best is None:
        return None
    _, _, rc, tc = best
    ok = [tid for tid, w in world.items() if _tag_rms(rc, tc, w, obs[tid]) < INIT_AGREE]
    if len(ok) > 1:
        try:
            rc, tc, _ = pose_from_points(
                np.concatenate([world[k] for k in ok]), np.concatenate([obs[k] for k in ok]), False
            )
        except DataError:
            pass
    return rc, tc


def _body_pose(
    b: BodyModel,
    cams: dict[int, tuple[FloatArray, FloatArray]],
    norm: list[dict[int, FloatArray]],
    photos: list[Photo],
) -> tuple[FloatArray, FloatArray] | None:
    """A body's first pose (body → world) from the placed photos showing it (``None`` without
    one): candidates from its views in the six photos where its tags look largest (two or more
    of its tags first; :func:`_view_poses`), the one the most views agree with
    (:data:`INIT_AGREE`; then the smallest error)."""
    views = []
    for c in cams:
        seen = [t for t in b.tags if t.tag_id in norm[c]]
        if seen:
            area = sum(_area(photos[c].tags[t.tag_id]) for t in seen)
            views.append((len(seen) > 1, area, c, seen))
    if not views:
        return None
    views.sort(key=lambda v: (v[0], v[1]), reverse=True)
    best: tuple[int, float, FloatArray, FloatArray] | None = None
    for _multi, _area_px, c, seen in views[:6]:
        rc, tc = cams[c]
        for r_cb, t_cb in _view_poses(seen, norm[c]):
            rb, pb = rc.T @ r_cb, rc.T @ (t_cb - tc)
            errs: list[float] = []
            for _m, _a, c2, seen2 in views:
                r2, t2 = cams[c2]
                errs.extend(
                    _tag_rms(r2, t2, t.corners_body() @ rb.T + pb, norm[c2][t.tag_id])
                    for t in seen2
                )
            agree = sum(e < INIT_AGREE for e in errs)
            score = float(np.sum(np.minimum(errs, INIT_AGREE)))
            if best is None or (agree, -score) > (best[0], -best[1]):
                best = (agree, score, rb, pb)
    return None if best is None else (best[2], best[3])


def _area(c: FloatArray) -> float:
    x, y = c[:, 0], c[:, 1]
    return 0.5 * abs(float(np.dot(x, np.roll(y, 1)) - np.dot(y, np.roll(x, 1))))
