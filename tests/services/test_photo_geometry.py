"""Geometry from photos: bad photos named with the fix, EXIF-less photos refused, a body seen
too rarely named with the photos it needs; the detector's corners against a rendered truth."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from dimacq.errors import DataError
from dimacq.io.tags_file import BodySpec, LayoutSpec, TagsFile, TagSpec
from dimacq.pipeline.photogrammetry.bundle import BodyModel, TagMount
from dimacq.services.geometry.photo_geometry import detect_tags, geometry_from_photos, read_photos
from dimacq.services.geometry.photo_input import Photo


def _sheet(ids: list[int], family: int, px: int = 60) -> np.ndarray:
    d = cv2.aruco.getPredefinedDictionary(family)
    img = np.full((400, 600), 255, np.uint8)
    for k, i in enumerate(ids):
        x = 60 + k * (px + 40)
        img[170 : 170 + px, x : x + px] = cv2.aruco.generateImageMarker(d, i, px)
    return img


def _tags() -> TagsFile:
    plate = LayoutSpec(tags=[TagSpec(index=0, side_m=0.04)])
    return TagsFile(
        layouts={"plate": plate},
        bodies=[
            BodySpec(
                kind="reference",
                name="REF0",
                layout="plate",
                first_id=0,
                position_m=(0.0, 0.0, 0.0),
                rotation_deg=(0.0, 0.0, 0.0),
            ),
            BodySpec(kind="triax", node=1, layout="plate", first_id=1),
        ],
    )


def test_detection_corners_exact_on_a_printed_sheet() -> None:
    img = _sheet([3, 7], cv2.aruco.DICT_APRILTAG_36h11)
    det = detect_tags(img)
    assert sorted(det) == [3, 7]
    # the black square spans pixels 60..119 (edges at 59.5 and 119.5)
    np.testing.assert_allclose(
        det[3], [[59.5, 169.5], [119.5, 169.5], [119.5, 229.5], [59.5, 229.5]], atol=0.6
    )


def test_bad_photos_named(tmp_path: Path) -> None:
    cv2.imwrite(str(tmp_path / "a_blank.png"), np.full((400, 600), 128, np.uint8))
    cv2.imwrite(str(tmp_path / "b_family.png"), _sheet([1, 2], cv2.aruco.DICT_4X4_50))
    blurred = cv2.GaussianBlur(_sheet([0, 1], cv2.aruco.DICT_APRILTAG_36h11), (0, 0), 12)
    cv2.imwrite(str(tmp_path / "c_blur.png"), blurred)
    cv2.imwrite(str(tmp_path / "d_one.png"), _sheet([0], cv2.aruco.DICT_APRILTAG_36h11))
    (tmp_path / "e_text.jpg").write_text("not an image")
    paths = sorted(tmp_path.iterdir())
    photos, issues = read_photos(paths, "DICT_APRILTAG_36h11", {0, 1}, lambda _m: None)
    by = {i.photo: i for i in issues}
    assert "no tags found" in by["a_blank.png"].problem
    assert "DICT_4X4" in by["b_family.png"].problem and "family" in by["b_family.png"].fix
    assert "blurred" in by["c_blur.png"].problem
    assert "one known tag" in by["d_one.png"].problem
    assert "not an image" in by["e_text.jpg"].problem
    assert [p.name for p in photos] == ["d_one.png"]


def test_exif_less_photos_refused(tmp_path: Path) -> None:
    for k in range(3):
        cv2.imwrite(str(tmp_path / f"p{k}.png"), _sheet([0, 1], cv2.aruco.DICT_APRILTAG_36h11))
    with pytest.raises(DataError, match=r"EXIF.*--camera"):
        geometry_from_photos(tmp_path, _tags())


def test_views_nothing_ties_are_left_out() -> None:
    """A body without a stated pose seen in one photo, and a photo with one tag, are dropped."""
    from dimacq.pipeline.photogrammetry.bundle import BodyModel, Observation, TagMount
    from dimacq.services.geometry.photo_geometry import tied_only

    def body(name: str, ids: list[int], prior: bool) -> BodyModel:
        tags = tuple(TagMount(i, 0.02, np.eye(3), np.zeros(3)) for i in ids)
        if prior:
            return BodyModel(name, "reference", tags, None, np.eye(3), np.zeros(3), 1e-4, 0.1)
        return BodyModel(name, "triax", tags, 1)

    models = [body("REF0", [0], True), body("triax 1", [1, 2], False), body("bar", [3], False)]
    c = np.zeros((4, 2))
    obs = [
        Observation(0, 0, c),
        Observation(0, 1, c),
        Observation(1, 0, c),
        Observation(1, 2, c),
        Observation(1, 3, c),  # the bar: in photo 1 only
        Observation(2, 1, c),  # photo 2: one tag only
    ]
    kept = {(o.photo, o.tag_id) for o in tied_only(obs, models)}
    assert kept == {(0, 0), (0, 1), (1, 0), (1, 2)}


def test_too_uncertain_triax_refused_with_the_views_it_needs() -> None:
    """σ ∝ 1/√n: a triax at twice the angle limit from 10 photos needs 30 more."""
    from dataclasses import replace
    from types import SimpleNamespace

    from dimacq.services.geometry.photo_geometry import LIMIT_ANGLE_STD_DEG, too_uncertain
    from dimacq.services.geometry.records import Orientation

    def ori(node: int, ang: float) -> Orientation:
        return Orientation(
            node=node,
            rotation=np.eye(3).tolist(),
            origin_m=[0.0, 0.0, 0.0],
            method="photos",
            rods=[],
            n_points=40,
            residual_rms_m=1e-5,
            angle_std_deg=[ang, 0.01, 0.01],
            uncertainty_deg=ang,
            jig_uncertainty_deg=ang,
            registration_uncertainty_deg=None,
            origin_std_m=5e-5,
        )

    bundle = SimpleNamespace(
        bodies=[
            SimpleNamespace(kind="triax", node=1, n_photos=10),
            SimpleNamespace(kind="triax", node=2, n_photos=10),
        ]
    )
    out = too_uncertain(
        bundle,  # type: ignore[arg-type]
        [ori(1, 2 * LIMIT_ANGLE_STD_DEG), ori(2, 0.5 * LIMIT_ANGLE_STD_DEG)],
        [],
        [],
    )
    assert len(out) == 1 and out[0].startswith("triax 1:") and "about 30 more close-ups" in out[0]
    assert "reference plates" not in out[0]
    # a block seen with other bodies in 4 of its 10 photos, its position twice over the limit:
    # 12 more photos tying it to the frame
    pos = replace(ori(3, 0.5 * LIMIT_ANGLE_STD_DEG), origin_std_m=4e-4)
    out = too_uncertain(bundle, [pos], [], [], {("triax", 3): 4})  # type: ignore[arg-type]
    assert len(out) == 1 and "from 4 photos" in out[0]
    assert "about 12 more photos showing its block together with reference plates" in out[0]
    assert "close-ups" not in out[0]


def _cube_tags(first: int, side: float) -> tuple[TagMount, ...]:
    """Tags on the +z, +x and +y faces of a cube of edge ``1.25 side`` (body frame)."""
    h = 0.625 * side
    faces = [Rotation.identity(), Rotation.from_euler("y", 90, degrees=True)]
    faces.append(Rotation.from_euler("x", -90, degrees=True))
    return tuple(
        TagMount(first + k, side, f.as_matrix(), f.apply([0.0, 0.0, h]))
        for k, f in enumerate(faces)
    )


def _seen(
    r_c: np.ndarray, t_c: np.ndarray, rb: np.ndarray, pb: np.ndarray, t: TagMount
) -> np.ndarray:
    xc = (t.corners_body() @ rb.T + pb) @ r_c.T + t_c
    return xc[:, :2] / xc[:, 2:3]


def _camera_at(eye: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A camera at ``eye`` looking at the origin (world → camera)."""
    z = -eye / np.linalg.norm(eye)
    x = np.cross(z, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    r = np.array([x, np.cross(z, x), z])
    return r, -r @ eye


def test_first_poses_outvote_a_misplaced_body_and_the_mirrored_square() -> None:
    from dimacq.services.geometry.photo_poses import _body_pose, _photo_pose

    rng = np.random.default_rng(4)
    bodies_true = {
        i: (
            Rotation.from_rotvec(rng.normal(scale=0.1, size=3)).as_matrix(),
            rng.uniform(-0.1, 0.1, 3),
        )
        for i in range(3)
    }
    tags = {i: _cube_tags(10 * i, 0.024) for i in range(3)}
    mount = {t.tag_id: (i, t) for i, ts in tags.items() for t in ts}
    r_c, t_c = _camera_at(np.array([0.5, 0.4, 0.45]))
    obs = {
        t.tag_id: _seen(r_c, t_c, *bodies_true[i], t)
        for i, ts in tags.items()
        for t in ts
        if (r_c @ bodies_true[i][0] @ t.rotation[:, 2])[2] < -0.3  # facing the camera
    }
    assert len({mount[k][0] for k in obs}) == 3
    # body 2 placed 80 mm and 45° off (a gross error, far beyond INIT_AGREE): the photo's pose
    # follows bodies 0 and 1
    wrong = dict(bodies_true)
    wrong[2] = (
        Rotation.from_euler("z", 45, degrees=True).as_matrix() @ bodies_true[2][0],
        bodies_true[2][1] + 0.08,
    )
    pose = _photo_pose(obs, mount, wrong, 2)
    assert pose is not None
    np.testing.assert_allclose(pose[0], r_c, atol=1e-6)
    np.testing.assert_allclose(pose[1], t_c, atol=1e-6)
    # a body seen through one tag in its largest view: the planar square's two solutions;
    # the one the other photos agree with is taken
    one = BodyModel("triax 9", "triax", (tags[0][0],))
    r_b, p_b = bodies_true[0]
    cams = {
        0: (r_c, t_c),
        1: _camera_at(np.array([0.2, 0.5, 0.4])),
    }
    norm = [{one.tags[0].tag_id: _seen(*cams[c], r_b, p_b, one.tags[0])} for c in (0, 1)]
    photos = [
        Photo(
            f"p{c}", (1600, 1200), {one.tags[0].tag_id: 1450 * norm[c][one.tags[0].tag_id]}, 1450.0
        )
        for c in (0, 1)
    ]
    got = _body_pose(one, cams, norm, photos)
    assert got is not None
    np.testing.assert_allclose(got[0], r_b, atol=1e-6)
    np.testing.assert_allclose(got[1], p_b, atol=1e-8)


@pytest.mark.slow
def test_a_tag_glued_off_its_place_is_named(tmp_path: Path) -> None:
    """One tag of a photographed triax sits 1 mm off its stated place (20 times the default
    placement 1σ): the run names that tag, on its block, with the fix, and no other tag; the
    block's pose, taken from its other tags, is within its stated 1σ of the truth."""
    from dataclasses import replace

    from dimacq.io.tags_file import dump_tags, load_tags, standard_tags
    from dimacq.simulators.camera.render import photograph_article, tagged_world
    from dimacq.simulators.lab.scenarios import build_scenario

    built = build_scenario("calibration-mass-bungee", 1)
    st = built.model.setup
    nodes = sorted({c.node for c in st.responses})[:2]
    plan = standard_tags(
        nodes,
        [st.excitations[0].node],
        np.vstack([st.response_positions, st.input_positions]),
    )
    world = tagged_world(plan, st, np.random.default_rng(2001))
    k, moved = next(
        (k, t) for k, t in enumerate(world.tags) if t.body == f"triax {nodes[0]}" and not t.hidden
    )
    tags = list(world.tags)
    tags[k] = replace(moved, centre_m=moved.centre_m + 1e-3 * moved.rotation[:, 0])
    photograph_article(replace(world, tags=tuple(tags)), tmp_path, 24, 3001)
    dump_tags(plan, tmp_path / "tags.toml")
    res = geometry_from_photos(tmp_path, load_tags(tmp_path / "tags.toml"))
    named = [i for i in res.issues if "off its stated place" in i.problem]
    assert [i.photo for i in named] == [f"tag {moved.tag_id} on triax {nodes[0]}"], res.issues
    assert "glue it square" in named[0].fix and "taken from its other tags" in named[0].problem
    o = next(o for o in res.orientations if o.node == nodes[0])
    r_true, p_true = world.truth[f"triax {nodes[0]}"]
    assert np.all(np.abs(np.array(o.origin_m) - p_true) < 3 * o.origin_std_m)
    err = np.degrees(Rotation.from_matrix(np.array(o.rotation) @ r_true.T).as_rotvec())
    assert np.all(np.abs(np.array(o.rotation).T @ err) < 3 * np.asarray(o.angle_std_deg))


def test_records_scale_the_corners_part_by_the_residual_factor() -> None:
    """A triax whose corners' residuals are twice the set's: its record's 1σ is
    ``sqrt(f² (Σ − P) + P)`` per axis and coordinate (``P`` its priors' part), against the same
    body at ``f = 1`` (or below: never scaled down)."""
    from dimacq.pipeline.photogrammetry.bundle import BodyEstimate, BundleResult, TagPlacement
    from dimacq.pipeline.photogrammetry.camera import Intrinsics
    from dimacq.services.geometry.photo_records import bundle_records

    cov = np.diag([4e-6, 9e-6, 1e-6, 4e-10, 1e-10, 9e-10])
    prior = np.diag([1e-6, 1e-6, 1e-6, 1e-10, 1e-10, 1e-10])
    model = BodyModel("triax 3", "triax", (), node=3)
    intr = Intrinsics(1000.0, 1000.0, 500.0, 400.0, 0, 0, 0, 0, 0, 1000, 800)

    def record(f: float):
        est = BodyEstimate("triax 3", "triax", 3, np.eye(3), np.zeros(3), cov, 20, 80, f, prior)
        tp = TagPlacement(1, "triax 3", np.zeros(3), np.zeros(2), np.zeros(3), np.zeros(2), 0.0, 20)
        bundle = BundleResult(
            (est,),
            np.zeros((0, 3, 3)),
            np.zeros((0, 3)),
            intr,
            None,
            0.2,
            80,
            30,
            0.2,
            np.zeros(0),
            (),
            10,
            1.0,
            placements=(tp,),
        )
        (o,), _ = bundle_records(bundle, [model], _tags(), 1e-5)
        return o

    want = np.sqrt(4.0 * (np.diag(cov) - np.diag(prior)) + np.diag(prior))
    o = record(2.0)
    np.testing.assert_allclose(o.angle_std_deg, np.degrees(want[:3]), rtol=1e-9)
    assert o.origin_std_m == pytest.approx(float(want[3:].max()), rel=1e-9)
    for f in (1.0, 0.6):
        np.testing.assert_allclose(
            record(f).angle_std_deg, np.degrees(np.sqrt(np.diag(cov)[:3])), rtol=1e-9
        )
